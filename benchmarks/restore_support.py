"""The support rule of the voxel -> event decision, measured on the study's trained restorers
(issue 11: DVXplorer background <= 15 %, better than BAF; no invented events).

The count restorers keep most input events that have no neighbour: on the validation rows of
the study's restorers about 80 % of the isolated input events are kept while 3 % of them are
real (docs/restoration.md, "Events with no neighbour"). The support rule
(:func:`rdnet.nn.decision.fit_support`, ``train.support_rule``) drops the kept voxels of pixels
without an input event at any of their 8 neighbours in the window, when the validation rows
say those voxels are real less often than the occupancy threshold, and refits the threshold.

This script refits the decision of each study restorer (``models/restore_image`` and
``models/restore_events``, every seed; the weights untouched) with and without the rule on its
own validation rows (:func:`rdnet.train.loop.fit_decision`), and scores both decisions

- on the simulated test pairs (``data/pairs/test.h5``: the event metrics of
  ``benchmarks/restore_learned_eval.py``);
- on every real recording ``restore_real`` scores (:func:`restore_training_scenes.score_real`:
  events kept, activity / background kept, ESR, the DAVIS346 consistency; image-guided where
  the recording has frames), raw and BAF beside them.

Writes ``benchmarks/results/restore_support.{json,md}``.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_support.py     # about 4 min on 2 cores
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TASKS = {"image": "restore_image", "events": "restore_events"}
METRICS = ("precision", "recall", "f1", "count_ratio", "l1_all", "l1_events")
log = logging.getLogger("restore_support")


#: decision variants: name -> (support rule, count gain)
RULES = {"threshold": (False, False), "support": (True, False), "support+gain": (True, True)}


def refit(path: Path, out: Path, support_rule: bool, count_gain: bool = False) -> dict:
    """A copy of checkpoint ``path`` at ``out`` whose decision is refitted on its validation
    rows (with or without the support rule and the count gain); returns that decision."""
    import numpy as np
    import torch

    from rdnet.train import checkpoint as ckpt_mod
    from rdnet.train.loop import fit_decision
    ck = ckpt_mod.read_checkpoint(path)
    net = ckpt_mod.model_from_checkpoint(path, ck).eval()
    extra = ck["extra"]
    decision = fit_decision(net, ROOT / extra["train_path"], np.asarray(extra["val_rows"], np.int64),
                            torch.device("cpu"), image=net.image_channels > 0, support_rule=support_rule,
                            count_gain=count_gain)
    out.parent.mkdir(parents=True, exist_ok=True)
    ckpt_mod.save_checkpoint(out, {**ck, "extra": {**extra, "decision": decision}})
    return decision


def table(res: dict) -> str:
    import numpy as np
    lines = [f"Decisions refitted on each restorer's validation rows: the threshold alone, with the support rule, and with the support rule and the count gain "
             f"(`python benchmarks/restore_support.py`, seeds {res['seeds']}). Test: `data/pairs/test.h5` "
             f"(raw: F1 {res['raw']['f1']:.3f}, count ratio {res['raw']['count_ratio']:.2f}, "
             f"all-voxel L1 {res['raw']['l1_all']:.4f}).", "",
             "| restorer | rule | seed | threshold | validation: unsupported kept voxels (share of kept), precision | "
             "count gain (validation F1) | test F1 | test count ratio | test all-voxel L1 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for label, runs in res["runs"].items():
        task, rule = label.split("/")
        for seed, r in runs.items():
            sup = r["decision"].get("support") or {}
            v = "-" if not sup else (f"{sup['val_events']:,} ({100 * sup['val_share_of_kept']:.1f} %), "
                                     f"{sup['val_precision']:.3f}" + (" -> dropped" if sup["drop"] else ""))
            t = r["test"]
            cg = r["decision"].get("count_gain")
            g = "-" if not cg else f"{cg['gain']:g} ({cg['val_f1'][format(cg['gain'], 'g')]:.3f})"
            lines.append(f"| {task} | {rule} | {seed} | {r['decision']['threshold']:.3f} | {v} | {g} | {t['f1']:.3f} | "
                         f"{t['count_ratio']:.2f} | {t['l1_all']:.4f} |")
    lines += ["", "Real recordings (as `restore_real` scores them; means over seeds; activity / background = share "
              "of the raw events kept inside / outside the activity mask):", "",
              "| recording | method | events kept | activity kept | background kept | ESR | consistency R^2 |",
              "|---|---|---|---|---|---|---|"]
    for rec, r in res["real"].items():
        groups: dict[str, list] = {}
        for label, m in r["methods"].items():
            groups.setdefault(label.rsplit("/", 1)[0] if "/" in label else label, []).append(m)
        for name, ms in groups.items():
            mean = lambda k: float(np.mean([m[k] for m in ms]))  # noqa: E731
            cons = [m["consistency_r2"] for m in ms if m["consistency_r2"] is not None]
            c = f"{np.mean(cons):.3f}" if cons else "-"
            lines.append(f"| {rec} | {name} ({len(ms)}) | {100 * mean('kept_fraction'):.1f} % | "
                         f"{100 * mean('activity'):.1f} % | {100 * mean('background'):.1f} % | {mean('esr'):.3f} | {c} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--test", type=Path, default=ROOT / "data" / "pairs" / "test.h5")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_support.json")
    ap.add_argument("--table-only", action="store_true", help="only rewrite OUT.md from OUT (.json)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from restore_train_range import rewrite_table, write_results
    if args.table_only:
        return rewrite_table(args.out, table)
    import torch
    from restore_learned_eval import eval_pairs
    from restore_training_scenes import RECORDINGS, score_real_recordings

    from rdnet.config import load_params

    torch.set_num_threads(2)
    params = load_params(ROOT / "params.yaml")
    res = {"seeds": args.seeds, "test_pairs": str(args.test.relative_to(ROOT)), "runs": {}, "real": {}}
    with tempfile.TemporaryDirectory() as tmp:
        ckpts = {}
        for task, name in TASKS.items():
            for rule, (support_rule, count_gain) in RULES.items():
                res["runs"][f"{task}/{rule}"] = {}
                for seed in args.seeds:
                    out = Path(tmp) / name / rule.replace("+", "_") / f"seed{seed}" / "model.pt"
                    decision = refit(ROOT / "models" / name / f"seed{seed}" / "model.pt", out, support_rule, count_gain)
                    ckpts[f"{task}/{rule}/{seed}"] = out
                    res["runs"][f"{task}/{rule}"][str(seed)] = {"decision": decision}
        scored = eval_pairs(args.test, ckpts)
        res["raw"] = {m: scored["raw"][m] for m in METRICS}
        for key, ck in ckpts.items():
            task, rule, seed = key.split("/")
            res["runs"][f"{task}/{rule}"][seed]["test"] = {m: scored[key][m] for m in METRICS}
        def learned(rec):                   # image-guided where the recording has frames
            task = "image" if rec == "davis346_road" else "events"
            return {k: ck for k, ck in ckpts.items() if k.startswith(task + "/")}
        res["real"] = score_real_recordings(RECORDINGS, params, learned, Path(tmp) / "real")
    write_results(args.out, res, table)


if __name__ == "__main__":
    main()
