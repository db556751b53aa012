"""Regime sweep of the RDNet row: where does restoring events pay off for deblurring?

The paper (Sec. 4.3, Tab. 3) finds RDNet (row 3) 0.51 dB above a DeblurNet trained on
degraded events (row 2); the embedded study does not reproduce it (docs/study.md, "Investigation
of the RDNet row"). This module reruns the rows that decide the question under *one*
change of params.yaml at a time (a :class:`Variant`: dotted ``--set`` overrides), every
network once per seed of ``study.seeds``, and scores them on the study's own test set
(``data/pairs/test.h5``: the same 37 test samples for every variant, so the variants are
compared with each other and with the committed study).

A variant that changes how the data is made (``scenes``, ``interpolate``, ``sensor``,
``degrade``, ``randomize``, ``blur``, ``voxel``, ``seed``) gets its own training pairs
(:mod:`rdnet.study.data`, both splits rendered; the test split is checked to be the
study's and the study's file is what is scored); the others train on
``data/pairs/train.h5``. Trained networks are kept in ``work/<variant>/models`` and a
rerun resumes or skips them.

Per variant the result holds the rows ``undegraded_train``, ``degraded_train``, ``rdnet``,
``upper_bound`` and ``restored`` (per-seed PSNR), the paired gaps (RDNet - row 2, row 2 -
row 1, restored - row 1; :func:`rdnet.study.report.paired_gap`), each network's
parameters and training FLOPs, and the stage-1 restoration error (voxel L1 on responses).
"""
from __future__ import annotations

import copy
import dataclasses
import logging
from pathlib import Path

import numpy as np

from rdnet.config import apply_sets, load_params, section, to_dict
from rdnet.errors import ConfigError, FormatError

log = logging.getLogger(__name__)

#: params sections (and top-level keys) that change the simulated data
DATA_KEYS = ("seed", "scenes", "interpolate", "sensor", "degrade", "randomize", "blur", "voxel")

#: (network directory, task, training events): what rows 1-4 and ``restored`` need.
#: ``rdnet`` starts stage 1 from ``restore`` and stage 2 from ``study.rdnet_stage2_init``.
NETWORKS = (("deblur_undegraded", "deblur", "undegraded"), ("deblur_degraded", "deblur", "degraded"),
            ("restore", "restore", "degraded"), ("rdnet", "rdnet", "degraded"))

ROWS = ("undegraded_train", "degraded_train", "rdnet", "upper_bound", "restored")

#: (name, row a, row b): gaps reported per variant (a - b, paired over seeds)
GAPS = (("rdnet_minus_row2", "rdnet", "degraded_train"),
        ("row2_minus_row1", "degraded_train", "undegraded_train"),
        ("restored_minus_row1", "restored", "undegraded_train"),
        ("upper_minus_rdnet", "upper_bound", "rdnet"))


@dataclasses.dataclass(frozen=True)
class Variant:
    """One regime: ``sets`` are dotted params overrides (as ``dvc exp run -S``)."""

    sets: tuple = ()
    note: str = ""


#: The regimes docs/study.md reports: one axis of the issue's list each.
VARIANTS = {
    "data_x4": Variant(("scenes.n_train=48",), "4x the training scenes (428 samples; same test set)"),
    "width_16": Variant(("model.width=16",), "every network twice as wide (about 4x parameters)"),
    "crop_64": Variant(("train.crop=64",), "64x64 crops: whole samples, 1.8x the pixels per step"),
    "iters_x3": Variant(("train.iterations=2400",), "3x the optimisation steps of every network"),
}


def variant_params(base: dict, variant: Variant) -> dict:
    """params.yaml with the variant's overrides applied and validated."""
    return load_params(None, variant.sets, base=base)


def changes_data(base: dict, params: dict) -> bool:
    return any(base.get(k) != params.get(k) for k in DATA_KEYS)


def _same_test_set(a: Path, b: Path) -> bool:
    import h5py
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        keys = ("blurry", "sharp", "voxel_degraded", "voxel_undegraded")
        return all(k in fa and k in fb and fa[k].shape == fb[k].shape
                   and np.array_equal(np.asarray(fa[k]), np.asarray(fb[k])) for k in keys)


