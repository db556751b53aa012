"""A learned per-event keep/drop classifier, EDnCNN-style: the baseline of issue 11 that
decides *each recorded event* (keep it unchanged or drop it) and can never invent one.

After Baldwin et al., "Event Probability Mask (EPM) and Event Denoising Convolutional
Neural Network (EDnCNN) for Neuromorphic Cameras" (CVPR 2020), scaled to the study's
sensor and to the parameter count of rdnet's events-only restorer.

Features (:func:`event_features`, a numba kernel, one pass over the stream). For every
event, from the events *before* it only (causal): the ``depth`` most recent timestamps of
each pixel of its (2r+1) x (2r+1) neighbourhood, per polarity (EDnCNN's FIFO time
surfaces), as ``exp(-(t - t_past) / tau_us)`` (1 = just now, 0 = never or long ago, 0
outside the sensor). Channels are ordered relative to the event: ``[same polarity,
opposite polarity] x [most recent, ..., depth-th most recent]``, a
(2 depth, 2r+1, 2r+1) float32 patch; the event's own polarity is a separate input.
The FIFOs (:class:`FeatureState`) are updated by every event after its features are
taken, and are carried from one call to the next: chunked processing of a stream gives
exactly the features of one call on the whole stream.

Classifier (:class:`EdnccnNet`): 3x3 convolutions without padding on the patch, then
fully connected layers (with the polarity appended) to one logit.

Labels (:func:`window_labels`) follow the event-level metrics of
:mod:`rdnet.eval.events` exactly: per voxel (hard time bin of the sample's window, pixel,
polarity) with r degraded and u undegraded events, ``min(r, u)`` are matched, so each of
the r events is real with probability ``min(r, u) / r`` (a soft label, EPM-like). The
labels of a window sum to its ``matched`` count of
:func:`rdnet.eval.events.match_metrics` (raw degraded events against the reference).

Training (:func:`train_ednccn`): the study's training pairs (windows and reference
counts) and training event streams; the last ``val_sequences`` sequences are held out
(:func:`rdnet.train.data.split_rows`, as for stage 1) and the keep threshold is the one
that maximises the event F1 of those held-out windows (:func:`fit_f1_threshold`, exact).
The checkpoint (:mod:`rdnet.train.checkpoint` layout, task ``ednccn``) holds the class,
its arguments, the config, the threshold and the validation metrics.

Inference (:class:`EdnccnRestorer`, ``rdnet restore --method ednccn``): keep an event
when its probability is >= the threshold; streamed (stateful, window independent).
"""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Mapping

import numba
import numpy as np
import torch
from torch import nn

from rdnet.baselines.stcf import NEVER_US
from rdnet.errors import ConfigError, FormatError, ModelNotFoundError, ValidationError
from rdnet.events.core import Events
from rdnet.restore.settings import EdnccnConfig  # noqa: F401  (the ``ednccn`` params section; re-exported)

log = logging.getLogger(__name__)

TASK = "ednccn"
#: where ``dvc repro`` (stage train_ednccn) writes the classifier, relative to the working directory.
STUDY_MODEL = Path("models/ednccn")
DECISION_RULE = "max_f1_heldout"


# --------------------------------------------------------------------------------------
# features

class FeatureState:
    """The per-pixel timestamp FIFOs carried between chunks of one stream: ``fifo``
    (2 polarities, depth, height, width) int64, most recent first (:data:`NEVER_US`:
    no event)."""

    def __init__(self, width: int, height: int, depth: int):
        self.width, self.height, self.depth = int(width), int(height), int(depth)
        self.fifo = np.full((2, self.depth, self.height, self.width), NEVER_US, np.int64)

    def check(self, events: Events) -> None:
        if (events.width, events.height) != (self.width, self.height):
            raise ValidationError("state", f"state is for a {self.width}x{self.height} sensor, events are "
                                           f"{events.width}x{events.height}")


