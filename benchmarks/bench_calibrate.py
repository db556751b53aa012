"""Speed of the whole calibration (``rdnet calibrate``): wall time per million recorded
events, on the DAVIS346 road recording and on a synthetic concealed-effect recording.
Goal: at most 60 s per million recorded events on 2 CPU cores.

The cost of a diagnosis grows with the number of simulations (candidates x search points
x seeds) times the simulated pixel-frames (sampled pixels x upsampled frames), not with
the recorded events, so the per-event figure depends on how busy the recording is.

    .venv/bin/python benchmarks/bench_calibrate.py           # writes benchmarks/results/calibrate.json
    .venv/bin/python benchmarks/bench_calibrate.py --real path/to/davis346.aedat4 --out /tmp/cal
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from rdnet.calib.calibrate import calibrate, finding
from rdnet.calib.proof import CASES, make_recording
from rdnet.calib.report import write_json, write_report
from rdnet.calib.scene import SceneSpec
from rdnet.calib.settings import CalibrateConfig
from rdnet.events.io import load
from rdnet.sim.interpolate import InterpolateConfig
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4"


def _row(name: str, cal, n_events: int, wall: float) -> dict:
    r = cal.report
    return {"recording": name, "recorded_events": n_events,
            "compared_events": r["setup"]["real_events_compared"],
            "sampled_pixels": r["setup"]["sampled_pixels"], "pixel_stride": r["setup"]["pixel_stride"],
            "simulated_frames": r["setup"]["simulated_frames"], "simulations": r["setup"]["simulations"],
            "wall_s": wall, "s_per_million_events": wall / max(n_events, 1) * 1e6,
            "goal_s_per_million_events": 60.0, "meets_goal": wall / max(n_events, 1) * 1e6 <= 60.0,
            "finding": finding(r)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--real", type=Path, default=REAL, help="DAVIS346 recording (.aedat4)")
    ap.add_argument("--out", type=Path, default=None, help="also write the calibration reports here")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "calibrate.json")
    args = ap.parse_args()
    sensor, cfg = SensorConfig(), CalibrateConfig()
    rows = []

    case = next(c for c in CASES if c.effect == "hot_pixels")
    interp = InterpolateConfig(max_upsample=16)
    rec, _ = make_recording(case, SceneSpec(), sensor, np.random.default_rng(0), 1, interp)
    t = time.perf_counter()
    cal = calibrate(rec, sensor, DegradeConfig(**case.base), cfg, interpolate=interp, source="synthetic:" + case.name)
    rows.append(_row("synthetic " + case.name + " (64x64, 1 s)", cal, len(rec.events), time.perf_counter() - t))
    if args.out:
        write_report(cal, args.out / case.name)

    if args.real.is_file():
        t = time.perf_counter()
        rec = load(args.real)
        cal = calibrate(rec, sensor, DegradeConfig(), cfg, interpolate=InterpolateConfig(), source=str(args.real))
        rows.append(_row("DAVIS346 road (346x260, 2.36 s)", cal, len(rec.events), time.perf_counter() - t))
        if args.out:
            write_report(cal, args.out / "davis346")
    out = {"benchmark": "calibrate", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                  "platform": platform.platform()},
           "calibrate_config": {k: getattr(cfg, k) for k in ("segments", "seeds", "search_points", "refine_steps",
                                                               "max_sim_steps", "max_upsample", "max_effects")},
           "results": rows}
    args.results.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.results, out)
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
