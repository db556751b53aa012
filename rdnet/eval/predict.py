"""Run a trained network over a pairs file (full frames, in batches) and score it.

Methods (:data:`METHODS`, the names of the study rows):

* ``blurry`` -- no network: the blurry input itself (the lower reference);
* ``deblur`` / ``deblurnet_matched`` -- a DeblurNet checkpoint fed the ``events`` voxels
  (undegraded or degraded);
* ``image_only`` -- the image-only baseline (no events);
* ``rdnet`` -- stage 1 then stage 2 on the ``events`` voxels (degraded in the paper);
  also scores the restored voxels;
* ``restore`` -- a stage-1 checkpoint alone (image-guided, frame-pair guided or
  events-only): restoration metrics only. A frame-pair restorer (task ``restore_frames``,
  :mod:`rdnet.nn.guide`) reads the guide its checkpoint stores, built from the pairs
  file's ``frame_first``/``frame_last``.

Stage 1 with the count output (``train.restore_output: counts``) reads the per-polarity
counts of the pairs file (``voxel_<events>_on``/``_off``); ``restored`` is then the
signed expected counts (what stage 2 reads). With the checkpoint's voxel -> event
decision (:func:`stage1_decision`) the predictions also hold ``restored_counts``: the
restored *events* as (n, 2, bins, H, W) ON/OFF counts (the fitted occupancy threshold
for the count output, ``round`` for the signed one), scored by
:func:`rdnet.eval.events.match_metrics` against ``counts_undegraded``. The restored
voxels and events come from one stage-1 pass (:func:`rdnet.eval.stage1.run_stage1`), and
a checkpoint file is read once per call (``loaded``: not at all). A pairs file whose
datasets fit in :data:`rdnet.train.data.PRELOAD_MAX_BYTES` is read whole once and kept in
memory while it is unchanged (the last such file only; :func:`_pairs_rows`): the stress
test and the restoration stage score many networks on one test file, and each row's
compressed chunk was decompressed again for every one of them. The rows are the same bytes.

``voxel_transform(voxels, index) -> voxels`` (optional) replaces the input voxels of a
batch before the network sees them: ``voxels`` (n, B, H, W) float32 numpy, ``index``
(n,) int64 rows of the pairs file; it must return an array of the same shape (used for
the event-denoising baselines, e.g. STCF/GEF-filtered events).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable, Iterator, Mapping, Sequence

import numpy as np
import torch

from rdnet.errors import ConfigError
from rdnet.eval import metrics as M
from rdnet.sim.blur import FRAME_KEYS
from rdnet.train.data import EVENT_KINDS, read_pairs_info, read_rows_whole, sample_datasets

log = logging.getLogger(__name__)

#: method -> network kind stored in its checkpoint (None: no network).
METHODS = {"blurry": None, "deblur": "deblur", "deblurnet_matched": "deblurnet_matched",
           "image_only": "image_only", "rdnet": "rdnet", "restore": "restore"}

VoxelTransform = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _device(name: str | torch.device) -> torch.device:
    from rdnet.train.loop import resolve_device
    return name if isinstance(name, torch.device) else resolve_device(str(name), key="device")


def load_method(kind: str, checkpoint: str | Path | None, pairs_path: str | Path,
                device: str | torch.device = "cpu", *, loaded: Mapping | None = None):
    """The network of ``checkpoint`` for method ``kind``, checked against the pairs
    file (kind, voxel bins, image channels); None for ``blurry``. ``loaded``: the
    checkpoint dict already read from ``checkpoint``
    (:func:`rdnet.train.checkpoint.read_checkpoint`): the file is then not read again."""
    return _load(kind, checkpoint, pairs_path, device, loaded)[0]


def _load(kind, checkpoint, pairs_path, device, loaded) -> tuple:
    """(model, checkpoint dict) of :func:`load_method` ((None, None) for ``blurry``),
    the checkpoint file read at most once (not at all with ``loaded``)."""
    if kind not in METHODS:
        raise ConfigError("method", f"unknown method {kind!r}; known: {', '.join(METHODS)}")
    if METHODS[kind] is None:
        if checkpoint is not None:
            raise ConfigError("checkpoint", f"method {kind!r} takes no checkpoint")
        return None, None
    if checkpoint is None:
        raise ConfigError("checkpoint", f"method {kind!r} needs a checkpoint")
    from rdnet.train.checkpoint import load_model, read_checkpoint
    info = read_pairs_info(pairs_path)
    ck = read_checkpoint(checkpoint) if loaded is None else loaded
    channels = info.channels
    if kind == "restore" and int(ck["model_args"].get("image_channels", 1)) == 0:
        channels = 0                                   # an events-only restorer (task restore_events)
    elif kind == "restore" and checkpoint_guide(ck) is not None:
        channels = info.channels + 1                   # a frame-pair restorer (task restore_frames)
    model = load_model(checkpoint, METHODS[kind], _device(device), bins=info.bins, image_channels=channels,
                       loaded=ck)
    return model, ck


#: (path, inode, mtime, size) -> {dataset: array}: the last pairs file read whole (:func:`_pairs_rows`).
_PAIRS_IN_MEMORY: dict = {}


def _pairs_rows(f, pairs_path: str | Path, info) -> Mapping:
    """name -> rows source of the open pairs file ``f``: its datasets as numpy arrays (the
    window frames too when the file has them, for a frame-pair restorer), read whole on the
    first call for this file (:func:`rdnet.train.data.read_rows_whole`) and kept until
    another file is read or this one changes; ``f`` itself when they do not fit in
    :data:`rdnet.train.data.PRELOAD_MAX_BYTES`."""
    st = Path(pairs_path).stat()
    key = (str(Path(pairs_path).resolve()), st.st_ino, st.st_mtime_ns, st.st_size)
    if key not in _PAIRS_IN_MEMORY:
        _PAIRS_IN_MEMORY.clear()
        arrays = read_rows_whole(f, ("level",) + sample_datasets(info, info.has_frame_pair))
        if arrays is None:
            return f
        _PAIRS_IN_MEMORY[key] = arrays
    return _PAIRS_IN_MEMORY[key]


def checkpoint_guide(ck: Mapping):
    """The frame-pair guide a checkpoint's network reads (:mod:`rdnet.nn.guide`), or None."""
    from rdnet.nn.guide import FramePairGuide
    return FramePairGuide.from_dict(ck.get("extra", {}).get("guide"))


