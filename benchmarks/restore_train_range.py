"""Where the count restorer's test shortfall comes from: the training degradation range
(issue 11, goals "count ratio 0.85-1.15" and "all-voxel L1 at least 30 % below raw").

The study's test sequences draw every effect at 1.0-1.5x ``degrade`` (``randomize.test_scale``)
and its training sequences at 0.5-0.9x (``randomize.train_scale``): the test asks the restorer to
extrapolate to stronger degradations than it ever saw. This script retrains the same stage 1
(study ``model`` and ``train`` settings; seeds 0 and 1) on training sequences simulated from the same
scenes and interpolated frames with other training ranges, and scores each on the study's own
test pairs (``data/pairs/test.h5``, unchanged) with the metrics of
``benchmarks/restore_learned_eval.py``: event precision / recall / F1 matched per voxel and
polarity, count ratio, signed-voxel L1 over all voxels and over event voxels.

Variants (``--variants``, NAME=SCALE with SCALE as JSON: a ``train_scale``, or an object of
``randomize`` keys such as ``{"train_scale": [[0.5, 0.9], [1.6, 2.0]], "train_scale_keys":
{"cutoff_hz": [0.5, 0.9]}}``, whose ``degrade`` key, if any, overrides ``degrade`` keys for the
training split alone, ``{"degrade": {"leak_spread_decades": 1.0}}``): ``study`` ([0.5, 0.9]), ``bracket``
([[0.5, 0.9], [1.6, 2.0]]: disjoint from the test range but on both sides of it), ``wide``
([[0.25, 0.9], [1.6, 3.0]]) and ``in_range`` ([1.0, 1.5]: the test range itself, *not* disjoint,
a reference for what the network can do without extrapolating; not a protocol).
``--iterations-factor`` scales ``train.iterations`` (3 for a longer-training reference).
``--circuit`` also scores every network on the test sequences rendered by the independent
circuit generator (:func:`rdnet.study.independent.circuit_pairs`, one draw), so that a finding
on the test split does not rest on rdnet's simulator alone.
``--work DIR`` keeps each variant's training pairs and networks, the networks as
``DIR/<variant>/models/<restore_image|restore_events>/seed<k>/model.pt`` (the study's layout, so
that ``benchmarks/restore_seeds_real.py --runs NAME=DIR/<variant>`` scores them on the real
recordings), and reuses the pairs and networks already there, whatever they were made with
(use one DIR per ``--iterations-factor``; a reused network's row records ``train_wall_s`` null).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_train_range.py   # needs data/scenes, data/interp, data/pairs
        (dvc repro blur); writes benchmarks/results/restore_train_range.{json,md}
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_VARIANTS = ["study=[0.5, 0.9]", "bracket=[[0.5, 0.9], [1.6, 2.0]]", "wide=[[0.25, 0.9], [1.6, 3.0]]",
                    "in_range=[1.0, 1.5]"]
#: the study's model folder of each training task (dvc.yaml), which --work's layout follows
STUDY_DIR = {"restore": "restore_image", "restore_events": "restore_events"}
METRICS = ("precision", "recall", "f1", "count_ratio", "l1_all", "l1_events")
log = logging.getLogger("restore_train_range")


def simulate_train(params: dict, scale, work: Path) -> Path:
    """The training pairs of ``params`` with ``randomize.train_scale = scale`` (or, when
    ``scale`` is a dict, with those ``randomize`` keys: ``train_scale``, ``train_scale_keys``,
    and its ``degrade`` dict's keys in ``degrade``);
    only the training split is simulated; a test range is set aside when the training range
    overlaps the study's, which only the ``in_range`` reference variant does."""
    from rdnet.config import section
    from rdnet.errors import ConfigError
    from rdnet.sim.settings import scale_ranges
    from rdnet.study.data import make_pairs, simulate_sequences

    spec = dict(scale) if isinstance(scale, dict) else {"train_scale": scale}
    degrade = spec.pop("degrade", {})                # training-split degrade keys (the test pairs stay)
    rand = dict(params["randomize"], **spec)
    try:
        section({"randomize": rand}, "randomize")
    except ConfigError:                      # overlaps the test range: a reference run only
        hi = max(b for _, b in scale_ranges(rand["train_scale"]))
        rand["test_scale"] = [hi + 1.0, hi + 2.0]
    p = {**params, "randomize": rand, "degrade": {**params["degrade"], **degrade}}
    events, pairs = work / "events", work / "pairs"
    simulate_sequences(p, ROOT / "data" / "scenes", ROOT / "data" / "interp", events, splits=("train",))
    make_pairs(p, events, pairs, splits=("train",))
    return pairs / "train.h5"


def train(task: str, pairs: Path, out: Path, seed: int, iterations: int, overrides=(),
          timeout_s: float | None = None) -> tuple[Path, float]:
    """One training of ``task`` (study ``params.yaml``, one thread, no DVCLive) in a child
    process; ``overrides``: more ``--set`` values (``"train.clean_fraction=0.2"``; a later one
    wins). Returns the checkpoint and the wall time; ``subprocess.CalledProcessError`` when
    it fails, ``subprocess.TimeoutExpired`` after ``timeout_s``."""
    cmd = [sys.executable, "-m", "rdnet.train.run", "--task", task, "--train", str(pairs), "--out", str(out),
           "--no-progress", "--params", str(ROOT / "params.yaml"), "--set", f"train.seed={seed}",
           "--set", f"train.iterations={iterations}", "--set", "train.dvclive=false", "--set", "train.threads=1"]
    for o in overrides:
        cmd += ["--set", o]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    t = time.perf_counter()
    try:
        subprocess.run(cmd, check=True, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                       text=True, timeout=timeout_s)
    except subprocess.CalledProcessError as e:      # its error line, which the exception does not show
        log.error("training %s failed (%d): %s", out, e.returncode, (e.stderr or "").strip()[-2000:])
        raise
    return out / "model.pt", time.perf_counter() - t


def circuit_table(res: dict) -> str:
    """The runs scored on the circuit generator's rendering (``--circuit``), or nothing."""
    if "raw_circuit" not in res:
        return ""
    keys = ("f1", "count_ratio", "l1_all")
    lines = ["", "Scored on the same test sequences rendered by the independent circuit generator (one draw):", "",
             "| variant | task, seed | " + " | ".join(keys) + " |", "|---|---|" + "---:|" * len(keys),
             "| raw degraded events | - | " + " | ".join(f"{res['raw_circuit'][m]:.3f}" for m in keys) + " |"]
    for name, v in res["variants"].items():
        for run in v["runs"]:
            if "test_circuit" in run:
                lines.append(f"| {name} | {run['task']}, {run['seed']} | "
                             + " | ".join(f"{run['test_circuit'][m]:.3f}" for m in keys) + " |")
    return "\n".join(lines) + "\n"


def table(res: dict) -> str:
    lines = ["| variant | train_scale | task, seed | iterations | " + " | ".join(METRICS) + " |",
             "|---|---|---|---:|" + "---:|" * len(METRICS)]
    raw = res["raw"]
    lines.append("| raw degraded events | - | - | - | " + " | ".join(f"{raw[m]:.3f}" for m in METRICS) + " |")
    for name, v in res["variants"].items():
        for run in v["runs"]:
            lines.append(f"| {name} | {json.dumps(v['train_scale'])} | {run['task']}, {run['seed']} | {run['iterations']} | "
                         + " | ".join(f"{run['test'][m]:.3f}" for m in METRICS) + " |")
            for t, at in run.get("at_threshold", {}).items():
                lines.append(f"| {name}, occupancy threshold {t} (not fitted) | {json.dumps(v['train_scale'])} | "
                             f"{run['task']}, {run['seed']} | {run['iterations']} | " + " | ".join(f"{at[m]:.3f}" for m in METRICS) + " |")
    return "\n".join(lines) + "\n" + circuit_table(res)


def rewrite_table(out: Path, render) -> None:
    """Only the table: ``render`` of the results already in ``out`` (.json) to the .md beside it."""
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(out.with_suffix(".md"), render(json.loads(out.read_text())))


def write_results(out: Path, res: dict, render) -> None:
    """``res`` (with the load average after the run) to ``out`` (.json) and ``render(res)`` to
    the .md beside it, both written atomically; the table is logged too."""
    from rdnet.eval.report import write_text_atomic
    res["load_average_1min_after"] = os.getloadavg()[0]
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(res, indent=2) + "\n")
    write_text_atomic(out.with_suffix(".md"), render(res))
    log.info("\n%s", render(res))


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", nargs="*", default=DEFAULT_VARIANTS, help="NAME=SCALE (JSON)")
    ap.add_argument("--tasks", nargs="*", default=["restore_events"], help="restore_events and/or restore")
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1])
    ap.add_argument("--iterations-factor", type=float, default=1.0)
    ap.add_argument("--also-threshold", type=float, nargs="*", default=[0.5],
                    help="also score each network at these occupancy thresholds (0.5: the L1-optimal "
                         "median decision when the network is calibrated)")
    ap.add_argument("--parallel", type=int, default=2, help="trainings at once (1 thread each)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_train_range.json")
    ap.add_argument("--circuit", action="store_true",
                    help="also score every network on the test sequences rendered by the independent circuit "
                         "generator (one draw, as stage restoration_circuit)")
    ap.add_argument("--work", type=Path, default=None,
                    help="keep (and reuse) the variants' pairs and networks here (module docstring)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import torch
    from restore_learned_eval import eval_pairs

    from rdnet.config import load_params

    torch.set_num_threads(1)
    params = load_params(ROOT / "params.yaml")
    iterations = int(round(params["train"]["iterations"] * args.iterations_factor))
    test = ROOT / "data" / "pairs" / "test.h5"
    variants = {}
    for item in args.variants:
        name, spec = item.split("=", 1)
        variants[name] = json.loads(spec)
    res = {"test_pairs": str(test.relative_to(ROOT)), "test_scale": params["randomize"]["test_scale"],
           "seeds": args.seeds, "load_average_1min_before": os.getloadavg()[0], "variants": {}}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) if args.work is None else args.work
        jobs = []
        for name, scale in variants.items():
            work = root / name
            pairs = work / "pairs" / "train.h5"
            if not pairs.is_file():
                log.info("simulating the training split of %s (train_scale %s)", name, scale)
                pairs = simulate_train(params, scale, work)
            for task in args.tasks:
                for seed in args.seeds:
                    jobs.append((name, task, seed, pairs, work / "models" / STUDY_DIR[task] / f"seed{seed}"))

        def run(job):
            name, task, seed, pairs, out = job
            if (out / "model.pt").is_file():                      # kept by an earlier --work run
                log.info("reusing %s", out / "model.pt")
                return out / "model.pt", None
            return train(task, pairs, out, seed, iterations)

        with ThreadPoolExecutor(max_workers=args.parallel) as pool:
            done = list(pool.map(run, jobs))
        ckpts = {f"{name}/{task}/{seed}": ck for (name, task, seed, _, _), (ck, _) in zip(jobs, done)}
        scored = eval_pairs(test, ckpts, args.also_threshold)
        circuit = None
        if args.circuit:              # the same test sequences from the independent generator
            from rdnet.study.data import sequences
            from rdnet.study.independent import circuit_pairs
            pairs_c, _ = circuit_pairs(params, sequences(ROOT / "data" / "events", "test"), Path(tmp) / "circuit", 0)
            circuit = eval_pairs(pairs_c, ckpts)
            res["raw_circuit"] = {m: circuit["raw"][m] for m in METRICS}
    res["raw"] = scored["raw"]
    for (name, task, seed, _, _), (ck, wall) in zip(jobs, done):
        s = scored[f"{name}/{task}/{seed}"]
        v = res["variants"].setdefault(name, {"train_scale": variants[name], "runs": []})
        v["runs"].append({"task": task, "seed": seed, "iterations": iterations, "train_wall_s": wall,
                          "test": {m: s[m] for m in (*METRICS, "events")}, "threshold": s["threshold"],
                          "val_metrics": s["val_metrics"],
                          "at_threshold": {str(t): {m: scored[f"{name}/{task}/{seed}@{t}"][m] for m in METRICS}
                                           for t in args.also_threshold}})
        if circuit is not None:
            v["runs"][-1]["test_circuit"] = {m: circuit[f"{name}/{task}/{seed}"][m] for m in METRICS}
    write_results(args.out, res, table)


if __name__ == "__main__":
    main()
