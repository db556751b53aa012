"""Parameter counts of every model kind and size, CPU forward time, and baseline speed.

Counts are for ``bins=10`` and grey / colour images; forward time is the median of a
few forward passes (no grad) of a (1, C, S, S) batch on CPU (``--size``); baselines:
STCF throughput (events/s, random events on a 346x260 sensor) and EDI time per frame.

    .venv/bin/python benchmarks/bench_params.py          # writes benchmarks/results/params.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from rdnet.baselines.edi import edi_from_voxel
from rdnet.baselines.stcf import stcf_mask
from rdnet.events import Events
from rdnet.nn.models import MODEL_KINDS, MODEL_SIZES, build_model, count_parameters


def timed(fn, repeats: int) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128, help="image side for the forward timing")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/results/params.json")
    args = ap.parse_args()
    torch.manual_seed(0)
    res: dict = {"machine": platform.processor() or platform.machine(),
                 "torch_threads": torch.get_num_threads(), "image_size": args.size, "models": {}}
    for size in MODEL_SIZES:
        for kind in MODEL_KINDS:
            row = {}
            for ch in (1, 3):
                m = build_model(kind, size, ch, 10).eval()
                row[f"params_c{ch}"] = count_parameters(m)
                if ch == 1:
                    row["config"] = {k: list(v) if isinstance(v, tuple) else v
                                     for k, v in m.config.items() if not isinstance(v, dict)}
            img = torch.rand(1, 1, args.size, args.size)
            vox = torch.randn(1, 10, args.size, args.size)
            m = build_model(kind, size, 1, 10).eval()
            with torch.no_grad():
                call = (lambda: m(img)) if kind == "image_only" else (lambda: m(img, vox))
                row["forward_s_cpu"] = round(timed(call, args.repeats), 4)
            res["models"][f"{size}/{kind}"] = row
    rdnet = res["models"]["paper/rdnet"]["params_c1"]
    res["paper_rdnet_vs_7.86M"] = round(rdnet / 7.86e6 - 1, 4)

    rng = np.random.default_rng(0)
    n = 2_000_000
    ev = Events.from_columns(np.sort(rng.integers(0, 10_000_000, n)), rng.integers(0, 346, n),
                             rng.integers(0, 260, n), rng.integers(0, 2, n), 346, 260)
    res["stcf_events_per_s"] = round(n / timed(lambda: stcf_mask(ev, 5000, 2, 1), args.repeats))
    blurry = rng.random((260, 346)).astype(np.float32)
    vox = rng.integers(-2, 3, (10, 260, 346)).astype(np.float32)
    res["edi_from_voxel_s_346x260"] = round(timed(lambda: edi_from_voxel(blurry, vox), 1), 3)

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(res, indent=1) + "\n")
    os.replace(tmp, out)
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