def train_pairs(base: dict, params: dict, data_dir: Path, work: Path) -> Path:
    """The training pairs of a variant: the study's when the data settings are the
    study's, else freshly simulated into ``work/data`` (whose test split must equal the
    study's, so that every variant is scored on the same samples)."""
    study_train, study_test = data_dir / "pairs" / "train.h5", data_dir / "pairs" / "test.h5"
    if not study_test.is_file():
        raise FormatError(study_test, None, "missing: run `dvc repro blur` first (the study's test set)")
    if not changes_data(base, params):
        if not study_train.is_file():
            raise FormatError(study_train, None, "missing: run `dvc repro blur` first")
        return study_train
    from rdnet.study.data import interpolate_scenes, make_pairs, render_scenes, simulate_sequences
    d = work / "data"
    pairs = d / "pairs" / "train.h5"
    if not pairs.is_file():
        log.info("simulating the variant's data into %s", d)
        render_scenes(params, d / "scenes")
        interpolate_scenes(params, d / "scenes", d / "interp")
        simulate_sequences(params, d / "scenes", d / "interp", d / "events")
        make_pairs(params, d / "events", d / "pairs")
    if not _same_test_set(d / "pairs" / "test.h5", study_test):
        raise ConfigError("variant", "changes the test set; a regime variant may only change training data")
    return pairs


def train_networks(params: dict, pairs: Path, models: Path, *, parallel: int | None = None,
                   progress: bool = True) -> dict:
    """Train :data:`NETWORKS` for every seed of ``study.seeds``; returns their summaries."""
    from rdnet.study.config import NetworkConfig
    from rdnet.study.training import train_seeds
    study = section(params, "study")
    if parallel is not None:
        study = dataclasses.replace(study, parallel=int(parallel))
    init_deblur = study.rdnet_stage2_init
    if init_deblur not in (None, "deblur_undegraded"):
        raise ConfigError("study.rdnet_stage2_init", "the regime sweep trains deblur_undegraded only")
    out = {}
    for name, task, events in NETWORKS:
        log.info("training %s (%s, %s events)", name, task, events)
        out[name] = train_seeds(NetworkConfig(task=task, events=events), study, section(params, "train"),
                                section(params, "model"), pairs, models / name,
                                init=models / "restore" if task == "rdnet" else None,
                                init_deblur=models / init_deblur if task == "rdnet" and init_deblur else None,
                                progress=progress)
    return out


def _ablation(params: dict, models: Path):
    """The ``ablation`` section with the study's rows pointed at ``models``."""
    cfg = section(params, "ablation")
    rows = copy.deepcopy(dict(cfg.rows))
    for rid in ROWS:
        if rid not in rows:
            raise ConfigError(f"ablation.rows.{rid}", "the regime sweep needs this row")
        for key in ("checkpoint", "filter_checkpoint"):
            v = rows[rid].get(key)
            if v:
                rows[rid][key] = str(models / Path(v).name)
    return dataclasses.replace(cfg, rows=rows)


def evaluate_rows(params: dict, models: Path, test_pairs: Path, test_events: Path) -> dict:
    from rdnet.study.rows import evaluate_ablation_row
    cfg = _ablation(params, models)
    seeds = section(params, "study").seeds
    out = {}
    for rid in ROWS:
        r = evaluate_ablation_row(cfg, rid, test_pairs, test_events, seeds=seeds)
        out[rid] = {k: r[k] for k in ("psnr", "psnr_std", "psnr_seeds", "ssim", "ssim_std", "seeds")}
    return out


def gaps(rows: dict) -> dict:
    from rdnet.study.report import paired_gap
    return {name: paired_gap(rows[a], rows[b]) for name, a, b in GAPS if a in rows and b in rows}


def run_variant(name: str, variant: Variant, base: dict, *, data_dir: Path, work: Path,
                parallel: int | None = None, progress: bool = True) -> dict:
    """Train and score one variant; returns its JSON-ready result."""
    params = variant_params(base, variant)
    vwork = work / name
    pairs = train_pairs(base, params, data_dir, vwork)
    summaries = train_networks(params, pairs, vwork / "models", parallel=parallel, progress=progress)
    test_pairs, test_events = data_dir / "pairs" / "test.h5", data_dir / "events" / "test"
    rows = evaluate_rows(params, vwork / "models", test_pairs, test_events)
    from rdnet.study.rows import restoration_table
    rest = restoration_table(section(params, "ablation"), test_pairs, test_events,
                             {"rdnet": vwork / "models" / "rdnet"}, filters=(), seeds=section(params, "study").seeds)
    return {"sets": list(variant.sets), "note": variant.note, "own_training_data": pairs.parent != data_dir / "pairs",
            "train_samples": _n_samples(pairs), "rows": rows, "gaps": gaps(rows),
            "networks": {n: {"parameters": s["parameters"], "iterations": s["runs"][0]["iterations"],
                             "train_gflop": float(np.mean([r["train_gflop"] for r in s["runs"]])),
                             "wall_s_total": s["wall_s_total"]} for n, s in summaries.items()},
            "restoration_voxel_l1": {"degraded": rest["degraded"]["voxel_l1"],
                                     "rdnet_stage1": rest["rdnet"]["voxel_l1"],
                                     "rdnet_stage1_std": rest["rdnet"]["voxel_l1_std"]},
            "restoration_event_f1": {"degraded": (rest["degraded"].get("events") or {}).get("f1"),
                                     "rdnet_stage1": (rest["rdnet"].get("events") or {}).get("f1")},
            "model": to_dict(section(params, "model")), "train": to_dict(section(params, "train"))}