def stage1_of(kind: str, model):
    """The RestoreNet of a loaded ``rdnet`` or ``restore`` model (None otherwise)."""
    if model is None:
        return None
    return model.restore if kind == "rdnet" else model if kind == "restore" else None


def stage1_decision(checkpoint: str | Path, *, loaded: Mapping | None = None) -> dict:
    """The voxel -> event decision stored with a stage-1 or RDNet checkpoint
    (:func:`rdnet.nn.decision.read_decision`: rounding for the signed output);
    ``loaded``: the checkpoint dict already read (the file is then not read)."""
    from rdnet.nn.decision import read_decision
    from rdnet.train.checkpoint import read_checkpoint
    ck = read_checkpoint(checkpoint) if loaded is None else loaded
    args = ck["model_args"]
    output = args.get("restore_output", "signed")
    return read_decision(ck.get("extra", {}).get("decision"), output)


def iter_predictions(kind: str, model, pairs_path: str | Path, events: str = "degraded", *,
                     voxel_transform: VoxelTransform | None = None, batch_size: int = 4,
                     device: str | torch.device = "cpu", indices: Sequence[int] | None = None,
                     progress: bool = False, decision: dict | None = None, guide=None) -> Iterator[dict]:
    """Batches of predictions: dicts of numpy arrays ``index``, ``level``, ``blurry``,
    ``sharp`` (target), ``voxel_undegraded``, ``voxel_degraded``, ``voxel`` (the input
    events after ``voxel_transform``), ``pred`` (predicted sharp image; absent for
    ``restore``) and ``restored`` (restored voxels; rdnet and restore); when the file has
    per-polarity voxels ``counts_undegraded``/``counts_degraded`` ((n, 2, bins, H, W),
    ON then OFF) and, with ``decision``, ``restored_counts`` (module docstring). ``guide``:
    the frame-pair guide of a ``restore`` model (:func:`checkpoint_guide`), which then
    reads it instead of the blurry frame."""
    import h5py
    from tqdm.auto import tqdm

    from rdnet.eval.stage1 import run_stage1
    if kind not in METHODS:
        raise ConfigError("method", f"unknown method {kind!r}; known: {', '.join(METHODS)}")
    if events not in EVENT_KINDS:
        raise ConfigError("events", f"must be one of {list(EVENT_KINDS)}, got {events!r}")
    if batch_size < 1:
        raise ConfigError("eval.batch_size", f"must be >= 1, got {batch_size}")
    info = read_pairs_info(pairs_path)
    rows = np.arange(info.n) if indices is None else np.asarray(indices, np.int64)
    if rows.size and (rows.min() < 0 or rows.max() >= info.n):
        raise ConfigError("indices", f"sample indices must lie in [0, {info.n})")
    dev = _device(device)
    if model is not None:
        model.eval().to(dev)
    stage1 = stage1_of(kind, model)
    split = stage1 is not None and stage1.output == "counts"
    if split and (voxel_transform is not None or not info.has_counts):
        raise ConfigError("method", f"{kind}: a count-output stage 1 reads the per-polarity voxels of the "
                          "pairs file (no voxel_transform; rerun the blur step for old files)")
    if decision is not None and stage1 is None:
        raise ConfigError("decision", f"method {kind!r} has no stage 1 to decide events for")
    if guide is not None and (kind != "restore" or not info.has_frame_pair):
        raise ConfigError("guide", f"a frame-pair guide goes with method restore on a pairs file with the "
                          f"window frames (frame_first, frame_last), not {kind!r} on {pairs_path}")
    bar = tqdm(total=int(rows.size), desc=f"predict {kind}", unit="sample", disable=(not progress) or None)
    with h5py.File(pairs_path, "r") as f, torch.inference_mode():
        src = _pairs_rows(f, pairs_path, info)
        for s in range(0, rows.size, batch_size):
            idx = rows[s:s + batch_size]
            order = np.argsort(idx, kind="stable")          # h5py wants increasing indices
            uniq, inv = np.unique(idx[order], return_inverse=True)
            def read(name):
                a = np.asarray(src[name][uniq.tolist()])
                out = np.empty((idx.size,) + a.shape[1:], a.dtype)
                out[order] = a[inv]
                return out
            b = {"index": idx.copy(), "level": read("level").astype(np.float64)}
            for name in ("blurry", "sharp", "voxel_undegraded", "voxel_degraded"):
                b[name] = read(name).astype(np.float32)
            vox = b[f"voxel_{events}"]
            if voxel_transform is not None:
                t = np.asarray(voxel_transform(vox.copy(), idx.copy()), np.float32)
                if t.shape != vox.shape:
                    raise ValueError(f"voxel_transform returned shape {t.shape}, expected {vox.shape}")
                vox = t
            b["voxel"] = vox
            if info.has_counts and (split or decision is not None):   # per-polarity counts, when used
                for k in EVENT_KINDS:
                    b[f"counts_{k}"] = np.stack([read(f"voxel_{k}_on"), read(f"voxel_{k}_off")],
                                                1).round().astype(np.int64)
            if kind == "blurry":
                b["pred"] = b["blurry"]
            else:
                img = torch.from_numpy(b["blurry"]).to(dev)
                v = torch.from_numpy(vox).to(dev)
                if split:                                  # (n, 2 * bins, H, W): ON bins then OFF bins
                    c = b[f"counts_{events}"]
                    v = torch.from_numpy(c.reshape(c.shape[0], -1, *c.shape[3:]).astype(np.float32)).to(dev)
                if stage1 is not None and not stage1.image_channels:
                    img = None                             # events-only restorer
                elif guide is not None:                    # the frame-pair restorer's image
                    first, last = (read(k) for k in FRAME_KEYS)
                    img = torch.from_numpy(np.stack([guide.image(a, z) for a, z in zip(first, last)])).to(dev)
                if stage1 is not None:                     # rdnet, restore: one stage-1 pass
                    restored, counts = run_stage1(stage1, img, v, decision)
                    b["restored"] = restored.float().cpu().numpy()
                    if kind == "rdnet":                    # what RDNet.forward does after stage 1
                        b["pred"] = model.stage2(img, restored, v).float().cpu().numpy()
                    if counts is not None:
                        b["restored_counts"] = counts
                elif kind == "image_only":
                    b["pred"] = model(img, None).float().cpu().numpy()
                else:
                    b["pred"] = model(img, v).float().cpu().numpy()
            bar.update(idx.size)
            yield b
    bar.close()


