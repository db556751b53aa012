"""Does the events-only restorer learn to remove a real camera's background noise when some of
its training sequences are filmed by a still camera? (issue 11, goal "DVXplorer background
<= 15 %, person >= 75 %, better than BAF").

With ``scenes.static_fraction: 0`` every training sequence pans (``scenes.speed_px`` with
shake): nearly every pixel sees moving texture, about 8 undegraded events per pixel and window
(about 200 per pixel and second), and only 1-2 % of the degraded events are noise in pixels
that hold no undegraded event. A real recording is sparse (0.1-2.5 events per pixel and second
for the DAVIS346, DVXplorer, ECD and night files) and, with a static camera, its background
holds noise only. This script renders the training split with each variant's ``scenes``
overrides (default: ``static_fraction`` 0, 0.25 and 0.5: that share of the sequences has a still
camera, the objects still move), simulates and pairs it with the study's other settings,
trains the events-only count stage 1 (``restore_events``, study ``model``/``train`` settings;
``--task restore``: the image-guided one, for recordings with frames) per seed, and scores
every network

- on simulated test pairs (``--test``, default the study's ``data/pairs/test.h5``; more than one
  may be given as NAME=PATH) with the event metrics of ``benchmarks/restore_learned_eval.py``;
- on the real recordings, with no ground truth, as ``restore_real`` does (after the hot-pixel
  pass): events kept, the share of the raw events kept inside the activity mask and outside it
  (background), ESR, and with frames the event-frame consistency; raw and BAF beside them.

Training is byte-deterministic, so a variant equal to the study's settings reproduces the
study's ``models/restore_events/seed<k>``. ``--work DIR`` keeps the pairs and networks (and
reuses those already there).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_training_scenes.py   # about 30 min on 2 cores
        writes benchmarks/results/restore_training_scenes.{json,md}
"""
from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_VARIANTS = ['pan={"static_fraction": 0.0}', 'static25={"static_fraction": 0.25}',
                    'static50={"static_fraction": 0.5}']
#: real recordings (folder names under data/real or ../shared/real)
RECORDINGS = ("dvxplorer_person", "prophesee_evk4_night", "ecd_shapes_subset", "davis346_road")
METRICS = ("precision", "recall", "f1", "count_ratio", "l1_all", "l1_events")
log = logging.getLogger("restore_training_scenes")


def training_pairs(params: dict, scenes_overrides: dict, work: Path) -> Path:
    """The training pairs of ``params`` rendered with ``scenes_overrides`` (both splits are
    rendered and interpolated, as the study's functions do; only the training split is
    simulated and paired)."""
    from rdnet.study.data import interpolate_scenes, make_pairs, render_scenes, simulate_sequences

    p = {**params, "scenes": {**params["scenes"], **scenes_overrides}}
    render_scenes(p, work / "scenes")
    interpolate_scenes(p, work / "scenes", work / "interp")
    simulate_sequences(p, work / "scenes", work / "interp", work / "events", splits=("train",))
    make_pairs(p, work / "events", work / "pairs", splits=("train",))
    return work / "pairs" / "train.h5"


@contextlib.contextmanager
def restorers_from(wrap):
    """Inside the block, ``rdnet restore``'s restorer lookup
    (:func:`rdnet.restore.learned.load_restorer`, which :func:`score_real` reaches) answers with
    ``wrap(original)``: a function of the same signature, given the original lookup. How a
    benchmark hands a restorer that is not a checkpoint to the user's code path."""
    import rdnet.restore.learned as learned
    original = learned.load_restorer
    learned.load_restorer = wrap(original)
    try:
        yield
    finally:
        learned.load_restorer = original


