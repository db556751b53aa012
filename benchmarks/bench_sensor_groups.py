"""The pixel kernel in groups of rows (``rdnet.sim.sensor.row_group``) against one row per
group: nanoseconds per pixel and step, one numba thread, for the frame shapes the
calibration simulates (its DAVIS346 pixel sample 130 x 173, its search sample 65 x 87,
the proof's 64 x 64 scenes) and a full DAVIS346 frame, each under the ideal sensor and
under one effect at a time. The events of both layouts are compared (they must be equal).

The kernel advances a group of rows step by step; with one row per group each step of a
narrow frame reads 0.3-1.4 KB of a frame and the next step's row lies a whole frame
further, so every row and step waits on memory. ``GROUP_PIXELS`` (1024) sets the group.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_sensor_groups.py   # writes benchmarks/results/sensor_groups.{json,md}
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numba
import numpy as np

import rdnet.sim.sensor as sensor_mod
from rdnet.calib.effects import ideal
from rdnet.calib.report import write_json
from rdnet.sim.sensor import Sensor
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from machine import machine  # noqa: E402
SHAPES = {"calibration sample (DAVIS346, stride 2)": (130, 173), "search sample (stride 4)": (65, 87),
          "proof scene": (64, 64), "DAVIS346 frame": (260, 346)}
EFFECTS = {"ideal": {}, "bandwidth (cutoff 200 Hz)": {"cutoff_hz": 200.0},
           "shot noise 2 Hz": {"shot_noise_hz": 2.0}, "refractory 0.5 ms": {"refractory_us": 500.0},
           "leak 0.5 Hz": {"leak_hz": 0.5}}


def host_reference(rounds: int = 5) -> float:
    """How fast this host is right now, in a unit other benchmarks can record beside their
    own times: ns per pixel-step of the ideal sensor's kernel on the calibration's DAVIS346
    sample shape (130 x 173, 600 frames, one numba thread, best of ``rounds``). Rounds on
    different hosts or at different moments compare better divided by it."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        lin, t = frames(130, 173, 600, np.random.default_rng(130173))
        degrade = ideal(DegradeConfig())
        run(lin[:3], t[:3], degrade, sensor_mod.GROUP_PIXELS, 1)
        best, _, _ = run(lin, t, degrade, sensor_mod.GROUP_PIXELS, rounds)
    finally:
        numba.set_num_threads(threads)
    return best / (599 * 130 * 173) * 1e9


def frames(h: int, w: int, steps: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Linear frames of a drifting texture, 1 ms apart: about 0.03 events per pixel and step."""
    base = rng.uniform(0.05, 1.0, (h, w)).astype(np.float32)
    phase = rng.uniform(0, 2 * np.pi, (h, w)).astype(np.float32)
    k = np.arange(steps, dtype=np.float32)[:, None, None]
    lin = np.clip(base * np.exp(0.6 * np.sin(phase + 0.02 * k)), 0, 1).astype(np.float32)
    return lin, 1000 + 1000 * np.arange(steps, dtype=np.int64)


def run(lin, t, degrade, group_pixels: int, rounds: int) -> tuple[float, np.ndarray, int]:
    """Best time of ``rounds`` (s) of the kernel over every frame but the first, the events, the
    rows per group (the sensors' ``group_pixels``)."""
    log = np.log(lin + np.float32(SensorConfig().log_eps))
    best, events, group = float("inf"), None, 0
    for _ in range(rounds):
        s = Sensor(lin.shape[2], lin.shape[1], SensorConfig(), degrade, np.random.default_rng(1),
                   group_pixels=group_pixels)
        group = s._group
        s.step(lin[:1], t[:1])
        t0 = time.perf_counter()
        ev = s.step(lin[1:], t[1:], log_frames=log[1:])
        best = min(best, time.perf_counter() - t0)
        events = ev.array
    return best, events, group


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "sensor_groups")
    args = ap.parse_args()
    numba.set_num_threads(1)
    default = sensor_mod.GROUP_PIXELS
    rows = []
    for shape_name, (h, w) in SHAPES.items():
        lin, t = frames(h, w, args.steps, np.random.default_rng(h * 1000 + w))
        for eff_name, eff in EFFECTS.items():
            degrade = dataclasses.replace(ideal(DegradeConfig()), **eff)
            run(lin[:3], t[:3], degrade, default, 1)        # compile/load outside the timing
            one, ev_one, _ = run(lin, t, degrade, 1, args.rounds)
            grouped, ev_grouped, group = run(lin, t, degrade, default, args.rounds)
            if not np.array_equal(ev_one, ev_grouped):
                raise SystemExit(f"{shape_name} / {eff_name}: the events differ between the layouts")
            n = (args.steps - 1) * h * w
            rows.append({"shape": shape_name, "height": h, "width": w, "effect": eff_name, "rows_per_group": group,
                         "ns_per_pixel_step_one_row": one / n * 1e9, "ns_per_pixel_step_grouped": grouped / n * 1e9,
                         "speedup": one / grouped, "events_per_pixel_step": len(ev_one) / n, "events_equal": True})
            print(f"{shape_name:42s} {eff_name:26s} g={group:3d} {rows[-1]['ns_per_pixel_step_one_row']:6.2f} -> "
                  f"{rows[-1]['ns_per_pixel_step_grouped']:6.2f} ns  x{rows[-1]['speedup']:.2f}", flush=True)
    out = {"benchmark": "sensor_groups", "machine": {**machine(), "numba": numba.__version__},
           "group_pixels": default, "steps": args.steps, "rounds": args.rounds, "numba_threads": 1, "rows": rows}
    write_json(args.out.with_suffix(".json"), out)
    lines = ["# Pixel kernel: groups of rows against one row per group",
             "", f"`benchmarks/bench_sensor_groups.py`, {out['machine']['cpu']}, one numba thread, best of "
             f"{args.rounds}; {args.steps} frames 1 ms apart; the events of both layouts equal in every row.", "",
             "| frame | H x W | effect | rows per group | ns per pixel-step, one row | grouped | speed-up |",
             "|---|---|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['shape']} | {r['height']} x {r['width']} | {r['effect']} | {r['rows_per_group']} | "
                     f"{r['ns_per_pixel_step_one_row']:.2f} | {r['ns_per_pixel_step_grouped']:.2f} | "
                     f"{r['speedup']:.2f}x |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(json.dumps({"written": str(args.out.with_suffix(".json"))}))


if __name__ == "__main__":
    main()
