"""RDNet and its baselines as torch modules, a size registry and :func:`build_model`.

* :class:`RestoreNet` -- stage 1 of RDNet (event restoration): blurry image + degraded
  voxels -> restored voxels (global residual on the voxels). ``output="signed"`` is the
  paper's signed voxel; ``output="counts"`` reads and writes per-polarity counts and
  cannot invent events without evidence (see the class). ``image_channels=0`` is the
  events-only restorer (no image branch; cameras without frames).
* :class:`DeblurNet` -- stage 2 (deblurring): blurry image + voxels -> sharp image
  (global residual on the image). Alone it is the "DeblurNet" baseline (degraded events
  straight into the deblurring network); ``use_events=False`` drops the event branch and
  gives the image-only baseline (a NAFNet UNet).
* :class:`RDNet` -- both stages: ``forward(image, voxel) -> (restored_voxel, sharp)``.

Every model stores its constructor arguments in ``self.config`` (a plain dict with a
``kind`` key) so a checkpoint ``{"config": model.config, "state_dict": ...}`` rebuilds
with :func:`model_from_config` (nanoGPT style).

Sizes (:data:`MODEL_SIZES`, parameter counts for grey images, ``bins=10``):

* ``tiny``  -- width 8, 3 levels, one block each: trains on CPU at 64x64 in minutes.
* ``small`` -- width 16, 4 levels.
* ``paper`` -- width 24, enc (1, 1, 2, 2), middle 1, dec (1, 1, 1, 1): RestoreNet + DeblurNet
  together 7,905,779 parameters for grey input (3,953,866 + 3,951,913; colour: 7,907,077),
  0.6 % above the 7.86 M the paper reports (Sec. 4.1). The paper does not publish its block
  layout; this is the most regular layout found within 1 % of the total.

``deblurnet_matched`` is the stage-2 structure alone, widened (width searched by
:func:`match_deblurnet`) so its parameter count matches the two-stage RDNet of the same
size; where no integer width lands within 1 %, middle and decoder depths are searched too.
"""
from __future__ import annotations

import copy
import itertools
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from rdnet.errors import ConfigError
from rdnet.nn.blocks import nafblock_params
from rdnet.nn.decision import offset_threshold
from rdnet.nn.sparse import SparseVoxels
from rdnet.nn.stage import StageNet

#: Architecture hyper-parameters per named size (shared by both stages).
MODEL_SIZES: dict[str, dict[str, Any]] = {
    "tiny": {"width": 8, "enc_depths": (1, 1, 1), "middle_depth": 1, "dec_depths": (1, 1, 1)},
    "small": {"width": 16, "enc_depths": (1, 1, 1, 1), "middle_depth": 1, "dec_depths": (1, 1, 1, 1)},
    "paper": {"width": 24, "enc_depths": (1, 1, 2, 2), "middle_depth": 1, "dec_depths": (1, 1, 1, 1)},
}

MODEL_KINDS = ("restore", "deblur", "rdnet", "deblurnet_matched", "image_only")


def count_parameters(model: nn.Module, trainable_only: bool = False) -> int:
    """Number of parameters (all, or only those with ``requires_grad``)."""
    return int(sum(p.numel() for p in model.parameters() if p.requires_grad or not trainable_only))


#: RestoreNet outputs: the paper's signed voxel, or per-polarity counts with occupancy.
RESTORE_OUTPUTS = ("signed", "counts")
#: logit offset of the identity start of the occupancy head: sigmoid(+-4) = 0.982 / 0.018.
OCCUPANCY_GAIN = 4.0


