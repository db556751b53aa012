"""Peak memory of the study's data steps (scenes -> interpolate -> simulate) on one large
sequence: they stream (rdnet.study.data), so the peak stays far below the size of the
upsampled frames, which earlier versions held in memory whole.

Each step runs in a fresh process (``ru_maxrss`` of that process); the result records
the bytes of the upsampled float32 frames for comparison.

    .venv/bin/python benchmarks/bench_data_memory.py     # writes benchmarks/results/data_memory.json
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _step(name: str, sets: list, work: str, q) -> None:
    from rdnet.config import load_params
    from rdnet.study import data as D
    p = load_params(ROOT / "params.yaml", sets)
    w = Path(work)
    t = time.perf_counter()
    {"scenes": lambda: D.render_scenes(p, w / "scenes"),
     "interpolate": lambda: D.interpolate_scenes(p, w / "scenes", w / "interp"),
     "simulate": lambda: D.simulate_sequences(p, w / "scenes", w / "interp", w / "events")}[name]()
    q.put({"step": name, "wall_s": round(time.perf_counter() - t, 1),
           "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)})


def _run(height: int, width: int, frames: int) -> dict:
    sets = ["scenes.n_train=1", "scenes.n_test=1", f"scenes.height={height}", f"scenes.width={width}",
            f"scenes.n_frames={frames}", "scenes.supersample=1"]
    ctx = mp.get_context("spawn")
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for name in ("scenes", "interpolate", "simulate"):
            q = ctx.Queue()
            pr = ctx.Process(target=_step, args=(name, sets, work, q))
            pr.start()
            rows.append(q.get())
            pr.join()
            print(frames, rows[-1], flush=True)
        import h5py
        with h5py.File(Path(work) / "interp" / "train" / "seq_000.h5") as f:
            n_up = int(f["frames/images"].shape[0])
        with h5py.File(Path(work) / "events" / "train" / "seq_000.h5") as f:
            n_ev = {g: int(f[g]["t"].shape[0]) for g in ("events", "events_ideal")}
    return {"sequence": {"height": height, "width": width, "frames": frames, "upsampled_frames": n_up,
                         "upsampled_float32_mb": round(n_up * height * width * 4 / 2**20, 1), "events": n_ev},
            "steps": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--frames", type=int, nargs="+", default=[48, 96],
                    help="sequence lengths (a bounded peak does not grow with them)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "data_memory.json")
    a = ap.parse_args()
    runs = [_run(a.height, a.width, n) for n in a.frames]
    doc = {"benchmark": "data_memory", "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
           "runs": runs,
           "note": "peak RSS of each step's process (one sequence per split), against the size of one "
                   "sequence's upsampled float32 frames"}
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(a.out, json.dumps(doc, indent=2) + "\n")


if __name__ == "__main__":
    main()