def predict(kind: str, checkpoint: str | Path | None, pairs_path: str | Path, events: str = "degraded",
            *, indices: Sequence[int] | None = None, voxel_transform: VoxelTransform | None = None,
            batch_size: int = 4, device: str | torch.device = "cpu", progress: bool = False,
            events_out: bool = False, loaded: Mapping | None = None) -> dict:
    """All predictions of method ``kind`` for the rows ``indices`` (all rows by default),
    concatenated into arrays (see :func:`iter_predictions`; ``events_out``: with
    ``restored_counts``, the checkpoint's decision applied). ``loaded``: the checkpoint
    dict already read from ``checkpoint`` (otherwise the file is read here, once). For
    figures and small sets; :func:`evaluate_row` streams instead."""
    model, ck = _load(kind, checkpoint, pairs_path, device, loaded)
    decision = stage1_decision(checkpoint, loaded=ck) if events_out else None
    parts = list(iter_predictions(kind, model, pairs_path, events, voxel_transform=voxel_transform,
                                  batch_size=batch_size, device=device, indices=indices,
                                  progress=progress, decision=decision,
                                  guide=None if ck is None else checkpoint_guide(ck)))
    if not parts:
        return {}
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _read_degrade(pairs_path) -> dict[str, np.ndarray]:
    import h5py
    with h5py.File(pairs_path, "r") as f:
        if "degrade" not in f:
            return {}
        return {k: np.asarray(f["degrade"][k], np.float64) for k in f["degrade"]}


