"""Restoration scored on events from the independent circuit generator (issue 11: a proof with
a ground truth that rdnet's own simulator did not make).

The study's test split is simulated by ``rdnet.sim.sensor`` and the restorers were trained on
that simulator's streams, so their test scores say how well they invert it. Here the truth and
the degraded stream both come from :mod:`rdnet.circuit` (a continuous-time photoreceptor /
source-follower / comparator model sharing no code with rdnet's simulator), driven by the very
frames of the study's test sequences (``data/events/test``):

* undegraded: the circuit with the study's nominal thresholds and nothing else (``i_dark`` =
  ``sensor.log_eps``, infinite bandwidth, no noise, no refractory period);
* degraded: the circuit with each sequence's own test degradation where it has a counterpart
  (:func:`rdnet.circuit.from_degrade`: threshold mismatch and ON/OFF ratio, its photoreceptor
  bandwidth for ``cutoff_hz``, refractory hold, shot noise, leak, hot pixels, jitter, latency;
  the readout period has none and is left out).

Those files go through the study's own code: :func:`rdnet.study.data.make_pairs` (the blur
stage: windows, blurry images, voxel grids) and :func:`rdnet.study.rows.restoration_table`
(the restoration stage: raw, STCF, GEF, BAF, the EDnCNN-style classifier and every stage-1
network of the study, all seeds), so every number is comparable with ``metrics/restoration.json``.
Nothing is trained or tuned on these streams.

    .venv/bin/python benchmarks/restore_independent.py      # needs dvc repro's data/events/test and models/
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

from rdnet.circuit import from_degrade, generate
from rdnet.config import from_dict, load_params, section
from rdnet.events.io.hdf5 import H5RecordingWriter, read_events, read_recording
from rdnet.sim.settings import DegradeConfig
from rdnet.study.data import make_pairs, sequences
from rdnet.study.rows import LEARNED_RESTORERS, restoration_table

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("restore_independent")
#: root attributes carried over from the study's event files (the blur stage reads them)
CARRIED_ATTRS = ("degradation_level", "degrade_json", "scene_background", "scene_spec", "scene_split")


def circuit_file(src: Path, dst: Path, sensor, seed: int) -> dict:
    """``dst``: the frames and attributes of ``src`` with events from the circuit generator:
    ``events_ideal`` (nominal thresholds only) and ``events`` (``src``'s test degradation)."""
    rec = read_recording(src)
    frames = rec.require_frames(str(src))
    deg = from_dict(DegradeConfig, json.loads(rec.attrs["degrade_json"]), "degrade", src)
    ideal_params = from_degrade(sensor, DegradeConfig())
    degraded_params = from_degrade(sensor, dataclasses.replace(deg, sample_period_us=0.0))
    rng = np.random.default_rng(seed)
    ideal = generate(frames.images, frames.t_us, ideal_params, rng)
    degraded = generate(frames.images, frames.t_us, degraded_params, rng)
    with H5RecordingWriter(dst, rec.width, rec.height, sensor="rdnet-circuit") as w:
        w.write_frames(frames)
        w.append_events(ideal, group="events_ideal")
        w.append_events(degraded, group="events")
        for key in CARRIED_ATTRS:
            if key in rec.attrs:
                w.set_attr(key, rec.attrs[key])
    return {"file": src.name, "ideal_events": len(ideal), "degraded_events": len(degraded),
            "rdnet_ideal_events": len(read_events(src, group="events_ideal")),
            "rdnet_degraded_events": len(rec.require_events(str(src))),
            "degraded_params": dataclasses.asdict(degraded_params)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--events", type=Path, default=ROOT / "data" / "events", help="the study's event files")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=3, help="independent circuit draws (default 3)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_independent.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    params = load_params(args.params)
    sensor = section(params, "sensor")
    restore = section(params, "restore")
    started = time.perf_counter()
    tables, files = [], []
    for draw in range(args.draws):            # independent circuit draws (pixels, noise, start states)
        with tempfile.TemporaryDirectory() as tmp:
            events_dir = Path(tmp) / "events"
            (events_dir / "test").mkdir(parents=True)
            drawn = [circuit_file(src, events_dir / "test" / src.name, sensor, 1000 * (args.seed + draw) + i)
                     for i, src in enumerate(sequences(args.events, "test"))]
            for f in drawn:
                log.info("draw %d, %s: circuit %d undegraded, %d degraded events (rdnet's simulator: %d, %d)", draw,
                         f["file"], f["ideal_events"], f["degraded_events"], f["rdnet_ideal_events"],
                         f["rdnet_degraded_events"])
            files.append(drawn)
            make_pairs(params, events_dir, Path(tmp) / "pairs", splits=("test",))
            ednccn = ROOT / "models" / "ednccn"
            tables.append(restoration_table(
                section(params, "ablation"), Path(tmp) / "pairs" / "test.h5", events_dir / "test",
                {k: ROOT / v for k, v in LEARNED_RESTORERS.items() if (ROOT / v).exists()},
                seeds=section(params, "study").seeds, baf_dt_us=restore.baf_dt_us, gef_bins=restore.gef_bins,
                ednccn=ednccn if ednccn.exists() else None))
    keys = ("precision", "recall", "f1", "count_ratio", "voxel_l1_all", "voxel_l1_event")
    names = [n for n, e in tables[0].items() if "events" in e]
    # mean over the circuit draws (each already the mean over the study's training seeds), and their spread
    rows = {n: {k: float(np.mean([t[n]["events"][k] for t in tables])) for k in keys} |
            {f"{k}_draw_std": float(np.std([t[n]["events"][k] for t in tables], ddof=1)) if len(tables) > 1 else 0.0
             for k in ("f1", "voxel_l1_all")} for n in names}
    study = json.loads((ROOT / "metrics" / "restoration.json").read_text())
    out = {"benchmark": "restoration on the independent circuit generator",
           "generator": "rdnet.circuit (undegraded: nominal thresholds only; degraded: each test sequence's "
                        "degradation through rdnet.circuit.from_degrade, readout period left out)",
           "draws": args.draws, "sequences": files, "seconds": time.perf_counter() - started, "events": rows,
           "study_test_split_same_methods": {name: {k: study[name]["events"][k] for k in keys}
                                             for name in rows if name in study and "events" in study[name]}}
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    raw = rows["degraded"]
    lines = ["# Restoration on the independent circuit generator (`benchmarks/restore_independent.py`)", "",
             f"{len(files[0])} test sequences of the study, events from `rdnet.circuit` in {args.draws} independent draws; "
             "scored as `metrics/restoration.json` (events matched per voxel and polarity against the circuit's "
             "undegraded stream; learned rows: mean over the study's training seeds), mean over the draws, "
             "± their standard deviation. In brackets: the same method on the study's own test split "
             "(rdnet's simulator).", "",
             "| method | F1 | precision | recall | count ratio | all-voxel L1 | vs raw |", "|---|---:|---:|---:|---:|---:|---:|"]

    def cell(name, k, fmt):
        s = study.get(name, {}).get("events", {})
        spread = f" ± {rows[name][k + '_draw_std']:{fmt}}" if k + "_draw_std" in rows[name] else ""
        return f"{rows[name][k]:{fmt}}{spread}" + (f" ({s[k]:{fmt}})" if k in s else "")
    for name in sorted(rows, key=lambda n: -rows[n]["f1"]):
        lines.append(f"| {name} | {cell(name, 'f1', '.3f')} | {cell(name, 'precision', '.3f')} | "
                     f"{cell(name, 'recall', '.3f')} | {cell(name, 'count_ratio', '.2f')} | "
                     f"{cell(name, 'voxel_l1_all', '.4f')} | {100 * (rows[name]['voxel_l1_all'] / raw['voxel_l1_all'] - 1):+.1f} % |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
