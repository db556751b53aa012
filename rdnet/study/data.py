"""Data steps of the study: scenes -> interpolate -> simulate -> blur.

Each step reads the previous step's folder of per-sequence HDF5 recordings
(``<root>/<split>/seq_XXX.h5``) and writes its own; every file is written atomically.
Randomness: one ``numpy.random.Generator`` per (study seed, step, split, sequence), so a
sequence's output does not depend on how many other sequences there are.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from tqdm import tqdm

from rdnet.config import section, to_dict
from rdnet.events import Frames, Recording
from rdnet.events.io import read_events, read_recording, write_recording
from rdnet.sim.blur import PairsWriter, make_samples
from rdnet.sim.interpolate import UpsampleStats, upsample_all
from rdnet.sim.pair import simulate_pair
from rdnet.sim.randomize import degradation_level, draw_degrade, scale_degrade
from rdnet.sim.scenes import SPLITS, render_split

log = logging.getLogger(__name__)

_STEP_IDS = {"scenes": 1, "simulate": 2, "blur": 3}


def step_rng(params: dict, step: str, split: str, index: int) -> np.random.Generator:
    """The generator of one sequence in one step: seeded by (seed, step, split, index)."""
    seed = int(params.get("seed", 0))
    return np.random.default_rng([seed, _STEP_IDS[step], SPLITS.index(split), index])


def sequences(root: Path, split: str) -> list[Path]:
    files = sorted((Path(root) / split).glob("seq_*.h5"))
    if not files:
        from rdnet.errors import FormatError
        raise FormatError(Path(root) / split, None, "no seq_*.h5 files (run the previous stage first)")
    return files


def gopro_split(cfg, split: str):
    """``(attrs, Frames)`` of the GOPRO sequences of ``split`` (``scenes.source: gopro``):
    every sequence folder of ``<gopro_root>/<split>`` in name order, at most ``n_<split>``
    of them (0: all), at most ``n_frames`` frames each, linear intensity, grey unless
    ``color``. FormatError naming the folder when the layout is not GOPRO's."""
    from rdnet.errors import FormatError
    from rdnet.sim.interpolate import luminance
    from rdnet.sim.sources import open_frames
    root = Path(cfg.gopro_root) / split
    if not root.is_dir():
        raise FormatError(root, None, "no such folder: scenes.gopro_root must hold train/ and test/ "
                          "sequence folders (GOPRO_Large_all layout)")
    folders = sorted(q for q in root.iterdir() if q.is_dir())
    if not folders:
        raise FormatError(root, None, "no sequence folders")
    cap = cfg.count(split)
    for q in folders[:cap] if cap > 0 else folders:
        fr = open_frames(q, max_frames=cfg.n_frames, fps_hz=cfg.fps_hz)
        if not cfg.color and fr.images.ndim == 4:
            fr = Frames(luminance(fr.images).astype(np.float32), fr.t_us, fr.exposure_us)
        yield {"source": "gopro", "sequence": q.name}, fr


def render_scenes(params: dict, out: Path) -> dict:
    """The sharp sequences of both splits into ``out/<split>/seq_XXX.h5``: rendered
    (embedded default) or read from GOPRO (``scenes.source``)."""
    cfg = section(params, "scenes")
    stats = {}
    for split in SPLITS:
        (out / split).mkdir(parents=True, exist_ok=True)
        n = 0
        if cfg.source == "gopro":
            items, total = gopro_split(cfg, split), None
        else:
            items = ((spec.attrs(), frames) for spec, frames in render_split(cfg, split))
            total = cfg.count(split)
        for i, (attrs, frames) in enumerate(tqdm(items, total=total, desc=f"scenes {split}", disable=None)):
            rec = Recording(frames.width, frames.height, frames=frames, sensor="rdnet-scene")
            write_recording(out / split / f"seq_{i:03d}.h5", rec, attrs=attrs)
            n += 1
        stats[split] = n
    return stats


