"""Data steps of the study: scenes -> interpolate -> simulate -> blur.

Each step reads the previous step's folder of per-sequence HDF5 recordings
(``<root>/<split>/seq_XXX.h5``) and writes its own; every file is written atomically.
Randomness: one ``numpy.random.Generator`` per (study seed, step, split, sequence), so a
sequence's output does not depend on how many other sequences there are.

Memory: GOPRO sequences (the paper profile) are read, upsampled and simulated in chunks
of :data:`STREAM_FRAMES` frames (:func:`rdnet.sim.pair.upsample_stream`,
:func:`rdnet.sim.pair.stream_events`, :class:`rdnet.events.io.H5RecordingWriter`), so
neither a whole sequence nor its 4-16x upsampled frames nor its events are ever in memory
at once; the blur step holds one sequence's native frames and events.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from tqdm import tqdm

from rdnet.config import section, to_dict
from rdnet.events import Events, Frames
from rdnet.events.io import H5RecordingWriter, read_events, read_header, read_recording
from rdnet.sim.blur import PairsWriter, make_samples
from rdnet.sim.interpolate import UpsampleStats
from rdnet.sim.pair import DEFAULT_CHUNK, frame_chunks, stream_events, upsample_stream
from rdnet.sim.sensor import Sensor
from rdnet.sim.randomize import degradation_level, draw_degrade, scale_degrade
from rdnet.sim.scenes import SPLITS, render_split

log = logging.getLogger(__name__)

_STEP_IDS = {"scenes": 1, "simulate": 2, "blur": 3}

#: frames per chunk when a sequence is read or written in pieces (the simulation itself
#: steps in the simulator's chunks, :data:`rdnet.sim.pair.DEFAULT_CHUNK`)
STREAM_FRAMES = 64


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
    """``(attrs, chunks)`` of the GOPRO sequences of ``split`` (``scenes.source: gopro``):
    every sequence folder of ``<gopro_root>/<split>`` in name order, at most ``n_<split>``
    of them (0: all), at most ``n_frames`` frames each; ``chunks`` iterates Frames of at
    most :data:`STREAM_FRAMES` frames, linear intensity, grey unless ``color``.
    FormatError naming the folder when the layout is not GOPRO's."""
    from rdnet.errors import FormatError
    from rdnet.sim.interpolate import luminance
    from rdnet.sim.sources import iter_frames
    root = Path(cfg.gopro_root) / split
    if not root.is_dir():
        raise FormatError(root, None, "no such folder: scenes.gopro_root must hold train/ and test/ "
                          "sequence folders (GOPRO_Large_all layout)")
    folders = sorted(q for q in root.iterdir() if q.is_dir())
    if not folders:
        raise FormatError(root, None, "no sequence folders")
    cap = cfg.count(split)

    def chunks(q):
        for fr in iter_frames(q, max_frames=cfg.n_frames, fps_hz=cfg.fps_hz, chunk_frames=STREAM_FRAMES):
            if not cfg.color and fr.images.ndim == 4:
                fr = Frames(luminance(fr.images).astype(np.float32), fr.t_us, fr.exposure_us)
            yield fr
    for q in folders[:cap] if cap > 0 else folders:
        yield {"source": "gopro", "sequence": q.name}, chunks(q)


def frame_parts(path: Path, chunk: int | None = None):
    """The frames of an HDF5 recording in consecutive Frames of at most ``chunk`` (default
    :data:`STREAM_FRAMES`) frames, linear intensity (FormatError naming the file when it
    has none): :func:`rdnet.sim.sources.iter_frames` at the study's chunk size."""
    from rdnet.sim.sources import iter_frames
    return iter_frames(path, linearize=False, chunk_frames=int(chunk or STREAM_FRAMES))