def _count_head(counts: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """The count head of :class:`RestoreNet` from the input counts and the output conv's
    count channels: ``mu = max(max(x, 1) + r, 1)``."""
    return (counts.clamp_min(1.0) + r).clamp_min(1.0)


def _patches(feats: torch.Tensor, b: torch.Tensor, y: torch.Tensor, x: torch.Tensor, k: int) -> torch.Tensor:
    """(n, k * k, C): the k x k neighbourhoods of ``feats`` (B, C, H', W') around the pixels
    ``(b, y, x)`` (int64 tensors), zero outside (the zero padding of a 'same' k x k conv),
    taps in row-major order: what that conv reads for those output pixels."""
    Hp, Wp = feats.shape[-2:]
    tap = torch.arange(k * k, device=feats.device)
    yy = y[:, None] + (tap // k - k // 2)[None]          # (n, taps)
    xx = x[:, None] + (tap % k - k // 2)[None]
    inside = (yy >= 0) & (yy < Hp) & (xx >= 0) & (xx < Wp)
    return feats[b[:, None], :, yy.clamp(0, Hp - 1), xx.clamp(0, Wp - 1)] * inside[..., None]


class RestoreNet(nn.Module):
    """Stage 1: restore degraded event voxels, guided by the blurry image (or events
    only with ``image_channels=0``: ``image`` is then None).

    ``output="signed"`` (the paper): forward(image (B, C, H, W), voxel (B, bins, H, W))
    -> restored signed voxel (B, bins, H, W) = ``voxel + correction`` (global residual,
    :mod:`rdnet.nn.stage`).

    ``output="counts"``: the input is the per-polarity count grid (B, 2 * bins, H, W) (ON
    counts of the bins, then OFF counts: ``voxel_grid(polarity="split")`` flattened) and
    the network has two heads per polarity voxel (:meth:`heads`):

    * occupancy logit ``z = o + 4 (2 [x > 0] - 1)``: the probability that the voxel holds
      at least one undegraded event;
    * count given occupied ``mu = max(max(x, 1) + r, 1)`` (>= 1).

    ``o`` and ``r`` come from a zero-initialised output conv, so a fresh network is the
    identity at the event level: ``p > 0.5`` exactly where the input has events and
    ``mu = x`` there. forward returns the expected counts ``sigmoid(z) * mu`` (>= 0,
    (B, 2 * bins, H, W)); :meth:`signed` turns counts into the signed voxel stage 2
    reads. Events are made by a decision fitted after training
    (:mod:`rdnet.nn.decision`): ``round(mu)`` events where ``sigmoid(z) >= threshold``,
    none elsewhere -- an empty voxel gets events only when the network is confident
    enough, and the losses (:func:`rdnet.nn.losses.count_restoration_loss`) constrain
    every voxel.
    """

    def __init__(self, image_channels: int = 1, bins: int = 10, width: int = 16,
                 enc_depths=(1, 1, 1, 1), middle_depth: int = 1, dec_depths=(1, 1, 1, 1),
                 output: str = "signed"):
        super().__init__()
        if output not in RESTORE_OUTPUTS:
            raise ValueError(f"output must be one of {RESTORE_OUTPUTS}, got {output!r}")
        self.config = {"kind": "restore", "image_channels": int(image_channels), "bins": int(bins),
                       "width": int(width), "enc_depths": tuple(enc_depths),
                       "middle_depth": int(middle_depth), "dec_depths": tuple(dec_depths)}
        if output != "signed":  # old checkpoints (signed) keep their config unchanged
            self.config["output"] = output
        self.output, self.bins, self.image_channels = output, int(bins), int(image_channels)
        if output == "signed":
            self.net = StageNet(image_channels, bins, bins, width, enc_depths, middle_depth,
                                dec_depths, fuse_into="event", residual=True)
        else:
            self.net = StageNet(image_channels, 2 * bins, 4 * bins, width, enc_depths, middle_depth,
                                dec_depths, fuse_into="event", residual=False)
            nn.init.zeros_(self.net.ending.weight)   # identity start (class docstring)
            nn.init.zeros_(self.net.ending.bias)

    @property
    def in_channels(self) -> int:
        """Event channels of the input: bins (signed) or 2 * bins (counts)."""
        return self.bins if self.output == "signed" else 2 * self.bins

    def heads(self, image: torch.Tensor | None, counts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mu, logit), each (B, 2 * bins, H, W), of the counts output (class docstring)."""
        if self.output != "counts":
            raise ValueError("heads() exists for output='counts' only")
        out = self.net(image, counts)
        r, o = out[:, :2 * self.bins], out[:, 2 * self.bins:]
        mu = _count_head(counts, r)
        logit = o + OCCUPANCY_GAIN * (2.0 * (counts > 0).to(o.dtype) - 1.0)
        return mu, logit

    def sparse_heads(self, image: torch.Tensor | None, counts, logit_min: float, pixels=None):
        """The occupancy decision of :meth:`heads` without the dense count head, for
        inference: ``(keep, mu_at)``. ``keep`` is ``logit >= logit_min`` (bool, (B, 2 * bins,
        H, W), the memory format of the inputs): the same mask as on :meth:`heads`'s logits,
        since the logit channels of the output conv are computed alone and offset exactly as
        there. ``mu_at(b, c, y, x)`` (int64 index arrays) gives the count head ``mu`` at
        those voxels only, a 3 x 3 x width dot product each: equal to :meth:`heads`'s ``mu``
        up to the order of the float32 sums. Saves half the output conv and every dense
        pass over ``mu`` (about 15 % of a DAVIS346 window on 2 cores).

        ``counts`` may be a :class:`rdnet.nn.sparse.SparseVoxels` (one sample): the event
        branch's intro conv then reads its non-zero voxels alone, and the input's occupancy
        enters the decision at those voxels only (the grid, its padding and two dense passes
        over it are never formed); equal to the dense input up to float rounding.

        ``pixels`` (one sample): ``(y, x)`` index arrays of the only pixels whose voxels the
        caller can keep (the decision's support rule drops the others:
        :func:`rdnet.nn.decision.sparse_decided_entries`). The occupancy logits are then
        computed at those pixels alone, a 3 x 3 x width dot product per channel as in
        ``mu_at`` (equal to the dense conv up to the order of the float32 sums), and ``keep``
        is the kept voxels' ``(b, c, y, x)`` index arrays (C order of (1, 2 * bins, H, W))
        instead of a mask. In a DAVIS346 window about 2 % of the pixels are supported; the
        dense logit conv was its costliest operation (5.3 of 33 ms in torch's profiler)."""
        if self.output != "counts":
            raise ValueError("sparse_heads() exists for output='counts' only")
        feats, _, H, W = self.net.decoded(image, counts)
        b2 = 2 * self.bins
        weight, bias = self.net.ending.weight, self.net.ending.bias
        # heads()' logit is o + GAIN where x > 0 and o - GAIN elsewhere (exactly: the offset
        # GAIN * (2 [x > 0] - 1) is +-GAIN); float32 addition is monotone, so each comparison
        # is one on o against the smallest float32 that reaches logit_min after the offset
        lo_on, lo_off = (offset_threshold(logit_min, g) for g in (OCCUPANCY_GAIN, -OCCUPANCY_GAIN))
        sparse = isinstance(counts, SparseVoxels)
        if sparse:
            def count_at(b, c, y, x):
                return torch.as_tensor(counts.at(c, y, x), device=feats.device)
        else:
            def count_at(b, c, y, x):
                return counts[tuple(torch.as_tensor(a, device=counts.device) for a in (b, c, y, x))]

        def mu_at(b, c, y, x) -> torch.Tensor:
            where = tuple(np.asarray(a, np.int64) for a in (b, c, y, x))     # host arrays, for count_at
            b, c, y, x = (torch.as_tensor(a, device=feats.device) for a in where)
            patch = _patches(feats, b, y, x, weight.shape[-1])               # (n, taps, width)
            w = weight[c].permute(0, 2, 3, 1).reshape(len(c), patch.shape[1], -1)    # (n, taps, width)
            return _count_head(count_at(*where), (patch * w).sum((1, 2)) + bias[c])

        if pixels is not None:
            if feats.shape[0] != 1:
                raise ValueError("sparse_heads(pixels=...) takes one sample")
            y, x = (np.asarray(a, np.int64).ravel() for a in pixels)
            n = y.size
            dev = feats.device
            patch = _patches(feats, torch.zeros(n, dtype=torch.int64, device=dev), torch.as_tensor(y, device=dev),
                             torch.as_tensor(x, device=dev), weight.shape[-1])
            w = weight[b2:].permute(0, 2, 3, 1).reshape(b2, -1)                # (2 bins, taps * width)
            o = patch.reshape(n, -1) @ w.T + bias[b2:]                         # (n, 2 bins)
            cs = np.tile(np.arange(b2, dtype=np.int64), n)                     # pixel-major, as o's rows
            ys, xs = np.repeat(y, b2), np.repeat(x, b2)
            zero = np.zeros(cs.size, np.int64)
            occupied = count_at(zero, cs, ys, xs).reshape(n, b2) > 0
            kept = (o >= torch.where(occupied, lo_on, lo_off)).reshape(-1).cpu().numpy()
            c, yk, xk = cs[kept], ys[kept], xs[kept]
            order = np.argsort((c * H + yk) * W + xk, kind="stable")
            return (zero[:c.size], c[order], yk[order], xk[order]), mu_at
        o = F.conv2d(feats, weight[b2:], bias[b2:], padding=1)[..., :H, :W]
        if sparse:
            keep = o >= lo_off
            occupied = counts.values > 0
            at = tuple(torch.as_tensor(a[occupied], device=o.device) for a in counts.coords())
            keep[(0, *at)] = o[(0, *at)] >= lo_on
        else:
            keep = o >= torch.where(counts > 0, lo_on, lo_off)
        return keep, mu_at

    def forward(self, image: torch.Tensor | None, voxel: torch.Tensor, return_heads: bool = False):
        """The restored voxel (signed) or expected counts; ``return_heads=True`` (counts
        output) returns ``(mu, logit)`` instead (through forward, so that wrappers such as
        DistributedDataParallel see the call)."""
        if self.output == "signed":
            if return_heads:
                raise ValueError("return_heads exists for output='counts' only")
            return self.net(image, voxel)
        mu, logit = self.heads(image, voxel)
        return (mu, logit) if return_heads else torch.sigmoid(logit) * mu

    def signed(self, restored: torch.Tensor) -> torch.Tensor:
        """The signed voxel (B, bins, H, W) of an output of :meth:`forward` (ON - OFF for
        counts; unchanged for the signed output)."""
        if self.output == "signed":
            return restored
        return restored[:, :self.bins] - restored[:, self.bins:]


class DeblurNet(nn.Module):
    """Stage 2: deblur the image guided by event voxels (or image only).

    forward(image (B, C, H, W), voxel (B, bins, H, W) or None) -> sharp (B, C, H, W).
    Event features are added into the image branch at every scale; the output is
    ``image + correction``. With ``use_events=False`` there is no event branch and
    ``voxel`` must be None (a voxel passed to the image-only model raises ValueError).
    """

    def __init__(self, image_channels: int = 1, bins: int = 10, width: int = 16,
                 enc_depths=(1, 1, 1, 1), middle_depth: int = 1, dec_depths=(1, 1, 1, 1),
                 use_events: bool = True):
        super().__init__()
        self.config = {"kind": "deblur", "image_channels": int(image_channels), "bins": int(bins),
                       "width": int(width), "enc_depths": tuple(enc_depths),
                       "middle_depth": int(middle_depth), "dec_depths": tuple(dec_depths),
                       "use_events": bool(use_events)}
        self.use_events = bool(use_events)
        self.net = StageNet(image_channels, bins if use_events else 0, image_channels, width,
                            enc_depths, middle_depth, dec_depths, fuse_into="image", residual=True)

    def forward(self, image: torch.Tensor, voxel: torch.Tensor | None = None) -> torch.Tensor:
        if not self.use_events and voxel is not None:
            raise ValueError("image-only DeblurNet (use_events=False) takes no voxel input")
        return self.net(image, voxel)

    def event_features(self, voxel: torch.Tensor) -> list[torch.Tensor]:
        """F(.) of the restoration loss (paper Eq. 9): the multi-scale features of this
        network's event encoder (one map per level + the bottom), independent of the image."""
        if not self.use_events:
            raise ValueError("image-only DeblurNet has no event encoder")
        return self.net.source_features(voxel)


class EventEncoder(nn.Module):
    """F of the restoration loss as a module of its own: ``deblur.event_features`` (it
    shares the DeblurNet's weights; parameter names ``deblur.<name>``), so that
    ``torch.func.functional_call`` can run F with detached weights: the fixed perceptual
    encoder of ``train.feature_grad: false``."""

    def __init__(self, deblur: "DeblurNet"):
        super().__init__()
        self.deblur = deblur

    def forward(self, voxel: torch.Tensor) -> list[torch.Tensor]:
        return self.deblur.event_features(voxel)


#: what RDNet's stage 2 reads: the restored voxel (the paper) or restored and raw ("dual").
STAGE2_INPUTS = ("restored", "dual")


class RDNet(nn.Module):
    """Both stages: forward(image, voxel) -> (restored_voxel, sharp_image).

    ``stage2_input="dual"``: stage 2 reads the restored *and* the raw signed voxels
    (2 x bins event channels), so that it cannot lose what DeblurNet on the raw events
    (row 2) has: restoration can only add information.

    ``voxel`` is stage 1's input (signed voxel, or per-polarity counts for a counts
    RestoreNet); ``restored_voxel`` is always the signed voxel (B, bins, H, W) -- for the
    counts output the expected ON minus OFF counts -- which is what stage 2 reads, so
    DeblurNet's input (bins signed channels) is the same for both stage-1 outputs."""

    def __init__(self, restore: RestoreNet, deblur: DeblurNet, stage2_input: str = "restored"):
        super().__init__()
        if not deblur.use_events:
            raise ValueError("RDNet needs a DeblurNet with an event branch")
        if stage2_input not in STAGE2_INPUTS:
            raise ValueError(f"stage2_input must be one of {STAGE2_INPUTS}, got {stage2_input!r}")
        factor = {"image_channels": 1, "bins": 2 if stage2_input == "dual" else 1}
        for key in ("image_channels", "bins"):
            if restore.config[key] * factor[key] != deblur.config[key]:
                raise ValueError(f"stages disagree on {key}: {restore.config[key]} vs {deblur.config[key]}")
        self.restore = restore
        self.deblur = deblur
        self.stage2_input = stage2_input
        self.config = {"kind": "rdnet", "restore": dict(restore.config), "deblur": dict(deblur.config)}
        if stage2_input != "restored":
            self.config["stage2_input"] = stage2_input

    def stage2_events(self, restored: torch.Tensor, voxel: torch.Tensor) -> torch.Tensor:
        """What stage 2 reads: the restored signed voxel, or (``dual``) it concatenated with
        the raw signed voxel of stage 1's input ``voxel`` (ON - OFF for counts)."""
        if self.stage2_input == "restored":
            return restored
        if self.restore.output == "counts":
            b = self.restore.bins
            voxel = voxel[:, :b] - voxel[:, b:]
        return torch.cat([restored, voxel], 1)

    def stage2(self, image: torch.Tensor, restored: torch.Tensor, voxel: torch.Tensor) -> torch.Tensor:
        """Stage 2 on the restored voxel (and the raw one with ``dual``)."""
        return self.deblur(image, self.stage2_events(restored, voxel))

    def forward(self, image: torch.Tensor, voxel: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        restored = self.restore.signed(self.restore(image, voxel))
        return restored, self.stage2(image, restored, voxel)


# --- construction ---------------------------------------------------------------------
_ARCH_KEYS = ("width", "enc_depths", "middle_depth", "dec_depths")


def _arch(size: str, overrides: dict) -> dict:
    try:
        arch = copy.deepcopy(MODEL_SIZES[size])
    except KeyError:
        raise ConfigError("model.size", f"unknown size {size!r}; known: {', '.join(MODEL_SIZES)}") from None
    for k, v in overrides.items():
        if k not in _ARCH_KEYS:
            raise ConfigError(f"model.{k}", f"unknown architecture key; known: {', '.join(_ARCH_KEYS)}")
        arch[k] = tuple(int(d) for d in v) if k.endswith("depths") else int(v)
    if len(arch["enc_depths"]) != len(arch["dec_depths"]):
        raise ConfigError("model.dec_depths", f"{len(arch['dec_depths'])} levels but enc_depths has "
                          f"{len(arch['enc_depths'])}")
    if arch["width"] < 1 or arch["middle_depth"] < 0 or min(arch["enc_depths"] + arch["dec_depths"]) < 0:
        raise ConfigError("model", f"width must be >= 1 and depths >= 0, got {arch}")
    return arch


def _deblur_params(image_channels: int, bins: int, arch: dict) -> int:
    with torch.device("meta"):
        return count_parameters(DeblurNet(image_channels, bins, **arch))


def match_deblurnet(target: int, image_channels: int, bins: int, arch: dict,
                    tol: float = 0.01) -> dict:
    """Architecture of a DeblurNet whose parameter count is closest to ``target``.

    Searches the width (parameters grow ~ width**2, so bisection on an integer). Integer
    widths step the count by ~2/width relative, so if the best width is off by more than
    ``tol`` the depths are searched too: widths {lo-1, lo, hi} around the bisection point,
    middle depth 0 .. 2*base+4 and each decoder level's depth base .. base+2. Among the
    candidates within ``tol`` the one with the fewest added/removed blocks wins (then the
    closest); if none is within ``tol``, the closest. Counts of depth variants are
    computed analytically (blocks are additive, :func:`rdnet.nn.blocks.nafblock_params`);
    base counts are taken on the meta device (no memory allocated).
    """
    def count(a):
        return _deblur_params(image_channels, bins, a)

    lo, hi = 1, max(2, arch["width"])
    while count({**arch, "width": hi}) < target:
        lo, hi = hi, hi * 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if count({**arch, "width": mid}) < target:
            lo = mid
        else:
            hi = mid
    best = min(({**arch, "width": w} for w in (lo, hi)), key=lambda a: abs(count(a) - target))
    if abs(count(best) - target) <= tol * target:
        return best
    L = len(arch["dec_depths"])
    m0, d0 = arch["middle_depth"], tuple(arch["dec_depths"])
    scored = []
    for w in (max(1, lo - 1), lo, hi):
        base = count({**arch, "width": w})
        for m in range(0, 2 * m0 + 5):
            for extra in itertools.product(range(3), repeat=L):
                n = (base + (m - m0) * nafblock_params(w * 2 ** L)
                     + sum(e * nafblock_params(w * 2 ** i) for i, e in enumerate(extra)))
                err = abs(n - target) / target
                changes = abs(m - m0) + sum(extra)
                cand = {**arch, "width": w, "middle_depth": m,
                        "dec_depths": tuple(d + e for d, e in zip(d0, extra))}
                scored.append((err > tol, changes if err <= tol else 0, err, cand))
    scored.sort(key=lambda s: s[:3])
    return scored[0][3]


def build_model(kind: str, size: str = "tiny", image_channels: int = 1, bins: int = 10,
                restore_output: str = "signed", stage2_input: str = "restored", **overrides) -> nn.Module:
    """Build a model of ``kind`` (one of :data:`MODEL_KINDS`) and named ``size``.

    ``restore_output``: the output of the stage-1 network (restore, rdnet):
    :data:`RESTORE_OUTPUTS`. ``image_channels=0`` (restore only): events-only restorer.
    ``stage2_input`` (rdnet only): :data:`STAGE2_INPUTS`.

    ``overrides`` replace architecture keys of the size (width, enc_depths, middle_depth,
    dec_depths). ``deblurnet_matched`` returns a :class:`DeblurNet` widened to the
    parameter count of the ``rdnet`` of the same size and overrides.
    """
    arch = _arch(size, overrides)
    if restore_output not in RESTORE_OUTPUTS:
        raise ConfigError("train.restore_output", f"unknown stage-1 output {restore_output!r}; "
                          f"known: {', '.join(RESTORE_OUTPUTS)}")
    if restore_output != "signed" and kind not in ("restore", "rdnet"):
        raise ConfigError("train.restore_output", f"only restore and rdnet have a stage-1 output, not {kind!r}")
    if stage2_input not in STAGE2_INPUTS or (stage2_input != "restored" and kind != "rdnet"):
        raise ConfigError("train.stage2_input", f"{stage2_input!r}: one of {', '.join(STAGE2_INPUTS)}, "
                          "and only rdnet has a stage 2")
    if image_channels == 0 and kind != "restore":
        raise ConfigError("image_channels", f"only the restore network runs without images, not {kind!r}")
    if kind == "restore":
        return RestoreNet(image_channels, bins, output=restore_output, **arch)
    if kind == "deblur":
        return DeblurNet(image_channels, bins, **arch)
    if kind == "image_only":
        return DeblurNet(image_channels, bins, use_events=False, **arch)
    if kind == "rdnet":
        return RDNet(RestoreNet(image_channels, bins, output=restore_output, **arch),
                     DeblurNet(image_channels, bins * (2 if stage2_input == "dual" else 1), **arch),
                     stage2_input)
    if kind == "deblurnet_matched":
        with torch.device("meta"):
            target = count_parameters(build_model("rdnet", size, image_channels, bins, **overrides))
        return DeblurNet(image_channels, bins, **match_deblurnet(target, image_channels, bins, arch))
    raise ConfigError("model.kind", f"unknown model kind {kind!r}; known: {', '.join(MODEL_KINDS)}")


def model_from_config(config: dict) -> nn.Module:
    """Rebuild a model (fresh weights) from its ``config`` dict (see module docstring)."""
    cfg = dict(config)
    kind = cfg.pop("kind", None)
    if kind == "restore":
        return RestoreNet(**cfg)
    if kind == "deblur":
        return DeblurNet(**cfg)
    if kind == "rdnet":
        return RDNet(model_from_config(cfg["restore"]), model_from_config(cfg["deblur"]))
    raise ConfigError("model.kind", f"cannot rebuild a model of kind {kind!r}")