def _n_samples(pairs: Path) -> int:
    from rdnet.train.data import read_pairs_info
    return int(read_pairs_info(pairs).n)


def study_reference(rows_dir: Path, restoration: Path | None = None) -> dict | None:
    """The committed study's rows (``results/rows/<row>.json``, written by ``dvc repro``)
    and stage-1 restoration error (``metrics/restoration.json``) in the sweep's shape:
    the reference line of the table (params.yaml as is)."""
    import json
    rows = {}
    for rid in ROWS:
        p = rows_dir / f"{rid}.json"
        if not p.is_file():
            return None
        r = json.loads(p.read_text())
        rows[rid] = {k: r.get(k) for k in ("psnr", "psnr_std", "psnr_seeds", "ssim", "ssim_std", "seeds")}
    out = {"sets": [], "note": "params.yaml as is (the committed study: results/rows, metrics/restoration.json)",
           "rows": rows, "gaps": gaps(rows)}
    if restoration is not None and restoration.is_file():
        r = json.loads(restoration.read_text())
        out["restoration_voxel_l1"] = {"degraded": r["degraded"]["voxel_l1"], "rdnet_stage1": r["rdnet"]["voxel_l1"],
                                       "rdnet_stage1_std": r["rdnet"].get("voxel_l1_std")}
    return out


def _pm(g: dict) -> str:
    return f"{g['mean']:+.2f} ± {g['std']:.2f} ({g['positive']}/{g['n']}, p = {g['p']:.2f})" \
        if g.get("std") is not None else f"{g['mean']:+.2f}"


def markdown(results: dict) -> str:
    """The sweep as a Markdown table (one line per variant)."""
    head = ("| variant | change | row 1 | row 2 | RDNet | RDNet − row 2 | restored − row 1 | "
            "stage-1 voxel L1 (raw → restored) | RDNet / row 2 parameters |\n"
            "|---|---|---:|---:|---:|---|---|---|---|\n")
    lines = []
    for name, r in results.items():
        rows, g = r["rows"], r["gaps"]

        def cell(rid):
            x = rows[rid]
            return f"{x['psnr']:.2f} ± {x['psnr_std']:.2f}"
        l1 = r.get("restoration_voxel_l1")
        l1s = f"{l1['degraded']:.3f} → {l1['rdnet_stage1']:.3f}" if l1 else "-"
        nets = r.get("networks")
        par = f"{nets['rdnet']['parameters']:,} / {nets['deblur_degraded']['parameters']:,}" if nets else "-"
        change = ", ".join(f"`{s}`" for s in r["sets"]) or "none"
        lines.append(f"| `{name}` | {change} | {cell('undegraded_train')} | {cell('degraded_train')} | "
                     f"{cell('rdnet')} | {_pm(g['rdnet_minus_row2'])} | {_pm(g['restored_minus_row1'])} | "
                     f"{l1s} | {par} |")
    return head + "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> Path:
    """RDNet − row 2 per variant (mean ± std of the paired per-seed gaps, seeds as dots)."""
    from rdnet.eval.report import _figure, _save_figure
    names = list(results)
    fig, ax = _figure(figsize=(6.5, 0.9 + 0.45 * len(names)))
    for i, n in enumerate(names):
        g = results[n]["gaps"]["rdnet_minus_row2"]
        ax.errorbar(g["mean"], i, xerr=g["std"] or 0, fmt="o", color="C0", capsize=3)
        if g["per_seed"]:
            ax.plot(g["per_seed"], [i] * len(g["per_seed"]), "x", color="C1", alpha=0.7)
    ax.axvline(0, color="k", lw=0.8)
    ax.axvline(0.51, color="C2", ls="--", lw=0.8, label="paper +0.51 dB")
    ax.set_yticks(range(len(names)), names)
    ax.invert_yaxis()
    ax.set_xlabel("RDNet − row 2 (dB; dot: mean ± std over seeds, x: per seed)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    return _save_figure(fig, path)
