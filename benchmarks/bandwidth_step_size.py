"""Does the simulated bandwidth limit depend on the simulation's time step? (issue 12: the
circuit generator's bandwidth cases are fitted 12-27 % below their true cutoff.)

A photoreceptor is a continuous low-pass filter: its lag behind a changing log intensity is
set by its cutoff, not by how finely a simulator samples the input. rdnet's simulator
(:mod:`rdnet.sim.sensor`) advances the filter once per simulated frame; this script feeds one
pixel a log-intensity ramp (+1.0 in 20 ms, sampled every ``dt``, the intensity linear in log
between samples as the interpolated frames are) at several ``dt`` and reports the times of
its first ON events against those of the finest step (5 us, the continuous filter to within
a few microseconds). Rows: cutoff 100 and 300 Hz (at full intensity; ``cutoff_floor`` 0.078,
the default), a bright pixel (ramp from I = 0.5) and a dark one (from I = 0.05, where the
filter is about 10x slower). The calibration upsamples 10 ms proof frames up to 16x (steps of
about 0.6 ms) and 40 ms DAVIS346 frames likewise (about 2.5 ms).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bandwidth_step_size.py
    # -> benchmarks/results/bandwidth_step_size.{json,md} (a few seconds)
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STEPS_US = (2500, 1000, 625, 250, 100, 20)
REFERENCE_US = 5
RAMP_US = 20_000
RAMP_LOG = 1.0


def event_times(step_us: int, cutoff_hz: float, start: float, n: int = 3) -> np.ndarray:
    """Times (us) of the first ``n`` events of one pixel on the ramp sampled every ``step_us``."""
    from rdnet.sim.sensor import Sensor
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    sensor = SensorConfig()
    t = np.arange(0, RAMP_US + 1, step_us, dtype=np.int64)
    log_i = np.log(start + sensor.log_eps) + RAMP_LOG * t / RAMP_US
    frames = np.maximum(np.exp(log_i) - sensor.log_eps, 0.0).astype(np.float32)[:, None, None]
    sim = Sensor(1, 1, sensor, DegradeConfig(cutoff_hz=cutoff_hz), np.random.default_rng(0))
    ev = sim.step(frames, t)
    return np.asarray(ev.t[:n], np.int64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "bandwidth_step_size")
    args = ap.parse_args()
    rows = []
    for cutoff in (100.0, 300.0):
        for name, start in (("bright (I from 0.5)", 0.5), ("dark (I from 0.05)", 0.05)):
            ref = event_times(REFERENCE_US, cutoff, start)
            for step in STEPS_US:
                t = event_times(step, cutoff, start)
                k = min(len(t), len(ref))
                rows.append({"cutoff_hz": cutoff, "pixel": name, "step_us": step,
                             "event_times_us": t.tolist(), "reference_times_us": ref.tolist(),
                             "mean_shift_us": float(np.mean(t[:k] - ref[:k])) if k else None})
    from rdnet.eval.report import write_text_atomic
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.out.with_suffix(".json"), json.dumps(
        {"benchmark": "bandwidth_step_size", "reference_step_us": REFERENCE_US, "ramp_us": RAMP_US,
         "ramp_log": RAMP_LOG, "rows": rows}, indent=2) + "\n")
    lines = ["# The simulated bandwidth limit against the simulation's time step", "",
             f"`benchmarks/bandwidth_step_size.py`: one pixel on a log-intensity ramp (+{RAMP_LOG} in "
             f"{RAMP_US / 1000:g} ms); the mean shift of its first 3 events against a {REFERENCE_US} us step "
             "(negative: earlier, i.e. less lag than the continuous filter).", "",
             "| cutoff (Hz) | pixel | " + " | ".join(f"step {s} us" for s in STEPS_US) + " |",
             "|---|---|" + "---:|" * len(STEPS_US)]
    for cutoff in (100.0, 300.0):
        for name in ("bright (I from 0.5)", "dark (I from 0.05)"):
            cells = [r for r in rows if r["cutoff_hz"] == cutoff and r["pixel"] == name]
            lines.append(f"| {cutoff:g} | {name} | " + " | ".join(
                "-" if r["mean_shift_us"] is None else f"{r['mean_shift_us']:+.0f} us" for r in cells) + " |")
    write_text_atomic(args.out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