def score_real(path: Path, name: str, params: dict, runs: dict[str, tuple[str, Path | None]], work: Path) -> dict:
    """``runs``: label -> (method, checkpoint), scored as ``restore_real`` scores them
    (:func:`rdnet.restore.real.score_recording`): events kept, activity / background kept,
    ESR, with frames the consistency R^2, and on recordings with known hot pixels their share kept."""
    from rdnet.restore.real import Run, read_facts, score_recording
    sc = score_recording(name, path, params, [Run(k, m, ck) for k, (m, ck) in runs.items()], work / name,
                         keep=False, facts=read_facts(ROOT / "stages" / "real_recordings.yaml"))
    out = {"events": sc.entry["events"], "methods": {}}
    for label, m in sc.entry["methods"].items():
        out["methods"][label] = {"events_out": m["events_out"], "kept_fraction": m["kept_fraction"],
                                 "not_recorded_fraction": m["not_recorded_fraction"],
                                 "activity": m["regions"]["activity"], "background": m["regions"]["background"],
                                 "consistency_r2": m["consistency_r2"], "esr": m["esr"],
                                 **({"hot_pixels": m["regions"]["hot_pixels"]} if "hot_pixels" in m["regions"] else {})}
        log.info("%s %s: %s", name, label, out["methods"][label])
    return out


def score_real_recordings(names, params: dict, learned, work: Path) -> dict:
    """:func:`score_real` of every recording folder in ``names`` found under ``data/real`` or
    ``../shared/real`` (the others skipped with a warning), with raw, BAF and each
    ``label -> checkpoint`` of ``learned(name)`` as ``rdnet``: ``name -> {path, ...}``."""
    from rdnet.restore.real import recordings
    found = dict(recordings([ROOT / "data" / "real", ROOT.parent / "shared" / "real"]))
    out = {}
    for rec in names:
        path = found.get(rec)
        if path is None:
            log.warning("%s not found: skipped", rec)
            continue
        runs = {"raw": ("raw", None), "baf": ("baf", None), **{k: ("rdnet", ck) for k, ck in learned(rec).items()}}
        out[rec] = {"path": str(path.relative_to(ROOT.parent)), **score_real(path, rec, params, runs, work)}
    return out