@numba.njit(cache=True)
def _features_kernel(t, x, y, p, fifo, inv_tau, radius, out):
    n = t.shape[0]
    depth, height, width = fifo.shape[1], fifo.shape[2], fifo.shape[3]
    for i in range(n):
        ti, xi, yi, pi = t[i], np.int64(x[i]), np.int64(y[i]), np.int64(p[i])
        for side in range(2):                       # 0: same polarity, 1: opposite
            pol = pi if side == 0 else 1 - pi
            for j in range(depth):
                c = side * depth + j
                for dy in range(-radius, radius + 1):
                    yy = yi + dy
                    if yy < 0 or yy >= height:
                        continue
                    for dx in range(-radius, radius + 1):
                        xx = xi + dx
                        if xx < 0 or xx >= width:
                            continue
                        tp = fifo[pol, j, yy, xx]
                        if tp != NEVER_US:
                            out[i, c, dy + radius, dx + radius] = math.exp(-(ti - tp) * inv_tau)
        for j in range(depth - 1, 0, -1):           # push t_i after its features are taken
            fifo[pi, j, yi, xi] = fifo[pi, j - 1, yi, xi]
        fifo[pi, 0, yi, xi] = ti


def event_features(events: Events, radius: int, depth: int, tau_us: int,
                   state: FeatureState | None = None) -> np.ndarray:
    """(N, 2 depth, 2r+1, 2r+1) float32 causal time-surface patches of ``events`` (module
    docstring). ``state``: the FIFOs of the previous chunks of the same stream (updated in
    place); None starts from empty FIFOs."""
    if radius < 1 or depth < 1 or tau_us <= 0:
        raise ValidationError("features", f"need radius >= 1, depth >= 1, tau_us > 0; got {radius}, {depth}, {tau_us}")
    if state is None:
        state = FeatureState(events.width, events.height, depth)
    else:
        state.check(events)
        if state.depth != depth:
            raise ValidationError("state", f"state has depth {state.depth}, features asked for {depth}")
    side = 2 * radius + 1
    out = np.zeros((len(events), 2 * depth, side, side), np.float32)
    if len(events):
        _features_kernel(events.t, events.x, events.y, events.p, state.fifo, 1.0 / float(tau_us),
                         int(radius), out)
    return out


# --------------------------------------------------------------------------------------
# labels (the matching rule of rdnet.eval.events)