def interpolate_scenes(params: dict, src: Path, out: Path) -> dict:
    """Upsample every scene so log intensity changes little between steps."""
    cfg = section(params, "interpolate")
    log_eps = cfg.log_eps if cfg.log_eps is not None else section(params, "sensor").log_eps
    summary = {}
    for split in SPLITS:
        (out / split).mkdir(parents=True, exist_ok=True)
        inserted, viol = [], 0
        for path in tqdm(sequences(src, split), desc=f"interpolate {split}", disable=None):
            rec = read_recording(path)
            fr = rec.require_frames(str(path))
            st = UpsampleStats()
            images, t_us = upsample_all(fr.linear(), fr.t_us, cfg, log_eps, stats=st)
            up = Frames(images.astype(np.float32), t_us, np.zeros(len(t_us), np.int64))
            write_recording(out / split / path.name, Recording(rec.width, rec.height, frames=up,
                                                               sensor=rec.sensor), attrs=rec.attrs)
            inserted.append(len(t_us) / max(len(fr), 1))
            viol += st.violations
        summary[split] = {"upsample_factor_mean": float(np.mean(inserted)), "bound_violations": int(viol)}
    return summary


def simulate_sequences(params: dict, scenes: Path, interp: Path, out: Path, splits=SPLITS,
                       fixed_scale: float | None = None) -> dict:
    """Paired ideal/degraded events of every sequence; the degradation of each sequence is
    drawn from the split's randomized settings and stored in its ``degrade_json`` attr.
    ``study.degrade_from`` swaps in a calibration report's fitted sensor + degradation.
    ``fixed_scale``: every active effect of every sequence at exactly ``fixed_scale`` x
    ``degrade`` instead of the randomized draw (the stress test); ``splits``: which splits."""
    sensor = section(params, "sensor")
    base = section(params, "degrade")
    rand = section(params, "randomize")
    study = section(params, "study")
    if study.degrade_from:
        from rdnet.study.config import calibrated_configs
        sensor, base = calibrated_configs(study.degrade_from)
        log.info("sensor and degradation from the calibration %s", study.degrade_from)
    summary = {}
    for split in splits:
        (out / split).mkdir(parents=True, exist_ok=True)
        counts = []
        for i, path in enumerate(tqdm(sequences(interp, split), desc=f"simulate {split}", disable=None)):
            rng = step_rng(params, "simulate", split, i)
            deg = draw_degrade(base, rand, split, rng)
            if fixed_scale is not None:
                deg = scale_degrade(base, {k: float(fixed_scale) for k in base.active()})
            up = read_recording(path).require_frames(str(path))
            ideal, degraded = simulate_pair(up, None, sensor, deg, rng)
            orig = read_recording(scenes / split / path.name)
            attrs = dict(orig.attrs)
            attrs["degrade_json"] = json.dumps(to_dict(deg))
            attrs["degradation_level"] = degradation_level(deg, base)
            rec = Recording(orig.width, orig.height, events=degraded, frames=orig.frames, sensor="rdnet-sim")
            write_recording(out / split / path.name, rec, extra_events={"events_ideal": ideal}, attrs=attrs)
            counts.append((len(ideal), len(degraded)))
        c = np.array(counts, float)
        summary[split] = {"ideal_events": int(c[:, 0].sum()), "degraded_events": int(c[:, 1].sum())}
    return summary


def make_pairs(params: dict, events_dir: Path, out: Path, splits=SPLITS) -> dict:
    """Blurry/sharp pairs and both voxel grids of every sequence -> ``out/<split>.h5``."""
    from rdnet.sim.settings import DegradeConfig
    from rdnet.config import from_dict
    cfg = section(params, "blur")
    vox = section(params, "voxel")
    out.mkdir(parents=True, exist_ok=True)
    summary = {}
    for split in splits:
        n = 0
        files = sequences(events_dir, split)
        channels = 3 if section(params, "scenes").color else 1
        with PairsWriter(out / f"{split}.h5", {"bins": vox.bins, "voxel_mode": vox.mode,
                                               "channels": channels, "split": split}) as w:
            for i, path in enumerate(tqdm(files, desc=f"blur {split}", disable=None)):
                rec = read_recording(path)
                ideal = read_events(path, group="events_ideal")
                deg = from_dict(DegradeConfig, json.loads(rec.attrs["degrade_json"]), "degrade", path)
                s = make_samples(rec.require_frames(str(path)), ideal, rec.require_events(str(path)), cfg,
                                 vox.bins, step_rng(params, "blur", split, i), vox.mode, sequence=i,
                                 degrade=deg, level=float(rec.attrs.get("degradation_level", 0.0)))
                w.append(s)
                n += len(s["blurry"])
        summary[split] = {"samples": n}
    return summary
