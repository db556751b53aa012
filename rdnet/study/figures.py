"""Sample grid of the study: blurry | degraded events | restored events | RDNet | sharp."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def sample_figure(params: dict, pairs_path: Path, out: Path, n: int = 4) -> Path:
    from rdnet.config import section
    from rdnet.eval.predict import predict
    from rdnet.eval.report import sample_grid
    cfg = section(params, "ablation")
    row = cfg.row("rdnet")
    import h5py
    with h5py.File(pairs_path, "r") as f:
        total = f["blurry"].shape[0]
    idx = np.linspace(0, total - 1, min(n, total)).astype(int)
    from rdnet.study.config import seed_checkpoint
    seed = section(params, "study").seeds[0]
    res = predict("rdnet", seed_checkpoint(row.checkpoint, seed), pairs_path, "degraded", indices=idx.tolist(),
                  batch_size=cfg.batch_size, device=cfg.device)
    return sample_grid(out, res["blurry"], res["voxel"], res["restored"], res["pred"], res["sharp"])