def window_voxels(events: Events, bins: int, t0_us: int, duration_us: int) -> tuple[int, int, np.ndarray]:
    """(i0, i1, v): the events ``events[i0:i1]`` that :func:`rdnet.eval.events.polarity_counts`
    counts for the window [t0, t0 + duration] and the flat index ``v`` of each one's entry
    in that (2, bins, H, W) grid (the same binning: tests compare the two)."""
    t0_us, duration_us = int(t0_us), int(duration_us)
    H, W = events.height, events.width
    i0 = int(np.searchsorted(events.t, t0_us, "left"))
    i1 = int(np.searchsorted(events.t, t0_us + duration_us, "right"))
    a = events.array[i0:i1]
    b = np.minimum((a["t"] - np.int64(t0_us)) * bins // duration_us, bins - 1)
    v = ((a["p"].astype(np.int64) * bins + b) * H + a["y"].astype(np.int64)) * W + a["x"].astype(np.int64)
    return i0, i1, v


def window_labels(events: Events, reference: np.ndarray, bins: int, t0_us: int, duration_us: int
                  ) -> tuple[int, int, np.ndarray, np.ndarray]:
    """(i0, i1, v, label) for the events ``events[i0:i1]`` of one window against the
    (2, bins, H, W) ``reference`` counts (the undegraded events, channel 0 OFF, 1 ON):
    ``label = min(r, u) / r`` of the event's voxel (module docstring), float32."""
    i0, i1, v = window_voxels(events, bins, t0_us, duration_us)
    u = np.asarray(reference).ravel()
    r = np.bincount(v, minlength=u.size)
    if r.size != u.size:
        raise ValidationError("reference", f"reference has {u.size} entries, the window grid {r.size}")
    frac = np.minimum(r, u) / np.maximum(r, 1)
    return i0, i1, v, frac[v].astype(np.float32)


def fit_f1_threshold(prob: np.ndarray, voxel: np.ndarray, reference: np.ndarray) -> tuple[float, dict]:
    """The keep threshold (keep ``prob >= threshold``) with the highest event F1 of
    :func:`rdnet.eval.events.match_metrics` against ``reference`` (flat reference counts;
    ``voxel``: each event's flat index into it), exact over every distinct threshold:
    in each voxel the most probable events are matched first, up to its reference count.
    Ties of F1 go to the higher threshold. Returns (threshold, {"f1", "kept", "matched"})."""
    p = np.asarray(prob, np.float64)
    v = np.asarray(voxel, np.int64)
    u = np.asarray(reference, np.int64).ravel()
    if p.size == 0:
        return 0.5, {"f1": 0.0, "kept": 0, "matched": 0}
    by_vox = np.lexsort((-p, v))                                     # voxel, then most probable first
    vs = v[by_vox]
    start = np.r_[0, np.flatnonzero(vs[1:] != vs[:-1]) + 1]
    rank = np.arange(vs.size) - np.repeat(start, np.diff(np.r_[start, vs.size]))
    hit = np.empty(p.size, np.int64)
    hit[by_vox] = rank < u[vs]
    order = np.argsort(-p, kind="stable")
    ps = p[order]
    matched = np.cumsum(hit[order])
    kept = np.arange(1, p.size + 1)
    f1 = 2.0 * matched / (kept + u.sum())
    f1 = np.where(np.r_[ps[1:] != ps[:-1], True], f1, -1.0)         # only thresholds that keep whole ties
    k = int(np.argmax(f1))
    return float(ps[k]), {"f1": float(f1[k]), "kept": int(kept[k]), "matched": int(matched[k])}


# --------------------------------------------------------------------------------------
# the classifier

class EdnccnNet(nn.Module):
    """Per-event keep logit from a (2 depth, 2r+1, 2r+1) time-surface patch and the
    event's polarity (module docstring). ``config`` holds the constructor arguments."""

    def __init__(self, radius: int = 3, depth: int = 2, conv_channels=(16, 32), hidden=(192, 96)):
        super().__init__()
        self.config = {"radius": int(radius), "depth": int(depth),
                       "conv_channels": [int(c) for c in conv_channels], "hidden": [int(h) for h in hidden]}
        layers, c_in, side = [], 2 * depth, 2 * radius + 1
        for c in conv_channels:
            layers += [nn.Conv2d(c_in, int(c), 3), nn.ReLU()]
            c_in, side = int(c), side - 2
        if side < 1:
            raise ConfigError("ednccn.conv_channels", "too many convolutions for the patch")
        self.conv = nn.Sequential(*layers)
        fc, f_in = [], c_in * side * side + 1                       # + the event's polarity
        for h in hidden:
            fc += [nn.Linear(f_in, int(h)), nn.ReLU()]
            f_in = int(h)
        fc.append(nn.Linear(f_in, 1))
        self.fc = nn.Sequential(*fc)

    def forward(self, patch: torch.Tensor, polarity: torch.Tensor) -> torch.Tensor:
        z = self.conv(patch).flatten(1)
        s = polarity.to(z.dtype).reshape(-1, 1) * 2.0 - 1.0        # ON +1, OFF -1
        return self.fc(torch.cat([z, s], 1)).squeeze(1)


def parameter_count(net: nn.Module) -> int:
    return int(sum(p.numel() for p in net.parameters()))


def predict_proba(net: EdnccnNet, patches: np.ndarray, polarity: np.ndarray, device: torch.device,
                  batch_size: int = 8192) -> np.ndarray:
    """Keep probabilities (float32) of events given their patches and polarities."""
    out = np.empty(len(patches), np.float32)
    net.eval()
    with torch.inference_mode():
        for s in range(0, len(patches), batch_size):
            x = torch.from_numpy(patches[s:s + batch_size]).to(device)
            pol = torch.from_numpy(np.asarray(polarity[s:s + batch_size], np.float32)).to(device)
            out[s:s + batch_size] = torch.sigmoid(net(x, pol)).cpu().numpy()
    return out


# --------------------------------------------------------------------------------------
# data and training

def _window_data(pairs_path: Path, events_dir: Path, rows: np.ndarray, cfg: EdnccnConfig,
                 rng: np.random.Generator | None, max_events: int | None, progress: bool):
    """Patches, polarities, soft labels, flat voxel ids (into ``reference``) and the
    (n, 2, bins, H, W) reference counts of the windows ``rows`` of a pairs file; at most ``max_events``
    events, drawn uniformly (``rng``), when given."""
    import h5py
    from tqdm import tqdm

    from rdnet.events.io import read_events
    from rdnet.train.data import read_pairs_voxel
    bins = int(read_pairs_voxel(pairs_path)["bins"])
    with h5py.File(pairs_path, "r") as f:
        seq = np.asarray(f["sequence"])
        t0 = np.asarray(f["t0_us"])
        dur = np.asarray(f["duration_us"])
        if "voxel_undegraded_on" not in f:
            raise FormatError(pairs_path, "voxel_undegraded_on", "missing (the labels need per-polarity counts)")
        ref = np.stack([f["voxel_undegraded_off"][...][rows], f["voxel_undegraded_on"][...][rows]], 1)
    ref = np.rint(ref).astype(np.int64)                            # (n, 2, bins, H, W): OFF, ON
    files = sorted(Path(events_dir).glob("seq_*.h5"))
    grid = ref[0].size if len(rows) else 0
    # pass 1: each window's event range and labels (no features yet)
    seqs, parts = {}, []                    # parts: (sequence, i0, i1, polarity, labels, voxel ids)
    for s in np.unique(seq[rows]):
        if s >= len(files):
            raise FormatError(events_dir, "sequence", f"pairs row names sequence {s}, only {len(files)} seq_*.h5")
        ev = seqs[s] = read_events(files[s])
        for k in np.flatnonzero(seq[rows] == s):
            i0, i1, v, lab = window_labels(ev, ref[k], bins, int(t0[rows[k]]), int(dur[rows[k]]))
            parts.append((s, i0, i1, ev.p[i0:i1], lab, v + k * grid))
    sizes = np.array([p[2] - p[1] for p in parts], np.int64)
    total = int(sizes.sum())
    pick = None                             # the events kept, drawn before any feature is built
    if max_events is not None and total > max_events:
        pick = np.sort(rng.choice(total, max_events, replace=False))
    starts = np.concatenate([[0], np.cumsum(sizes)])
    # pass 2: features per sequence (causal over its whole stream), only the kept rows copied
    out = [[], [], [], []]
    for s in tqdm(list(seqs), desc="ednccn features", disable=not progress or None):
        feats = event_features(seqs[s], cfg.radius, cfg.depth, cfg.tau_us)
        for j in (j for j, p in enumerate(parts) if p[0] == s):
            _, i0, i1, pol, lab, vox = parts[j]
            keep = (slice(None) if pick is None else
                    pick[np.searchsorted(pick, starts[j]):np.searchsorted(pick, starts[j + 1])] - starts[j])
            for acc, a in zip(out, (feats[i0:i1], pol, lab, vox)):
                acc.append(a[keep])
        del feats
    cat = [np.concatenate(a) if a else np.zeros(0) for a in out]
    return cat[0], cat[1], cat[2], cat[3], ref


def train_ednccn(cfg: EdnccnConfig, pairs_path: str | Path, events_dir: str | Path, out: str | Path, *,
                 progress: bool = True) -> dict:
    """Train the classifier on the training pairs/events, fit the keep threshold on the
    held-out sequences, write ``out/model.pt``; returns the training record (metrics,
    wall time). Torch's global random state and thread count are restored afterwards."""
    threads = torch.get_num_threads()
    try:
        with torch.random.fork_rng(devices=[]):
            return _train(cfg, pairs_path, events_dir, out, progress)
    finally:
        torch.set_num_threads(threads)


def _train(cfg: EdnccnConfig, pairs_path, events_dir, out, progress: bool) -> dict:
    from tqdm import tqdm

    from rdnet.config import to_dict
    from rdnet.eval.events import match_metrics
    from rdnet.train.checkpoint import make_checkpoint, save_checkpoint
    from rdnet.train.data import split_rows

    start = time.perf_counter()
    pairs_path, events_dir = Path(pairs_path), Path(events_dir)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    from rdnet.train.loop import resolve_device
    device = resolve_device(cfg.device, key="ednccn.device")
    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    try:
        train_rows, val_rows = split_rows(pairs_path, cfg.val_sequences)
    except ConfigError as e:
        raise ConfigError("ednccn.val_sequences", str(e).split(": ", 1)[-1]) from None
    X, P, Y, _, _ = _window_data(pairs_path, events_dir, train_rows, cfg, rng, cfg.max_train_events, progress)
    net = EdnccnNet(cfg.radius, cfg.depth, cfg.conv_channels, cfg.hidden).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    steps = cfg.epochs * math.ceil(len(Y) / cfg.batch_size)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(steps, 1))
    Xt, Pt, Yt = torch.from_numpy(X), torch.from_numpy(P.astype(np.float32)), torch.from_numpy(Y)
    losses = []
    bar = tqdm(total=steps, desc="train ednccn", unit="step", disable=not progress or None)
    for epoch in range(cfg.epochs):
        net.train()
        order = torch.from_numpy(rng.permutation(len(Y)))
        total = 0.0
        for s in range(0, len(Y), cfg.batch_size):
            idx = order[s:s + cfg.batch_size]
            logit = net(Xt[idx].to(device), Pt[idx].to(device))
            loss = nn.functional.binary_cross_entropy_with_logits(logit, Yt[idx].to(device))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
            bar.update(1)
        losses.append(total / max(len(Y), 1))
        log.info("ednccn epoch %d: train BCE %.4f", epoch + 1, losses[-1])
    bar.close()
    del Xt, X
    Xv, Pv, Yv, Vv, Uv = _window_data(pairs_path, events_dir, val_rows, cfg, None, None, progress)
    prob = predict_proba(net, Xv, Pv, device)
    threshold, _ = fit_f1_threshold(prob, Vv, Uv)
    kept = np.bincount(Vv[prob >= threshold], minlength=Uv.size).reshape(Uv.shape)
    raw = np.bincount(Vv, minlength=Uv.size).reshape(Uv.shape)
    val = {k: float(v) for k, v in match_metrics(kept, Uv).items()}
    val_raw = {k: float(v) for k, v in match_metrics(raw, Uv).items()}
    val_bce = float(nn.functional.binary_cross_entropy(torch.from_numpy(prob).clamp(1e-7, 1 - 1e-7),
                                                       torch.from_numpy(Yv)))
    decision = {"rule": DECISION_RULE, "threshold": threshold,
                "fitted_on": f"{len(val_rows)} windows of the last {cfg.val_sequences} training sequences",
                "val_events": int(len(Yv)), "val_metrics": val, "val_metrics_raw": val_raw, "val_bce": val_bce}
    log.info("ednccn threshold %.4f: held-out F1 %.4f (raw %.4f), count ratio %.3f", threshold, val["f1"],
             val_raw["f1"], val["count_ratio"])
    metrics = {"train_bce": losses, "train_events": int(len(Y)), "train_windows": int(len(train_rows)),
               "parameters": parameter_count(net)}
    ck = make_checkpoint(net, TASK, {"kind": TASK, **net.config}, config=to_dict(cfg), step=steps,
                         extra={"decision": decision, "metrics": metrics, "tau_us": int(cfg.tau_us)},
                         with_rng=False)
    path = save_checkpoint(Path(out) / "model.pt", ck)
    return {"checkpoint": str(path), "decision": decision, **metrics, "steps": steps,
            "wall_s": time.perf_counter() - start, "device": str(device)}


