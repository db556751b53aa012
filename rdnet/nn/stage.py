"""The stage network of RDNet (Sec. 3.3 of "Restoring Real-World Degraded Events
Improves Deblurring Quality", ACM MM 2024): a dual-branch NAFNet-style UNet.

Both stages share this structure, with separate weights:

* an **image branch** and an **event branch** encoder, each an intro 3x3 conv followed by
  ``len(enc_depths)`` levels of NAFBlocks (:mod:`rdnet.nn.blocks`) separated by 2x
  downsampling (channels ``width * 2**level``);
* at every scale (every encoder level and the bottom) the features of the *source*
  branch are **added** into the *receiving* branch (``fuse_into``); the source branch runs
  independently of the receiving one, so its features are a function of its input alone;
* ``middle_depth`` NAFBlocks at the bottom, then a **single-branch decoder** (upsample,
  add the skip connection from the receiving branch at that scale, NAFBlocks) and a 3x3
  output conv to ``out_channels``;
* optional **global residual**: the output is added to the receiving branch's input.

Stage 1 (restoration, ``fuse_into="event"``): image features go into the event branch,
the decoder outputs the restored voxel grid; residual on the input voxels, so the network
learns the correction ``E_r - E_d``. With ``residual=True`` the output conv is
zero-initialised, so a fresh stage is exactly the identity on its receiving input
(stage 1 starts by passing the degraded voxels through, stage 2 the blurry image).
Stage 2 (deblurring, ``fuse_into="image"``): event features go into the image branch,
the decoder outputs the sharp image; residual on the blurry input.

With ``event_channels=0`` there is no event branch (image-only NAFNet UNet baseline);
with ``image_channels=0`` there is no image branch (events-only restoration, for cameras
without frames: ``fuse_into="event"``, the image argument of ``forward`` is None).

Inputs of any size are padded at the bottom/right to a multiple of
``2**len(enc_depths)`` (images: edge replication; voxels: zeros = "no events") and the
output is cropped back.
"""
from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from rdnet.nn.blocks import Downsample, Upsample, naf_stack
from rdnet.nn.sparse import SparseVoxels, sparse_conv2d


class EncoderBranch(nn.Module):
    """Intro conv + NAFBlock levels; :meth:`level` runs one level, :meth:`forward` all.

    ``forward(x)`` returns ``len(depths) + 1`` feature maps: after the blocks of each
    level (full, 1/2, 1/4 ... resolution) and the downsampled bottom features.
    """

    def __init__(self, in_channels: int, width: int, depths: Sequence[int]):
        super().__init__()
        self.intro = nn.Conv2d(in_channels, width, 3, padding=1)
        self.blocks = nn.ModuleList()
        self.downs = nn.ModuleList()
        c = width
        for d in depths:
            self.blocks.append(naf_stack(c, d))
            self.downs.append(Downsample(c))
            c *= 2
        self.out_channels = c

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = self.intro(x)
        feats = []
        for blocks, down in zip(self.blocks, self.downs):
            x = blocks(x)
            feats.append(x)
            x = down(x)
        feats.append(x)
        return feats