def _write_frames(path: Path, chunks, sensor: str, attrs: dict) -> int:
    """Write Frames chunks as one recording (atomically); returns the frame count."""
    import itertools
    from rdnet.errors import FormatError
    chunks = iter(chunks)
    first = next(chunks, None)
    if first is None:
        raise FormatError(path, "frames", "no frames to write")
    n = 0
    with H5RecordingWriter(path, first.width, first.height, sensor) as w:
        for k, v in attrs.items():
            w.set_attr(k, v)
        for fr in itertools.chain([first], chunks):
            w.write_frames(fr)
            n += len(fr)
    return n


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
            items = ((spec.attrs(), [frames]) for spec, frames in render_split(cfg, split))
            total = cfg.count(split)
        for i, (attrs, chunks) in enumerate(tqdm(items, total=total, desc=f"scenes {split}", disable=None)):
            _write_frames(out / split / f"seq_{i:03d}.h5", chunks, "rdnet-scene", attrs)
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
            _, _, sensor, attrs = read_header(path)
            st = UpsampleStats()
            n_in = 0

            def counted(parts):
                nonlocal n_in
                for fr in parts:
                    n_in += len(fr)
                    yield fr
            up = ((im.astype(np.float32), t, np.zeros(len(t), np.int64))
                  for im, t in upsample_stream(counted(frame_parts(path)), cfg, log_eps, stats=st))
            n_out = _write_frames(out / split / path.name, (Frames(*a) for a in up), sensor, attrs)
            inserted.append(n_out / max(n_in, 1))
            viol += st.violations
        summary[split] = {"upsample_factor_mean": float(np.mean(inserted)), "bound_violations": int(viol)}
    return summary


def simulation_configs(params: dict) -> tuple:
    """``(sensor, degrade)`` the study simulates with: the params sections, or the fitted ones
    of a calibration report when ``study.degrade_from`` names one."""
    sensor, base = section(params, "sensor"), section(params, "degrade")
    study = section(params, "study")
    if study.degrade_from:
        from rdnet.study.config import calibrated_configs
        sensor, base = calibrated_configs(study.degrade_from)
        log.info("sensor and degradation from the calibration %s", study.degrade_from)
    return sensor, base


def simulate_sequences(params: dict, scenes: Path, interp: Path, out: Path, splits=SPLITS,
                       fixed_scale: float | None = None) -> dict:
    """Paired ideal/degraded events of every sequence; the degradation of each sequence is
    drawn from the split's randomized settings and stored in its ``degrade_json`` attr.
    ``study.degrade_from`` swaps in a calibration report's fitted sensor + degradation.
    ``fixed_scale``: every active effect of every sequence at exactly ``fixed_scale`` x
    ``degrade`` instead of the randomized draw (the stress test); ``splits``: which splits."""
    sensor, base = simulation_configs(params)
    rand = section(params, "randomize")
    summary = {}
    for split in splits:
        (out / split).mkdir(parents=True, exist_ok=True)
        counts = []
        for i, path in enumerate(tqdm(sequences(interp, split), desc=f"simulate {split}", disable=None)):
            rng = step_rng(params, "simulate", split, i)
            deg = draw_degrade(base, rand, split, rng)
            if fixed_scale is not None:
                deg = scale_degrade(base, {k: float(fixed_scale) for k in base.active()})
            scene = scenes / split / path.name
            width, height, _, attrs = read_header(scene)
            attrs["degrade_json"] = json.dumps(to_dict(deg))
            attrs["degradation_level"] = degradation_level(deg, base)
            # the ideal and the degraded sensor see the same upsampled frames, chunk by chunk
            sensors = [Sensor(width, height, sensor, None), Sensor(width, height, sensor, deg, rng)]
            n = [0, 0]
            with H5RecordingWriter(out / split / path.name, width, height, "rdnet-sim") as w:
                for k, v in attrs.items():
                    w.set_attr(k, v)
                for fr in frame_parts(scene):          # the sharp frames at their own rate
                    w.write_frames(fr)
                groups = ("events_ideal", "events")
                for g in groups:
                    w.append_events(Events.empty(width, height), g)
                # steps in the simulator's own chunks, as simulate_pair takes them: the same bits
                steps = frame_chunks(frame_parts(path, DEFAULT_CHUNK), log_eps=sensor.log_eps, chunk=DEFAULT_CHUNK)
                for evs in stream_events(steps, sensors):
                    for j, (g, ev) in enumerate(zip(groups, evs)):
                        w.append_events(ev, g)
                        n[j] += len(ev)
            counts.append(tuple(n))
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