# --------------------------------------------------------------------------------------
# inference

class EdnccnRestorer:
    """``rdnet restore --method ednccn`` (a :class:`rdnet.restore.base.Restorer`): keeps
    the events whose keep probability is >= the checkpoint's threshold; the feature FIFOs
    are carried across windows (the result does not depend on the windows)."""

    name = "ednccn"
    needs_frames = False
    window_us = None

    def __init__(self, net: EdnccnNet, tau_us: int, threshold: float, *, device="cpu", source: str = "",
                 info: Mapping | None = None):
        self.net, self.tau_us, self.threshold = net.to(device).eval(), int(tau_us), float(threshold)
        self.device = torch.device(device)
        self.state: FeatureState | None = None
        self.info = {"kind": "classifier", "checkpoint": source, "threshold": self.threshold,
                     "tau_us": self.tau_us, **net.config, **dict(info or {})}

    def keep_probability(self, events: Events, state: FeatureState | None = None) -> np.ndarray:
        """Keep probabilities of the next events of a stream whose FIFOs are ``state``
        (updated in place; None: this restorer's own streaming state)."""
        cfg = self.net.config
        if state is None:
            if self.state is None:
                self.state = FeatureState(events.width, events.height, cfg["depth"])
            state = self.state
        feats = event_features(events, cfg["radius"], cfg["depth"], self.tau_us, state)
        return predict_proba(self.net, feats, events.p, self.device)

    def restore(self, events, t0_us=None, t1_us=None, frame=None) -> Events:
        """The kept events of the next chunk of the stream (window bounds and frame unused)."""
        if len(events) == 0:
            return events
        return events.select(self.keep_probability(events) >= self.threshold)

    def filter_stream(self, events: Events) -> Events:
        """The kept events of a whole stream, from empty FIFOs (the streaming state of
        :meth:`restore` is left untouched)."""
        if len(events) == 0:
            return events
        state = FeatureState(events.width, events.height, self.net.config["depth"])
        return events.select(self.keep_probability(events, state) >= self.threshold)


