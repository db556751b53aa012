"""Speed of the event simulator (rdnet.sim.sensor) on a DAVIS346-sized panning scene.

A natural image (skimage.data.camera, uint8 / 255 taken as linear intensity) is panned
along a Lissajous path at ~1 px per step (sub-pixel shifts with cv2.warpAffine, generated
on the fly in chunks), sampled at a 1 kHz internal step, and fed to :class:`Sensor`
once with all degradations on and once ideal. Reported: simulator steps/s and
pixel-steps/s (time inside Sensor.step only), end-to-end steps/s including the frame
generation, events/s, numba warm-up (first call, compile or cache load) separately, and
peak resident memory. CPU time (all threads) and the machine's load average are recorded
too: on a shared machine the wall-clock rates depend on what else runs, so each case runs
``--repeat`` times and the best run is the headline (all runs are kept). Each case runs in
its own process, so its peak memory is its own.

    .venv/bin/python benchmarks/bench_simulator.py [--steps 2000] [--chunk 50] [--repeat 3]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numba
import numpy as np
import skimage.data

from rdnet.sim.sensor import Sensor
from rdnet.sim.settings import DegradeConfig, SensorConfig

W, H = 346, 260
STEP_US = 1000

ALL_ON = DegradeConfig(threshold_sigma=0.1, onoff_ratio=1.2, cutoff_hz=300.0, sample_period_us=200.0,
                       refractory_us=100.0, shot_noise_hz=1.0, leak_hz=0.1, hot_pixel_fraction=1e-3,
                       hot_pixel_hz=100.0, jitter_us=100.0, latency_us=50.0)


class PanningScene:
    """Frames of a panned natural image: offset (80 sin(2 pi k / 503), 60 sin(2 pi k / 331))."""

    def __init__(self):
        img = skimage.data.camera().astype(np.float32) / 255.0
        self.img = img
        self.cx = (img.shape[1] - W) / 2
        self.cy = (img.shape[0] - H) / 2

    def frames(self, k0: int, n: int) -> np.ndarray:
        out = np.empty((n, H, W), np.float32)
        for i in range(n):
            k = k0 + i
            dx = self.cx + 80 * math.sin(2 * math.pi * k / 503)
            dy = self.cy + 60 * math.sin(2 * math.pi * k / 331)
            m = np.array([[1, 0, -dx], [0, 1, -dy]], np.float32)
            cv2.warpAffine(self.img, m, (W, H), dst=out[i], flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT)
        return out


def run(degrade: DegradeConfig | None, steps: int, chunk: int, seed: int = 0) -> dict:
    scene = PanningScene()
    sensor = Sensor(W, H, SensorConfig(), degrade, np.random.default_rng(seed))
    # warm-up: first call compiles (or loads the numba cache); excluded from the timing
    t_w = time.perf_counter()
    sensor.step(scene.frames(0, 2), np.arange(2, dtype=np.int64) * STEP_US)
    warm_s = time.perf_counter() - t_w
    k, n_ev, t_sim, cpu_sim = 2, 0, 0.0, 0.0
    load0 = os.getloadavg()[0]
    t_all = time.perf_counter()
    while k < steps + 2:
        n = min(chunk, steps + 2 - k)
        fr = scene.frames(k, n)
        t = (k + np.arange(n, dtype=np.int64)) * STEP_US
        t_s, c_s = time.perf_counter(), time.process_time()
        n_ev += len(sensor.step(fr, t))
        t_sim += time.perf_counter() - t_s
        cpu_sim += time.process_time() - c_s
        k += n
    t_s = time.perf_counter()
    n_ev += len(sensor.flush())
    t_sim += time.perf_counter() - t_s
    total = time.perf_counter() - t_all
    return {
        "degradations": "all" if degrade is not None else "none (ideal)",
        "degrade": None if degrade is None else {k: getattr(degrade, k) for k in degrade.active()},
        "steps": steps, "chunk": chunk,
        "warmup_s": round(warm_s, 3),
        "simulator_s": round(t_sim, 3),
        "simulator_steps_per_s": round(steps / t_sim, 1),
        "simulator_pixel_steps_per_s": round(steps * W * H / t_sim, 0),
        "simulator_cpu_s": round(cpu_sim, 3),
        "simulator_steps_per_cpu_s": round(steps / cpu_sim, 1),
        "load_average_1min_at_start": round(load0, 2),
        "end_to_end_steps_per_s": round(steps / total, 1),
        "events": int(n_ev),
        "events_per_step": round(n_ev / steps, 1),
        "events_per_s_wall": round(n_ev / t_sim, 0),
    }


def run_case(case: str, steps: int, chunk: int, repeat: int) -> dict:
    """``repeat`` runs of one case in this process; the best (highest simulator steps/s)
    is the headline, every run is listed."""
    degrade = ALL_ON if case == "all" else None
    runs = [run(degrade, steps, chunk) for _ in range(repeat)]
    best = max(runs, key=lambda r: r["simulator_steps_per_s"])
    out = dict(best)
    out["repeat"] = repeat
    out["runs_simulator_steps_per_s"] = [r["simulator_steps_per_s"] for r in runs]
    out["runs_load_average_1min_at_start"] = [r["load_average_1min_at_start"] for r in runs]
    out["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    out["peak_rss_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--chunk", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--case", choices=["all", "ideal"], help=argparse.SUPPRESS)   # child process
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "simulator.json")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    if args.case:
        print(json.dumps(run_case(args.case, args.steps, args.chunk, args.repeat)))
        return 0
    results = []
    for case in ("all", "ideal"):
        cmd = [sys.executable, __file__, "--case", case, "--steps", str(args.steps),
               "--chunk", str(args.chunk), "--repeat", str(args.repeat)]
        res = subprocess.run(cmd, check=True, capture_output=True, text=True)
        results.append(json.loads(res.stdout.strip().splitlines()[-1]))
    doc = {
        "benchmark": "rdnet.sim.sensor.Sensor on a panning natural image",
        "sensor_size": [W, H], "step_us": STEP_US, "goal_steps_per_s": 1000,
        "results": results,
        "peak_rss_mib": max(r["peak_rss_mib"] for r in results),
        "machine": {
            "cpu_count": os.cpu_count(),
            "numba_threads": numba.get_num_threads(),
            "numba_threading_layer": _threading_layer(),
            "processor": platform.processor() or platform.machine(),
            "python": sys.version.split()[0],
            "numpy": np.__version__, "numba": numba.__version__, "opencv": cv2.__version__,
        },
        "command": "python benchmarks/bench_simulator.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    text = json.dumps(doc, indent=2)
    print(text)
    if not args.no_write:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(text + "\n")
        os.replace(tmp, args.out)
    return 0


def _threading_layer() -> str:
    from rdnet.sim.sensor import sort_events
    sort_events(np.zeros(1, [("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")]))  # starts the pool
    try:
        return numba.threading_layer()
    except ValueError:
        return "unknown"


if __name__ == "__main__":
    sys.exit(main())