class StageNet(nn.Module):
    """Dual-branch encoder / single-branch decoder of one RDNet stage (module docstring).

    forward(image (B, image_channels, H, W), events (B, event_channels, H, W) or None)
    -> (B, out_channels, H, W).
    """

    def __init__(self, image_channels: int, event_channels: int, out_channels: int,
                 width: int, enc_depths: Sequence[int], middle_depth: int,
                 dec_depths: Sequence[int], fuse_into: str = "image", residual: bool = True):
        super().__init__()
        enc_depths, dec_depths = tuple(int(d) for d in enc_depths), tuple(int(d) for d in dec_depths)
        if len(enc_depths) != len(dec_depths):
            raise ValueError(f"enc_depths {enc_depths} and dec_depths {dec_depths} differ in length")
        if fuse_into not in ("image", "event"):
            raise ValueError(f"fuse_into must be 'image' or 'event', got {fuse_into!r}")
        if event_channels == 0 and fuse_into != "image":
            raise ValueError("without an event branch the decoder must read the image branch")
        if image_channels == 0 and fuse_into != "event":
            raise ValueError("without an image branch the decoder must read the event branch")
        if image_channels == 0 and event_channels == 0:
            raise ValueError("a stage needs an image or an event branch")
        recv_in = event_channels if fuse_into == "event" else image_channels
        if residual and recv_in != out_channels:
            raise ValueError(f"global residual needs out_channels == {recv_in}, got {out_channels}")
        self.image_channels, self.event_channels = image_channels, event_channels
        self.fuse_into, self.residual = fuse_into, residual
        self.levels = len(enc_depths)
        self.image_branch = EncoderBranch(image_channels, width, enc_depths) if image_channels else None
        self.event_branch = EncoderBranch(event_channels, width, enc_depths) if event_channels else None
        c = self.receiving.out_channels
        self.middle = naf_stack(c, middle_depth)
        self.ups = nn.ModuleList()
        self.decoders = nn.ModuleList()
        for d in reversed(dec_depths):
            self.ups.append(Upsample(c))
            c //= 2
            self.decoders.append(naf_stack(c, d))
        self.ending = nn.Conv2d(width, out_channels, 3, padding=1)
        if residual:  # start as the identity map: output = receiving input
            nn.init.zeros_(self.ending.weight)
            nn.init.zeros_(self.ending.bias)

    # --- branches ---------------------------------------------------------------------
    @property
    def receiving(self) -> EncoderBranch:
        return self.event_branch if self.fuse_into == "event" else self.image_branch

    @property
    def source(self) -> EncoderBranch | None:
        return self.image_branch if self.fuse_into == "event" else self.event_branch

    def _pad(self, x: torch.Tensor, mode: str) -> torch.Tensor:
        m = 2 ** self.levels
        H, W = x.shape[-2:]
        ph, pw = (-H) % m, (-W) % m
        if ph == 0 and pw == 0:
            return x
        return F.pad(x, (0, pw, 0, ph), mode=mode)

    def source_features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Multi-scale features of the source branch for input ``x`` (any size): one map
        per encoder level plus the bottom, each cropped to ceil(H / 2**level)."""
        if self.source is None:
            raise ValueError("this stage has no source branch")
        mode = "constant" if self.fuse_into == "image" else "replicate"
        H, W = x.shape[-2:]
        feats = self.source(self._pad(x, mode))
        return [f[..., :-(-H // 2 ** i), :-(-W // 2 ** i)] for i, f in enumerate(feats)]

    # --- forward ----------------------------------------------------------------------
    def forward(self, image: torch.Tensor | None, events: torch.Tensor | None = None) -> torch.Tensor:
        x, recv_in, H, W = self.decoded(image, events)
        out = self.ending(x)
        if self.residual:
            out = out + recv_in
        return out[..., :H, :W]

    def decoded(self, image: torch.Tensor | None, events: torch.Tensor | SparseVoxels | None = None):
        """Everything of :meth:`forward` before the output conv: ``(x, recv_in, H, W)``,
        the decoder's last features (B, width, H', W') and the receiving branch's input,
        both at the padded size H' x W' (module docstring), and the input size H x W.
        ``events`` may be a :class:`rdnet.nn.sparse.SparseVoxels` (one sample, inference)
        when the events are the receiving branch: its intro conv then reads the non-zero
        voxels alone and ``recv_in`` is None.
        ``forward`` is ``(ending(x) [+ recv_in])[..., :H, :W]``; a caller that needs only
        some output channels, or only some pixels, applies ``self.ending`` to ``x`` itself
        (:meth:`rdnet.nn.models.RestoreNet.sparse_heads`)."""
        sparse = isinstance(events, SparseVoxels)
        if sparse and self.fuse_into != "event":
            raise ValueError("sparse events feed the receiving event branch only (fuse_into='event')")
        ev_shape = None if events is None else (1, *events.shape) if sparse else tuple(events.shape)
        if self.image_branch is None:
            if image is not None:
                raise ValueError("this stage has no image branch: pass image=None")
            img = None
        else:
            if image is None or image.shape[1] != self.image_channels:
                got = None if image is None else image.shape[1]
                raise ValueError(f"expected {self.image_channels} image channels, got {got}")
            H, W = image.shape[-2:]
            img = self._pad(image, "replicate")
        if self.event_branch is not None:
            if events is None or ev_shape[1] != self.event_channels:
                got = None if events is None else ev_shape[1]
                raise ValueError(f"expected {self.event_channels} event channels, got {got}")
            if image is not None and tuple(ev_shape[-2:]) != tuple(image.shape[-2:]):
                raise ValueError(f"image {tuple(image.shape[-2:])} and events "
                                 f"{tuple(ev_shape[-2:])} sizes differ")
            evt = None if sparse else self._pad(events, "constant")
            if self.image_branch is None:
                H, W = ev_shape[-2:]
        else:
            evt = None
        recv_in, src_in = (evt, img) if self.fuse_into == "event" else (img, evt)
        src_feats = self.source(src_in) if self.source is not None else None

        branch = self.receiving
        if sparse:          # the intro conv from the non-zero voxels alone (rdnet.nn.sparse)
            m = 2 ** self.levels
            x = sparse_conv2d(events, branch.intro, (H + (-H) % m, W + (-W) % m))
        else:
            x = branch.intro(recv_in)
        skips = []
        for i, (blocks, down) in enumerate(zip(branch.blocks, branch.downs)):
            x = blocks(x)
            if src_feats is not None:
                x = x + src_feats[i]
            skips.append(x)
            x = down(x)
        if src_feats is not None:
            x = x + src_feats[-1]
        x = self.middle(x)
        for up, dec, skip in zip(self.ups, self.decoders, reversed(skips)):
            x = dec(up(x) + skip)
        return x, recv_in, H, W
