"""Ablation rows of the study (``ablation`` section): every row is data.

A row names a method and its inputs::

    rdnet:          {method: rdnet, checkpoint: models/rdnet, events: degraded, paper_psnr: 37.33}
    stcf:           {method: deblur, checkpoint: models/deblur_undegraded, events: degraded,
                     filter: stcf}

``checkpoint`` is a network directory of the study (one ``seed<k>/model.pt`` per training
seed, :mod:`rdnet.study.config`) or a single ``.pt`` file.
methods: ``deblur`` (DeblurNet fed ``events``), ``deblurnet_matched`` (the DeblurNet
widened to RDNet's parameter count), ``rdnet`` (stage 1 + 2), ``image_only``,
``edi`` (Pan et al. 2019 on the ``events`` voxels), ``blurry`` (the input itself).
``filter`` (deblur rows only) denoises the input events first: ``rdnet`` (RDNet's stage 1
of ``filter_checkpoint``, seed by seed), ``stcf`` (spatio-temporal
correlation filter on the raw event stream, then re-voxelized) or ``gef`` (image-guided
filtering of the voxels).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Literal, Optional

import numpy as np
from tqdm import tqdm

from rdnet.config import at_most, check_bounds, from_dict, positive
from rdnet.errors import ConfigError
from rdnet.restore.settings import RESTORE_UPPER_BOUNDS, check_stcf_k

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FilterConfig:
    """Parameters of the event-denoising baselines (``ablation.filters``; the bounds of the
    ``restore`` keys of the same names)."""

    stcf_tau_us: int = 10000
    stcf_k: int = 2
    stcf_radius: int = 1
    gef_radius: int = 2
    gef_eps: float = 0.01

    def __post_init__(self):
        for f in fields(self):
            positive(f"ablation.filters.{f.name}", getattr(self, f.name), allow_zero=False)
        check_bounds("ablation.filters", self, {k: v for k, v in RESTORE_UPPER_BOUNDS.items() if hasattr(self, k)})
        check_stcf_k("ablation.filters.stcf_k", self.stcf_k, self.stcf_radius)


@dataclass(frozen=True)
class RowConfig:
    method: Literal["deblur", "deblurnet_matched", "rdnet", "image_only", "edi", "blurry"]
    checkpoint: Optional[str] = None
    events: Literal["degraded", "undegraded"] = "degraded"
    filter: Optional[Literal["stcf", "gef", "rdnet"]] = None
    filter_checkpoint: Optional[str] = None  # filter rdnet: the RDNet whose stage 1 restores the events
    needs: Optional[str] = None          # the extra DVC dependency of the row (dvc.yaml)
    paper_psnr: Optional[float] = None
    label: str = ""

    def __post_init__(self):
        if self.method in ("deblur", "deblurnet_matched", "rdnet", "image_only") and not self.checkpoint:
            raise ConfigError("ablation.rows.*.checkpoint", f"method {self.method} needs a checkpoint")
        if self.filter and self.method != "deblur":
            raise ConfigError("ablation.rows.*.filter", "filters apply to deblur rows only")
        if (self.filter == "rdnet") != bool(self.filter_checkpoint):
            raise ConfigError("ablation.rows.*.filter_checkpoint", "is given with filter rdnet, and only then")
        if self.paper_psnr is not None:       # printed beside the row: 100 dB is an RMS error of 1e-5
            positive("ablation.rows.*.paper_psnr", self.paper_psnr)
            at_most("ablation.rows.*.paper_psnr", self.paper_psnr, 100.0)


#: bounds of the ``ablation`` keys: samples per network call in memory at once (as
#: ``train.batch_size``), equal-width bins of the degradation level in the report
ABLATION_UPPER_BOUNDS = {"batch_size": 4096, "level_bins": 100}


@dataclass(frozen=True)
class AblationConfig:
    rows: dict = field(default_factory=dict)
    filters: FilterConfig = FilterConfig()
    batch_size: int = 8
    device: str = "auto"
    level_bins: int = 4

    def __post_init__(self):
        for key in ABLATION_UPPER_BOUNDS:
            positive(f"ablation.{key}", getattr(self, key), allow_zero=False)
        check_bounds("ablation", self, ABLATION_UPPER_BOUNDS)

    def row(self, row_id: str) -> RowConfig:
        if row_id not in self.rows:
            raise ConfigError(f"ablation.rows.{row_id}", f"unknown row; rows: {', '.join(self.rows)}")
        return from_dict(RowConfig, self.rows[row_id], f"ablation.rows.{row_id}")


class _EventFilterTransform:
    """An event-level filter run on each raw test sequence (``events_dir/seq_*.h5``, row
    ``sequence`` = file index), restricted to each sample's window: its signed voxels
    (``__call__``, a ``voxel_transform``) or per-polarity counts (:meth:`counts`).
    ``whole(events) -> events`` filters a whole sequence (STCF, BAF: their timestamp maps
    see the history before the window); ``window(events, t0, t1, row) -> events`` filters
    the events of one window (GEF: guided by the sample's blurry frame)."""

    def __init__(self, pairs_path: Path, events_dir: Path, bins: int, mode: str, *, whole=None, window=None):
        import h5py
        with h5py.File(pairs_path, "r") as f:
            self.seq = np.asarray(f["sequence"])
            self.t0 = np.asarray(f["t0_us"])
            self.dur = np.asarray(f["duration_us"])
        self.files = sorted(Path(events_dir).glob("seq_*.h5"))
        self.bins, self.mode, self.whole, self.window = bins, mode, whole, window
        self._cache: dict[int, object] = {}

    def events(self, s: int):
        if s not in self._cache:
            from rdnet.events.io import read_events
            ev = read_events(self.files[s])
            self._cache = {s: ev if self.whole is None else self.whole(ev)}
        return self._cache[s]

    def split(self, i: int) -> np.ndarray:
        """(2, bins, H, W) ON/OFF grid of the filtered events of sample ``i``."""
        from rdnet.events.voxel import voxel_grid
        t0, dur = int(self.t0[i]), int(self.dur[i])
        ev = self.events(int(self.seq[i]))
        if self.window is not None:
            ev = self.window(ev.slice_time(t0, t0 + dur + 1), t0, t0 + dur, i)   # t0 <= t <= t0 + dur
        return voxel_grid(ev, self.bins, t0, dur, mode=self.mode, polarity="split")

    def counts(self, index: np.ndarray) -> np.ndarray:
        """(n, 2, bins, H, W) int64 ON/OFF counts of the samples ``index``."""
        return np.stack([np.rint(self.split(int(i))) for i in index]).astype(np.int64)

    def __call__(self, voxels: np.ndarray, index: np.ndarray) -> np.ndarray:
        from rdnet.eval.stage1 import signed_counts
        return np.stack([signed_counts(self.split(int(i))) for i in index])


def _pairs_mode(pairs_path: Path) -> tuple[int, str]:
    from rdnet.train.data import read_pairs_voxel
    v = read_pairs_voxel(pairs_path)
    return v["bins"], v["mode"] or "hard"


def event_filter(name: str, pairs_path: Path, events_dir: Path, cfg: FilterConfig,
                 baf_dt_us: int = 10000, gef_bins: int = 5, checkpoint: Path | None = None,
                 device: str = "cpu") -> _EventFilterTransform:
    """The event-level baseline ``name`` (stcf, baf, gef, ednccn) on the test events of each
    sample's window (:class:`_EventFilterTransform`); GEF is
    :class:`rdnet.restore.base.GefRestorer` (mask mode) guided by the sample's blurry frame;
    ednccn is the per-event classifier of ``checkpoint`` (:mod:`rdnet.restore.ednccn`, on
    ``device``) on each whole sequence."""
    bins, mode = _pairs_mode(pairs_path)
    if name == "ednccn":
        from rdnet.restore.ednccn import load_ednccn
        clf = load_ednccn(checkpoint, device=device, device_key="ablation.device")
        return _EventFilterTransform(pairs_path, events_dir, bins, mode, whole=clf.filter_stream)
    if name == "stcf":
        from rdnet.baselines.stcf import stcf_filter
        return _EventFilterTransform(pairs_path, events_dir, bins, mode, whole=lambda ev: stcf_filter(
            ev, cfg.stcf_tau_us, cfg.stcf_k, cfg.stcf_radius))
    if name == "baf":
        from rdnet.baselines.baf import baf_filter
        return _EventFilterTransform(pairs_path, events_dir, bins, mode, whole=lambda ev: baf_filter(ev, baf_dt_us))
    if name == "gef":
        import h5py
        from rdnet.config import from_dict
        from rdnet.restore.base import GefRestorer
        from rdnet.restore.settings import RestoreConfig
        gef = GefRestorer(from_dict(RestoreConfig, {"gef_radius": cfg.gef_radius, "gef_eps": cfg.gef_eps,
                                                    "gef_bins": gef_bins, "gef_mode": "mask"}, "restore"))
        with h5py.File(pairs_path, "r") as f:
            blurry = np.asarray(f["blurry"])
        return _EventFilterTransform(pairs_path, events_dir, bins, mode,
                                     window=lambda ev, t0, t1, i: gef.restore(ev, t0, t1, blurry[i]))
    raise ConfigError("ablation.filter", f"unknown event filter {name!r}")


class _GefTransform:
    def __init__(self, pairs_path: Path, cfg: FilterConfig):
        import h5py
        with h5py.File(pairs_path, "r") as f:
            self.blurry = np.asarray(f["blurry"])
        self.cfg = cfg

    def __call__(self, voxels: np.ndarray, index: np.ndarray) -> np.ndarray:
        from rdnet.baselines.gef import gef_voxel
        return np.stack([gef_voxel(v, self.blurry[i], self.cfg.gef_radius, self.cfg.gef_eps)
                         for v, i in zip(voxels, index)])


class _RestoreTransform:
    """The degraded voxels of each sample restored by RDNet's stage 1 (``checkpoint``: an
    RDNet or stage-1 checkpoint), computed once for the whole test set."""

    def __init__(self, pairs_path: Path, checkpoint: Path, batch_size: int, device: str):
        from rdnet.eval.predict import predict
        from rdnet.train.checkpoint import read_checkpoint
        ck = read_checkpoint(checkpoint)                  # read once: predict reuses it
        kind = ck["model_kind"]
        if kind not in ("rdnet", "restore"):
            from rdnet.errors import FormatError
            raise FormatError(checkpoint, "model_kind", f"filter rdnet needs an RDNet or restore checkpoint, got {kind!r}")
        self.restored = predict(kind, checkpoint, pairs_path, "degraded", batch_size=batch_size,
                                device=device, loaded=ck)["restored"]

    def __call__(self, voxels: np.ndarray, index: np.ndarray) -> np.ndarray:
        return self.restored[np.asarray(index)]


def voxel_filter(name: str | None, pairs_path: Path, events_dir: Path | None, cfg: FilterConfig,
                 checkpoint: Path | None = None, batch_size: int = 8, device: str = "auto"):
    """The ``voxel_transform`` of a filter name (None: no filtering); ``checkpoint`` is the
    RDNet of filter ``rdnet``."""
    if name is None:
        return None
    if name == "rdnet":
        return _RestoreTransform(pairs_path, checkpoint, batch_size, device)
    if name == "gef":
        return _GefTransform(pairs_path, cfg)
    if name == "stcf":
        if events_dir is None:
            raise ConfigError("ablation.filter", "stcf needs the raw test events (--events-dir)")
        return event_filter("stcf", pairs_path, events_dir, cfg)
    raise ConfigError("ablation.filter", f"unknown filter {name!r}")


def evaluate_edi(pairs_path: Path, events: str, level_bins: int) -> dict:
    """EDI (Pan et al., CVPR 2019) on every test sample, from its voxel grid."""
    from rdnet.baselines.edi import edi_from_voxel
    from rdnet.eval import metrics as M
    from rdnet.sim.blur import read_pairs
    preds, sharp, blurry, levels = [], [], [], []
    with read_pairs(pairs_path) as pf:
        for i in tqdm(range(len(pf)), desc="edi", disable=None):
            s = pf[i]
            out, _ = edi_from_voxel(s["blurry"], s[f"voxel_{events}"])
            preds.append(np.clip(out, 0, 1)); sharp.append(s["sharp"]); blurry.append(s["blurry"])
            levels.append(float(s["level"]))
    per = M.image_metrics_per_sample(np.stack(preds), np.stack(sharp))
    moving = M.has_motion(np.stack(blurry), np.stack(sharp))
    return {"method": "edi", "events": events, "n": len(preds), **M.image_means(per, moving),
            "by_level": M.by_level(M.motion_only(per, moving), np.array(levels), bins=level_bins),
            "per_sample": {"level": levels, **{k: v.tolist() for k, v in per.items()}, "moving": moving.tolist()}}


def mean_over_seeds(results: list[dict]) -> dict:
    """Merge the results of one row trained with several seeds: numbers of the same
    place are averaged (lists element-wise, so ``by_level`` bins and per-sample values
    are seed means), text is kept from the first. Structures must agree."""
    first = results[0]
    if isinstance(first, dict):
        return {k: mean_over_seeds([r[k] for r in results]) for k in first}
    if isinstance(first, list) and all(isinstance(r, list) and len(r) == len(first) for r in results):
        return [mean_over_seeds([r[i] for r in results]) for i in range(len(first))]
    if isinstance(first, bool) or not isinstance(first, (int, float)):
        return first
    vals = [float(r) for r in results]
    if isinstance(first, int) and all(v == vals[0] for v in vals):
        return first
    return float(np.mean(vals))


def count_grids(f, which: str) -> np.ndarray:
    """(N, 2, bins, H, W) int64 per-polarity event counts of an open pairs file, ON first:
    ``voxel_<which>_on`` / ``_off`` (``which``: undegraded or degraded)."""
    return np.rint(np.stack([np.asarray(f[f"voxel_{which}_on"]), np.asarray(f[f"voxel_{which}_off"])], 1)
                   ).astype(np.int64)


def seed_spread(values) -> float:
    """Sample standard deviation (ddof 1) of per-seed values; 0 for a single seed."""
    v = np.asarray(values, np.float64)
    return float(np.std(v, ddof=1)) if v.size > 1 else 0.0


def evaluate_ablation_row(cfg: AblationConfig, row_id: str, pairs_path: Path,
                          events_dir: Path | None = None, seeds=(0,)) -> dict:
    """Metrics of one row on the test pairs: ``psnr``, ``ssim``, ``by_level``, ...

    Trained rows are scored once per training seed (the checkpoint of each seed,
    :func:`rdnet.study.config.seed_checkpoint`): ``psnr``/``ssim`` are the means over
    seeds, ``psnr_std``/``ssim_std`` the sample spread, ``psnr_seeds``/``ssim_seeds`` the
    per-seed values, and the breakdowns the seed means. Untrained rows (EDI, the blurry
    input) are deterministic and scored once (``seeds`` empty)."""
    from rdnet.study.config import seed_checkpoint
    row = cfg.row(row_id)
    if row.method == "edi":
        runs, used = [evaluate_edi(pairs_path, row.events, cfg.level_bins)], []
    else:
        from rdnet.eval.predict import evaluate_row
        if row.filter == "rdnet" and row.events != "degraded":
            raise ConfigError(f"ablation.rows.{row_id}.events", "filter rdnet restores degraded events")
        used = list(seeds) if row.checkpoint else []
        # seed-independent filters are built once; RDNet's stage 1 is the one of each seed
        fixed = None if row.filter == "rdnet" else voxel_filter(row.filter, pairs_path, events_dir, cfg.filters)
        runs = []
        for s in used or [None]:
            transform = fixed if row.filter != "rdnet" else voxel_filter(
                "rdnet", pairs_path, events_dir, cfg.filters, seed_checkpoint(row.filter_checkpoint, s),
                cfg.batch_size, cfg.device)
            ck = None if s is None else seed_checkpoint(row.checkpoint, s)
            runs.append(evaluate_row(row.method, ck, pairs_path, row.events, transform, batch_size=cfg.batch_size,
                                     device=cfg.device, level_bins=cfg.level_bins, progress=True))
    out = mean_over_seeds(runs)
    out["seeds"] = used
    for key in ("psnr", "ssim"):
        if key in runs[0]:
            per_seed = [float(r[key]) for r in runs]
            out[f"{key}_seeds"] = per_seed
            out[f"{key}_std"] = seed_spread(per_seed)
    if used:
        out["checkpoint"] = [r.get("checkpoint") for r in runs]
    out["row"] = row_id
    out["filter"] = row.filter
    out["paper_psnr"] = row.paper_psnr
    out["label"] = row.label or row_id
    return out


#: stage-1 networks scored by the restoration stage: name -> network directory (kind read
#: from the checkpoint: a RestoreNet, or an RDNet whose fine-tuned stage 1 is scored).
LEARNED_RESTORERS = {"rdnet": "models/rdnet", "rdnet_signed": "models/rdnet_signed", "rdnet_dual": "models/rdnet_dual",
                     "restore_image": "models/restore_image", "restore_events": "models/restore_events",
                     "restore_frames": "models/restore_frames", "restore_signed": "models/restore_signed"}
#: event-level metrics reported per method (rdnet.eval.events.match_metrics).
EVENT_KEYS = ("precision", "recall", "f1", "count_ratio", "voxel_l1_all", "voxel_l1_event", "restored",
              "reference")


def _json_number(v):
    v = float(v) if not isinstance(v, (int, np.integer)) else int(v)
    return v if not isinstance(v, float) or np.isfinite(v) else None


def _event_entry(counts: np.ndarray, reference: np.ndarray, labels) -> dict:
    """Pooled event metrics of (n, 2, bins, H, W) counts, overall and per label group."""
    from rdnet.eval.events import match_metrics
    m = match_metrics(counts, reference)
    out = {k: _json_number(m[k]) for k in EVENT_KEYS}
    if labels is not None:
        groups = []
        for g in sorted(set(labels.tolist())):
            sel = labels == g
            mg = match_metrics(counts[sel], reference[sel])
            groups.append({"group": g, "n": int(sel.sum()), **{k: _json_number(mg[k]) for k in EVENT_KEYS}})
        out["by_degradation"] = groups
    return out


def restoration_table(cfg: AblationConfig, pairs_path: Path, events_dir: Path,
                      learned: dict | None = None, *, filters=("stcf", "gef", "baf", "gef_voxel"),
                      seeds=(0,), baf_dt_us: int = 10000, gef_bins: int = 5, ednccn: Path | None = None) -> dict:
    """Restoration metrics against the undegraded events, per method: the raw degraded
    events (``degraded``), the event filters ``filters`` (STCF, BAF and GEF on the test
    events of each sample's window, :func:`event_filter`; ``gef_voxel``: the study's
    voxel-level GEF, its voxels rounded to events), the EDnCNN-style classifier of ``ednccn``
    (a checkpoint or its folder, when given: :mod:`rdnet.restore.ednccn`) and every stage-1 network of
    ``learned`` (name -> network directory or ``.pt``: a RestoreNet, or an RDNet whose
    fine-tuned stage 1 is scored), seed by seed (seed mean, ``<metric>_std``).

    Per method: ``voxel_l1``/``voxel_psnr``/``voxel_l1_all`` of the voxels a network reads
    (the networks' raw responses: comparable with the study's earlier numbers) and their
    ``by_degradation`` means (:func:`rdnet.eval.metrics.dominant_degradation`); ``events``:
    the event-level metrics of the restored *events* (the checkpoint's decision applied;
    :func:`rdnet.eval.events.match_metrics`, pooled over the test samples) overall and
    per dominant degradation. Event metrics need the pairs file's per-polarity voxels."""
    from rdnet.eval import metrics as M
    from rdnet.eval.predict import predict
    from rdnet.eval.stage1 import signed_counts
    from rdnet.study.config import seed_checkpoint
    from rdnet.train.checkpoint import read_checkpoint
    import h5py
    with h5py.File(pairs_path, "r") as f:
        u = np.asarray(f["voxel_undegraded"]); d = np.asarray(f["voxel_degraded"])
        degrade = {k: np.asarray(f["degrade"][k]) for k in f["degrade"]} if "degrade" in f else {}
        has_counts = "voxel_undegraded_on" in f
        if has_counts:
            cu, cd = count_grids(f, "undegraded"), count_grids(f, "degraded")
    idx = np.arange(len(u))
    labels = M.dominant_degradation(degrade) if degrade else None

    def score(signed, counts) -> dict:
        """One run's entry (scored at once: the restored arrays are not kept)."""
        per = M.restoration_per_sample(signed, u, d)
        entry = {k: float(np.mean(v)) for k, v in per.items() if k != "mask_fraction"}
        if labels is not None:
            entry["by_degradation"] = M.group_means({k: per[k] for k in ("voxel_l1", "voxel_psnr")}, labels)
        if counts is not None:
            entry["events"] = _event_entry(counts, cu, labels)
        return entry

    # name -> entries, one per seed for the learned ones
    entries: dict[str, list] = {"degraded": [score(d, cd if has_counts else None)]}
    for name in filters:
        if name == "gef_voxel":
            from rdnet.nn.decision import polarity_grid, split_signed
            v = voxel_filter("gef", pairs_path, events_dir, cfg.filters)(d, idx)
            entries[name] = [score(v, polarity_grid(split_signed(np.rint(v)).astype(np.int64)))]
        else:
            c = event_filter(name, pairs_path, events_dir, cfg.filters, baf_dt_us, gef_bins).counts(idx)
            entries[name] = [score(signed_counts(c).astype(np.float32), c)]
    if ednccn is not None:
        c = event_filter("ednccn", pairs_path, events_dir, cfg.filters, checkpoint=ednccn, device=cfg.device).counts(idx)
        entries["ednccn"] = [score(signed_counts(c).astype(np.float32), c)]
    for name, ck in (learned or {}).items():
        entries[name] = []
        for s in seeds:
            path = seed_checkpoint(ck, s)
            loaded = read_checkpoint(path)               # read once: predict reuses it
            kind = "rdnet" if loaded["model_kind"] == "rdnet" else "restore"
            pr = predict(kind, path, pairs_path, "degraded", batch_size=cfg.batch_size, device=cfg.device,
                         events_out=has_counts, loaded=loaded)
            entries[name].append(score(pr["restored"], pr.get("restored_counts")))
            del pr
    out = {}
    for name, runs in entries.items():
        out[name] = mean_over_seeds(runs)
        if name in (learned or {}):
            out[name]["seeds"] = list(seeds)
            for key in ("voxel_l1", "voxel_psnr"):
                out[name][f"{key}_std"] = seed_spread([e[key] for e in runs])
            if "events" in runs[0]:
                out[name]["events"]["f1_std"] = seed_spread([e["events"]["f1"] for e in runs])
    return out