def evaluate_row(kind: str, checkpoint: str | Path | None, pairs_path: str | Path,
                 events: str = "degraded", voxel_transform: VoxelTransform | None = None, *,
                 batch_size: int = 4, device: str | torch.device = "auto", level_bins: int = 5,
                 progress: bool = False) -> dict:
    """Score method ``kind`` (``checkpoint`` None for ``blurry``) on every row of the pairs
    file. Returns a JSON-able dict:

    ``method``, ``events``, ``checkpoint``, ``n``; ``psnr``, ``ssim`` (means of the
    per-image values of :mod:`rdnet.eval.metrics` over the ``n_images`` samples with
    motion, :func:`~rdnet.eval.metrics.image_means`; ``still_excluded`` samples without
    motion left out, in the breakdowns too; absent for ``restore``);
    ``by_level``: ``[{level_bin, level_lo, level_hi, n, psnr, ssim, ...}]`` over
    ``level_bins`` equal-width bins of ``/level`` (non-empty bins only);
    ``by_degradation``: the same grouped by :func:`~rdnet.eval.metrics.dominant_degradation`
    of ``/degrade`` (when present); ``per_sample``: ``index``, ``level`` and every
    per-sample metric; for rdnet/restore ``restoration`` (restored vs undegraded voxels)
    and ``restoration_input`` (the input voxels vs undegraded: no restoration).
    """
    dev = _device(device)
    model, ck = _load(kind, checkpoint, pairs_path, dev, None)
    per: dict[str, list] = {}
    rest_in: dict[str, list] = {}
    for b in iter_predictions(kind, model, pairs_path, events, voxel_transform=voxel_transform,
                              batch_size=batch_size, device=dev, progress=progress,
                              guide=None if ck is None else checkpoint_guide(ck)):
        per.setdefault("index", []).append(b["index"])
        per.setdefault("level", []).append(b["level"])
        if "pred" in b:
            for k, v in M.image_metrics_per_sample(b["pred"], b["sharp"]).items():
                per.setdefault(k, []).append(v)
            per.setdefault("moving", []).append(M.has_motion(b["blurry"], b["sharp"]))
        if "restored" in b:
            for k, v in M.restoration_per_sample(b["restored"], b["voxel_undegraded"],
                                                 b["voxel_degraded"]).items():
                per.setdefault(k, []).append(v)
            for k, v in M.restoration_per_sample(b["voxel"], b["voxel_undegraded"],
                                                 b["voxel_degraded"]).items():
                rest_in.setdefault(k, []).append(v)
    per_np = {k: np.concatenate(v) for k, v in per.items()}
    metric_keys = [k for k in per_np if k not in ("index", "level", "moving")]
    values = {k: per_np[k] for k in metric_keys}
    out: dict = {"method": kind, "events": None if kind in ("blurry", "image_only") else events,
                 "checkpoint": None if checkpoint is None else str(checkpoint),
                 "n": int(per_np["index"].size)}
    if "psnr" in values:                        # over the samples with motion (rdnet.eval.metrics)
        out.update(M.image_means(values, per_np["moving"]))
        values = M.motion_only(values, per_np["moving"])
    if "voxel_l1" in values:
        out["restoration"] = {k: float(np.mean(values[k])) for k in
                              ("voxel_l1", "voxel_psnr", "voxel_l1_all")}
        out["restoration_input"] = {k: float(np.mean(np.concatenate(rest_in[k]))) for k in
                                    ("voxel_l1", "voxel_psnr", "voxel_l1_all")}
    main = {k: values[k] for k in ("psnr", "ssim", "voxel_l1", "voxel_psnr") if k in values}
    out["by_level"] = M.by_level(main, per_np["level"], bins=level_bins)
    degrade = _read_degrade(pairs_path)
    if degrade:
        labels = M.dominant_degradation({k: v[per_np["index"]] for k, v in degrade.items()})
        out["by_degradation"] = M.group_means(main, labels)
    out["per_sample"] = {k: v.tolist() for k, v in per_np.items()}
    return out
