"""Figures of the study: the sample grid (blurry | degraded events | restored events | RDNet |
sharp) and the rows' gaps to row 2 on both event generators."""
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


def gap_figure(rows: dict, circuit: dict, out: Path, base: str | None = None) -> Path:
    """Each trained row's PSNR gap to ``base`` (row 2), paired by seed, on rdnet's simulated
    test events (``rows``: ``results/rows/<row>.json``) beside the same networks on the events of
    the independent circuit generator (``circuit``: the ``rows`` of
    ``metrics/restoration_circuit.json``); bars are means, error bars the seed spread.
    ``base``: default :data:`rdnet.study.report.BASE_ROW`."""
    from rdnet.eval.report import _figure, _save_figure
    from rdnet.study.report import BASE_ROW, paired_gap, seed_paired
    base = base or BASE_ROW
    names = [r for r in rows if r != base and r in circuit and base in circuit and seed_paired(rows[r], rows.get(base))]
    sim = [paired_gap(rows[r], rows[base]) for r in names]
    cir = [paired_gap(circuit[r], circuit[base]) for r in names]
    fig, ax = _figure(figsize=(max(5.0, 0.8 * len(names) + 2.0), 3.6))
    x = np.arange(len(names))
    for off, gaps, label, color in ((-0.2, sim, "rdnet simulator (test split)", "tab:blue"),
                                    (0.2, cir, "independent circuit generator", "tab:orange")):
        ax.bar(x + off, [g["mean"] for g in gaps], 0.4, yerr=[g["std"] or 0.0 for g in gaps], capsize=3,
               color=color, label=label)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_ylabel(f"PSNR gap to {base} (dB)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.subplots_adjust(bottom=0.35, left=0.12, right=0.98, top=0.95)
    return _save_figure(fig, out)
