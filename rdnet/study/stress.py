"""Stress test: the trained rows on test sets whose degradation strength is fixed.

The study's test set draws each sequence's degradation from ``randomize.test_scale``
(1.0-1.5 x ``degrade``), disjoint from training (0.5-0.9 x). That answers "does it
generalise to unseen settings", but mixes strengths. Here the same test sequences are
simulated again with every active effect at exactly ``s`` x ``degrade`` for each ``s`` of
``study.stress_scales`` (inside, at the edge of and beyond the training range), and the
rows of ``study.stress_rows`` are scored on each, seed by seed: PSNR against
degradation strength, and RDNet's restoration error against it. This is where
"restoration helps when the degradation is stronger than what the deblurring network
was trained on" can be seen or refuted.
"""
from __future__ import annotations

import logging
from pathlib import Path

from rdnet.config import section
from rdnet.sim.settings import scale_ranges

log = logging.getLogger(__name__)


def stress_test(params: dict, scenes: Path, interp: Path, work: Path, *, progress: bool = True) -> dict:
    """``{"scales": [...], "rows": {row: [{"scale", "psnr", "psnr_std", "psnr_seeds", "ssim"}]},
    "restoration": {method: [{"scale", "voxel_l1", ..., "events_f1", "events_precision", ...}]}}``
    (methods of :func:`rdnet.study.rows.restoration_table`: raw, the event filters, the
    EDnCNN-style classifier and the study's stage-1 networks present under ``models/``); the simulated test sets go to
    ``work/scale_<s>/``."""
    from tqdm import tqdm
    from rdnet.study.data import make_pairs, simulate_sequences
    from rdnet.study.rows import LEARNED_RESTORERS, evaluate_ablation_row, restoration_table
    study = section(params, "study")
    ablation = section(params, "ablation")
    rows = list(study.stress_rows)
    for rid in rows:
        ablation.row(rid)                               # ConfigError for an unknown row
    restore = section(params, "restore")
    # the stage-1 networks of the study that exist (a partial study scores what it has)
    learned = {k: Path(v) for k, v in LEARNED_RESTORERS.items() if Path(v).exists()}
    from rdnet.restore.ednccn import STUDY_MODEL as ednccn
    ednccn = ednccn if ednccn.exists() else None         # the per-event classifier baseline, when trained
    out = {"scales": list(study.stress_scales), "rows": {r: [] for r in rows}, "restoration": {}}
    for s in tqdm(study.stress_scales, desc="stress", disable=not progress or None):
        d = Path(work) / f"scale_{s:g}"
        simulate_sequences(params, scenes, interp, d / "events", splits=("test",), fixed_scale=s)
        make_pairs(params, d / "events", d / "pairs", splits=("test",))
        pairs = d / "pairs" / "test.h5"
        for rid in rows:
            r = evaluate_ablation_row(ablation, rid, pairs, d / "events" / "test", seeds=study.seeds)
            out["rows"][rid].append({"scale": s, **{k: r[k] for k in ("psnr", "psnr_std", "ssim") if k in r},
                                     "psnr_seeds": r.get("psnr_seeds", [])})
        rest = restoration_table(ablation, pairs, d / "events" / "test", learned, seeds=study.seeds,
                                 baf_dt_us=restore.baf_dt_us, gef_bins=restore.gef_bins, ednccn=ednccn)
        for name, m in rest.items():
            ev = {f"events_{k}": v for k, v in m.get("events", {}).items() if isinstance(v, (int, float))}
            out["restoration"].setdefault(name, []).append(
                {"scale": s, **{k: v for k, v in m.items() if isinstance(v, (int, float))}, **ev})
        log.info("stress scale %g: %s", s, {r: round(v[-1]["psnr"], 2) for r, v in out["rows"].items()})
    return out


def plot_stress(path: Path, result: dict) -> Path:
    """PSNR against degradation strength, one line per row (error bars: seed spread), with
    the training range shaded."""
    from rdnet.eval.report import _figure, _save_figure
    fig, ax = _figure(figsize=(6.0, 4.0))
    for rid, pts in result["rows"].items():
        x = [p["scale"] for p in pts]
        ax.errorbar(x, [p["psnr"] for p in pts], yerr=[p.get("psnr_std", 0.0) for p in pts],
                    marker="o", capsize=3, label=rid)
    tr = result.get("train_scale")
    if tr:
        for i, (lo, hi) in enumerate(scale_ranges(tr)):
            ax.axvspan(lo, hi, color="0.9", zorder=0, label="training range" if i == 0 else None)
    ax.set_xlabel("degradation strength (x degrade, every effect)")
    ax.set_ylabel("PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save_figure(fig, path)


def stress_plot_data(result: dict) -> list[dict]:
    """One record per scale with a PSNR field per row (``dvc plots``)."""
    recs = []
    for i, s in enumerate(result["scales"]):
        rec = {"scale": s}
        for rid, pts in result["rows"].items():
            rec[rid] = pts[i]["psnr"]
        recs.append(rec)
    return recs