def load_ednccn(checkpoint: str | Path | None = None, *, device: str = "cpu",
                device_key: str = "restore.device") -> EdnccnRestorer:
    """The classifier of ``checkpoint`` (a ``model.pt`` or a folder holding one; default
    :data:`STUDY_MODEL`), validated: a ConfigError naming the file and the field when it
    is missing, unreadable or not an EDnCNN checkpoint."""
    from rdnet.restore.learned import _checkpoint_file, _fail
    from rdnet.train.checkpoint import read_checkpoint
    from rdnet.train.loop import resolve_device
    where = Path(checkpoint) if checkpoint is not None else STUDY_MODEL
    path = _checkpoint_file(where)
    if path is None:
        hint = "" if checkpoint is not None else " (train it with `dvc repro train_ednccn`, or pass --checkpoint)"
        raise ModelNotFoundError("checkpoint", f"{where}: no EDnCNN model.pt found{hint}")
    try:
        ck = read_checkpoint(path)
    except FormatError as e:
        raise ConfigError("checkpoint", str(e)) from None
    if ck["task"] != TASK or ck["model_class"] != EdnccnNet.__name__:
        raise _fail(path, "task", f"holds a {ck['task']!r} checkpoint ({ck['model_class']}), not an EDnCNN classifier")
    decision = ck.get("extra", {}).get("decision") or {}
    if not isinstance(decision.get("threshold"), float):
        raise _fail(path, "extra.decision.threshold", "missing (the keep threshold is fitted in training)")
    try:
        net = EdnccnNet(**ck["model_config"])
        net.load_state_dict(ck["state_dict"])
    except (TypeError, RuntimeError, ConfigError) as e:
        raise _fail(path, "state_dict", f"does not fit EdnccnNet({ck['model_config']}): "
                    f"{str(e).strip().splitlines()[0][:200]}") from None
    tau = ck.get("extra", {}).get("tau_us")
    if not isinstance(tau, int) or tau <= 0:
        raise _fail(path, "extra.tau_us", f"must be a positive int, got {tau!r}")
    log.info("EDnCNN classifier %s (threshold %.4f)", path, decision["threshold"])
    return EdnccnRestorer(net, tau, decision["threshold"], device=resolve_device(device, key=device_key), source=str(path),
                          info={"val_metrics": decision.get("val_metrics"), "train": ck.get("config")})
