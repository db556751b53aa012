"""Speed of the whole calibration (``rdnet calibrate``): wall time per million recorded
events, on the DAVIS346 road recording and on a synthetic concealed-effect recording.
Goal: at most 60 s per million recorded events on 2 CPU cores.

Both runs use the settings of their DVC stages: the ``calibrate`` section of params.yaml;
the DAVIS346 run also its ``interpolate`` section and the ideal sensor as base config
(``calibrate_real``), the synthetic one the proof's interpolation (``calibration_proof``).
The wall time includes loading the recording and upsampling its frames. The DAVIS346
recording is also timed as a user runs it: ``rdnet calibrate`` in its own process, with
its report figures (imports, numba's cached compilation, plots and writing included). The machine's
load average is recorded with each run (the 2 cores may be shared), and so is the CPU time
of the process. ``machine.reference_kernel_ns`` times a fixed workload on the host at the end
of the run (``bench_sensor_groups.host_reference``: the pixel kernel on the calibration's
sample shape, one thread), so that runs on different hosts or at different moments can be put
side by side.

The cost of a diagnosis grows with the number of simulations (candidates x search points
x seeds) times the simulated pixel-frames (sampled pixels x upsampled frames), not with
the recorded events, so the per-event figure depends on how busy the recording is.

    .venv/bin/python benchmarks/bench_calibrate.py           # writes benchmarks/results/calibrate.json
    .venv/bin/python benchmarks/bench_calibrate.py --real path/to/davis346.aedat4 --out /tmp/cal
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rdnet.calib.calibrate import calibrate, calibration_interpolation, finding
from rdnet.calib.proof import CASES, make_recording
from rdnet.calib.report import write_json, write_report
from rdnet.calib.scene import SceneSpec
from rdnet.config import load_params, section, to_dict
from rdnet.events.io import load as load_recording
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from calib_stability import run_seed, stage_sets  # noqa: E402

REAL = ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4"
log = logging.getLogger("bench_calibrate")


def _row(name: str, cal, n_events: int, wall: float, cpu: float, load: tuple) -> dict:
    r = cal.report
    per_m = wall / max(n_events, 1) * 1e6
    return {"recording": name, "recorded_events": n_events,
            "compared_events": r["setup"]["real_events_compared"],
            "sampled_pixels": r["setup"]["sampled_pixels"], "pixel_stride": r["setup"]["pixel_stride"],
            "search_pixels": r["setup"]["search"]["search_pixels"],
            "simulated_frames": r["setup"]["simulated_frames"], "simulations": r["setup"]["simulations"],
            "pixel_circuit_runs": r["setup"].get("pixel_circuit_runs", r["setup"]["search"]["kernel_runs"]),
            "wall_s": wall, "cpu_s": cpu, "load_average_1min_before_after": list(load),
            "s_per_million_events": per_m, "cpu_s_per_million_events": cpu / max(n_events, 1) * 1e6,
            "goal_s_per_million_events": 60.0, "meets_goal": per_m <= 60.0,
            "finding": finding(r)}


def _timed(fn):
    load0 = os.getloadavg()[0]
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    return out, wall, cpu, (round(load0, 2), round(os.getloadavg()[0], 2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--real", type=Path, default=REAL, help="DAVIS346 recording (.aedat4)")
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--out", type=Path, default=None, help="also write the calibration reports here")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "calibrate.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    params = load_params(args.params)
    cfg = section(params, "calibrate")
    sensor = SensorConfig()
    rows = []

    case = next(c for c in CASES if c.effect == "hot_pixels")
    interp = calibration_interpolation(cfg)
    rec, _ = make_recording(case, SceneSpec(), sensor, np.random.default_rng(0), 1, interp)
    cal, wall, cpu, load = _timed(lambda: calibrate(rec, sensor, DegradeConfig(**case.base), cfg, interpolate=interp,
                                                    source="synthetic:" + case.name, progress=False))
    rows.append(_row("synthetic " + case.name + " (64x64, 1 s)", cal, len(rec.events), wall, cpu, load))
    log.info("%s", rows[-1])
    if args.out:
        write_report(cal, args.out / case.name)

    if args.real.is_file():
        # as the calibrate_real stage: params.yaml with the stage's own --set list (every
        # degrade effect off, the shape keys as params.yaml has them)
        sets = stage_sets(ROOT / "dvc.yaml")
        real_params = load_params(args.params, sets)
        base = section(real_params, "degrade")
        real_sensor, real_interp = section(real_params, "sensor"), section(real_params, "interpolate")

        def run():
            r = load_recording(args.real)
            return r, calibrate(r, real_sensor, base, cfg, interpolate=real_interp, source=str(args.real),
                                progress=False)
        (rec, cal), wall, cpu, load = _timed(run)
        rows.append(_row("DAVIS346 road (346x260, 2.36 s)", cal, len(rec.events), wall, cpu, load))
        log.info("%s", rows[-1])
        if args.out:
            write_report(cal, args.out / "davis346")
        # the path a user runs: `rdnet calibrate` in its own process, figures included
        n = len(rec.events)
        with tempfile.TemporaryDirectory() as tmp:
            load0 = os.getloadavg()[0]
            run = run_seed(0, args.real, args.params, sets, Path(tmp) / "cli", plots=True)
        rows.append({"recording": "DAVIS346 road, `rdnet calibrate` end to end (CLI, figures)", "recorded_events": n,
                     "wall_s": run["wall_s"], "load_average_1min_before_after": [round(load0, 2),
                                                                                  round(os.getloadavg()[0], 2)],
                     "s_per_million_events": run["wall_s"] / n * 1e6, "goal_s_per_million_events": 60.0,
                     "meets_goal": run["wall_s"] / n * 1e6 <= 60.0,
                     "named": run["named"], "heldout_before_after": [run["heldout_before"], run["heldout_after"]]})
        log.info("%s", rows[-1])
    from bench_sensor_groups import host_reference
    from machine import machine
    out = {"benchmark": "calibrate", "machine": {**machine(), "reference_kernel_ns": host_reference()},
           "calibrate_config": to_dict(cfg), "results": rows}
    args.results.parent.mkdir(parents=True, exist_ok=True)
    if args.results.exists():       # keep the hand-recorded history (before_redesign, ...)
        old = json.loads(args.results.read_text())
        out.update({k: v for k, v in old.items() if k not in out})
    write_json(args.results, out)
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