def summary(res: dict) -> str:
    """Means over seeds per variant: simulated F1 / count ratio per test set, and per real
    recording the activity and background kept, ESR and consistency (BAF and raw beside)."""
    import numpy as np
    tests = list(res["test_pairs"])
    recs = list(res["real"])
    head = ["variant"] + [f"{t}: F1 / count ratio" for t in tests] + [f"{r}: activity / background kept" for r in recs]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]

    def real_cell(rec, labels):
        ms = [res["real"][rec]["methods"][k] for k in labels if k in res["real"][rec]["methods"]]
        return f"{100 * np.mean([m['activity'] for m in ms]):.1f} / {100 * np.mean([m['background'] for m in ms]):.1f} %"
    for base in ("raw", "baf"):
        cells = [f"{res['raw'][t]['f1']:.3f} / {res['raw'][t]['count_ratio']:.2f}" if base == "raw" else "-" for t in tests]
        lines.append(f"| {base} | " + " | ".join(cells + [real_cell(r, [base]) for r in recs]) + " |")
    for name, v in res["variants"].items():
        runs = v["runs"]
        cells = [f"{np.mean([r['test'][t]['f1'] for r in runs.values()]):.3f} / "
                 f"{np.mean([r['test'][t]['count_ratio'] for r in runs.values()]):.2f}" for t in tests]
        cells += [real_cell(r, [f"{name}/{seed}" for seed in runs]) for r in recs]
        lines.append(f"| {name} ({json.dumps(v['scenes_overrides'])}), mean of {len(runs)} seeds | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def table(res: dict) -> str:
    lines = ["Means over seeds:", "", summary(res).rstrip("\n"), ""]
    for test, path in res["test_pairs"].items():
        lines += [f"Simulated test pairs `{path}` ({test}):", "",
                  "| variant | seed | " + " | ".join(METRICS) + " | fitted threshold |",
                  "|---|---|" + "---:|" * (len(METRICS) + 1),
                  "| raw degraded events | - | " + " | ".join(f"{res['raw'][test][m]:.3f}" for m in METRICS) + " | - |"]
        for name, v in res["variants"].items():
            for seed, run in v["runs"].items():
                lines.append(f"| {name} | {seed} | " + " | ".join(f"{run['test'][test][m]:.3f}" for m in METRICS)
                             + f" | {run['threshold']:.3f} |")
        lines.append("")
    lines += ["Real recordings (after the hot-pixel pass; kept = share of the raw events; activity / "
              "background = share of the raw events kept inside / outside the activity mask of `restore_real`):", "",
              "| recording | method | events out | kept | activity kept | background kept | ESR | consistency R^2 |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
    for rec, r in res["real"].items():
        for label, m in r["methods"].items():
            c = "-" if m["consistency_r2"] is None else f"{m['consistency_r2']:.3f}"
            lines.append(f"| {rec} | {label} | {m['events_out']:,} | {100 * m['kept_fraction']:.1f} % | "
                         f"{100 * m['activity']:.1f} % | {100 * m['background']:.1f} % | {m['esr']:.3f} | {c} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", nargs="*", default=DEFAULT_VARIANTS,
                    help="NAME=JSON: overrides of the scenes section for the training split")
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1])
    ap.add_argument("--task", default="restore_events", choices=["restore_events", "restore"],
                    help="events-only (default) or image-guided stage 1 (then give only recordings with frames)")
    ap.add_argument("--test", nargs="*", default=["study=data/pairs/test.h5"],
                    help="NAME=PATH of simulated test pairs (relative to the repository)")
    ap.add_argument("--recordings", nargs="*", default=list(RECORDINGS))
    ap.add_argument("--parallel", type=int, default=2, help="trainings at once (1 thread each)")
    ap.add_argument("--work", type=Path, default=None,
                    help="keep the simulated pairs and the networks here (default: a temporary folder); "
                         "a variant's pairs and a seed's model.pt already there are reused")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_training_scenes.json")
    ap.add_argument("--table-only", action="store_true", help="only rewrite OUT.md from OUT (.json)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from restore_train_range import rewrite_table
    if args.table_only:
        return rewrite_table(args.out, table)
    import torch
    from restore_learned_eval import eval_pairs
    from restore_train_range import train, write_results

    from rdnet.config import load_params

    torch.set_num_threads(1)
    params = load_params(ROOT / "params.yaml")
    iterations = int(params["train"]["iterations"])
    variants = {}
    for item in args.variants:
        name, spec = item.split("=", 1)
        variants[name] = json.loads(spec)
    tests = dict(t.split("=", 1) for t in args.test)
    res = {"test_pairs": tests, "seeds": args.seeds, "iterations": iterations, "task": args.task,
           "scenes": params["scenes"], "load_average_1min_before": os.getloadavg()[0],
           "variants": {n: {"scenes_overrides": v, "runs": {}} for n, v in variants.items()}, "real": {}}
    with tempfile.TemporaryDirectory() as tmp:
        root = args.work or Path(tmp)
        jobs = []
        for name, overrides in variants.items():
            work = root / name
            pairs = work / "pairs" / "train.h5"
            if not pairs.is_file():
                log.info("rendering and simulating the training split of %s (%s)", name, overrides)
                pairs = training_pairs(params, overrides, work)
            jobs += [(name, seed, pairs, work / f"seed{seed}") for seed in args.seeds]

        def run(job):
            ck = job[3] / "model.pt"
            if ck.is_file():
                log.info("reusing %s", ck)
                return ck, None
            return train(args.task, job[2], job[3], job[1], iterations)
        with ThreadPoolExecutor(max_workers=args.parallel) as pool:
            done = list(pool.map(run, jobs))
        ckpts = {}
        for (name, seed, _, _), (ck, wall) in zip(jobs, done):
            ckpts[f"{name}/{seed}"] = ck
            res["variants"][name]["runs"][str(seed)] = {"train_wall_s": wall, "test": {}}
        res["raw"] = {}
        for test, path in tests.items():
            scored = eval_pairs(ROOT / path, ckpts)
            res["raw"][test] = {m: scored["raw"][m] for m in METRICS}
            for key in ckpts:
                name, seed = key.split("/")
                run = res["variants"][name]["runs"][seed]
                run["test"][test] = {m: scored[key][m] for m in METRICS}
                run["threshold"], run["val_metrics"] = scored[key]["threshold"], scored[key]["val_metrics"]
        res["real"] = score_real_recordings(args.recordings, params, lambda rec: ckpts, Path(tmp))
    write_results(args.out, res, table)


if __name__ == "__main__":
    main()
