"""Whether the learned restorer's windows, run one per core (``restore.workers``), need
their numba threads set too: the DAVIS346 recording written 10 times back to back
(``bench_restore.repeated_h5``), 60 windows of the study's image-guided restorer restored by
2 threads of one torch thread each, with 1 or 2 numba threads per window (the layer-norm
kernel of :mod:`rdnet.nn.cpu_kernels`), alternated over 8 rounds, in process. Result: the
per-window times and their medians (``benchmarks/results/restore_window_numba_threads.json``);
the same (29.1 against 29.2 ms a window on the 2026-11-30 host), so
:meth:`rdnet.restore.learned.LearnedRestorer.parallel` shares torch's threads only.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_window_numba_threads.py    # needs models/restore_image
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numba
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_restore import RECORDINGS, ROOT, repeated_h5  # noqa: E402

from rdnet.config import load_params  # noqa: E402
from rdnet.events.io import load  # noqa: E402
from rdnet.restore.learned import load_restorer  # noqa: E402
from rdnet.restore.run import nearest_frame  # noqa: E402

ROUNDS, WINDOWS = 8, 60


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x10.h5"
        repeated_h5(RECORDINGS["davis346_road"], 10, path)
        rec = load(path)
    r = load_restorer(None, has_frames=True, params=load_params(ROOT / "params.yaml"))
    ev, frames = rec.events, rec.frames
    grey = frames.grey()
    W = int(r.window_us)
    t0 = int(ev.t[0])
    wins = [(t0 + k * W, t0 + (k + 1) * W) for k in range(WINDOWS)]

    def one(w, threads):
        numba.set_num_threads(threads)          # per thread: this window's own
        return r.restore(ev, w[0], w[1], nearest_frame(frames, (w[0] + w[1]) // 2, grey))

    times = {1: [], 2: []}
    torch_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with ThreadPoolExecutor(2) as pool:
            for rnd in range(ROUNDS):
                for nb in ((1, 2) if rnd % 2 else (2, 1)):
                    list(pool.map(lambda w: one(w, nb), wins[:4]))          # warm
                    t = time.perf_counter()
                    list(pool.map(lambda w: one(w, nb), wins))
                    times[nb].append((time.perf_counter() - t) / WINDOWS * 1000)
    finally:
        torch.set_num_threads(torch_threads)
    out = {"benchmark": "restore_window_numba_threads", "windows": WINDOWS, "window_us": W, "rounds": ROUNDS,
           "ms_per_window": {str(k): [round(x, 2) for x in v] for k, v in times.items()},
           "median_ms_per_window": {str(k): float(np.median(v)) for k, v in times.items()}}
    dest = ROOT / "benchmarks" / "results" / "restore_window_numba_threads.json"
    dest.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out["median_ms_per_window"]))


if __name__ == "__main__":
    main()
