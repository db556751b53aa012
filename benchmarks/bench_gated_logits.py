"""Where computing the occupancy logits at the supported pixels alone stops paying: the
crossover behind :data:`rdnet.nn.decision.GATED_MAX_SUPPORT`.

The two ways :meth:`rdnet.nn.models.RestoreNet.sparse_heads` gets the kept voxels of a
DAVIS346-size window (8-channel features at the padded 352 x 264, the 20 logit channels of
the study's tiny restorer, random weights: the cost does not depend on them), each with the
read-back of the kept positions: the dense 3 x 3 conv, its threshold mask and the mask's
non-zero positions; or the 3 x 3 x 8 neighbourhoods of the given pixels (``_patches``), one
matrix product and the threshold. Medians of 15 calls per point, at 1 and 2 torch threads,
for pixel shares from 1 % to 60 % (a DAVIS346 window: 1.6 % on average, 2.7 % at most).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_gated_logits.py   # writes
        benchmarks/results/restore_gated_logits.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from rdnet.nn.models import _patches

ROOT = Path(__file__).resolve().parents[1]
H, W, HP, WP, WIDTH, LOGITS = 260, 346, 264, 352, 8, 20
SHARES = (0.01, 0.02, 0.05, 0.1, 0.15, 0.25, 0.4, 0.6)


def _median_ms(fn, *args, rep: int = 15) -> float:
    fn(*args)
    times = []
    for _ in range(rep):
        t = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t)
    return float(np.median(times) * 1000)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_gated_logits.json")
    args = ap.parse_args()
    g = torch.Generator().manual_seed(0)
    feats = torch.randn(1, WIDTH, HP, WP, generator=g).contiguous(memory_format=torch.channels_last)
    weight = torch.randn(LOGITS, WIDTH, 3, 3, generator=g).contiguous(memory_format=torch.channels_last)
    bias = torch.randn(LOGITS, generator=g)
    flat_w = weight.permute(0, 2, 3, 1).reshape(LOGITS, -1)

    def dense():
        keep = F.conv2d(feats, weight, bias, padding=1)[..., :H, :W] >= 0.5
        return np.flatnonzero(keep.permute(0, 2, 3, 1).contiguous().numpy())

    def gated(y, x):
        n = y.size
        patch = _patches(feats, torch.zeros(n, dtype=torch.int64), torch.as_tensor(y), torch.as_tensor(x), 3)
        return np.flatnonzero((patch.reshape(n, -1) @ flat_w.T + bias >= 0.5).numpy())

    rng = np.random.default_rng(0)
    rows = []
    threads0 = torch.get_num_threads()
    try:
        with torch.inference_mode():
            for threads in (1, 2):
                torch.set_num_threads(threads)
                row = {"threads": threads, "dense_ms": _median_ms(dense), "gated_ms": {}}
                for share in SHARES:
                    idx = np.sort(rng.choice(H * W, int(share * H * W), replace=False))
                    row["gated_ms"][str(share)] = _median_ms(gated, idx // W, idx % W)
                rows.append(row)
                print(json.dumps(row))
    finally:
        torch.set_num_threads(threads0)
    out = {"benchmark": "gated_logits", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                     "platform": platform.platform(), "torch": torch.__version__},
           "window": {"height": H, "width": W, "feature_channels": WIDTH, "logit_channels": LOGITS},
           "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
