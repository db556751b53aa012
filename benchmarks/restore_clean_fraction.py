"""Identity pairs in stage-1 training (``train.clean_fraction``): a restorer that leaves a clean
stream alone (issue 11, "no invented events").

``benchmarks/consistency_validity.py`` found that the study's learned restorers, handed a
simulated stream that needs no restoring (the undegraded events themselves), more than double
its events and halve its F1, while every filter leaves it nearly unchanged: every training
input had lost events (the degraded streams hold about 0.6 of the undegraded count at every
strength), so the network adds events to whatever it is given. ``train.clean_fraction`` makes
that share of the training samples identity pairs (input = target = the undegraded events).

This script retrains both stage-1 restorers (image-guided ``restore`` and ``restore_events``;
study ``model`` and ``train`` settings, 800 iterations, on ``data/pairs/train.h5``) at each
``--fractions`` value (the value of ``params.yaml`` is the study's own committed checkpoints,
``models/restore_*/seed<k>``, not retrained) and scores every variant on:

* the simulated test split, with the study's event metrics (``restore_learned_eval.eval_pairs``);
* ``consistency_validity`` recordings built from the test split (as ``rdnet restore`` runs on
  them): the degraded streams (``rdnet``), the undegraded ones as input (``clean input``) and
  one rendering by the independent circuit generator (``circuit``);
* the real recordings of ``data/real`` and ``../shared/real`` (:func:`rdnet.restore.real.score_recording`,
  as stage ``restore_real`` scores them: image-guided where the recording has frames,
  events-only elsewhere).

Writes ``benchmarks/results/restore_clean_fraction.{json,md}``. ``--key`` varies another
``train`` key the same way (``--values``; the same scores), e.g. the count head's loss::

    .venv/bin/python benchmarks/restore_clean_fraction.py [--fractions 0 0.2 0.4] [--seeds 0]
    .venv/bin/python benchmarks/restore_clean_fraction.py --key train.count_loss --values l1 poisson \
        --out benchmarks/results/restore_count_loss.json
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
log = logging.getLogger("restore_clean_fraction")
TASKS = {"image": "restore", "events": "restore_events"}
STUDY_MODELS = {"image": "restore_image", "events": "restore_events"}


def simulated_scores(params: dict, ckpts: dict[str, dict[str, Path]], srcs: list, tmp: Path) -> dict:
    """consistency_validity's groups for every variant (``ckpts``: variant -> kind -> checkpoint):
    each sequence's frames, raw and undegraded streams read and scored once, every variant's
    restorers run on it; then per variant the groups with its two restorers as ``rdnet-<kind>``."""
    from consistency_validity import score_sequence, summarize
    methods = {f"{v}/{kind}": ("rdnet", path) for v, kinds in ckpts.items() for kind, path in kinds.items()}
    per_seq = []
    for group, path in srcs:
        work = tmp / "work"
        work.mkdir(exist_ok=True)
        rows = score_sequence(path, params, 10, work, "events_ideal" if group == "clean input" else "events", methods)
        per_seq.append({"group": group, "sequence": path.name, "streams": rows})
    joint = summarize(per_seq)
    return {v: {g: {"sequences": s["sequences"],
                    "streams": {**{n: s["streams"][n] for n in ("raw", "undegraded")},
                                **{f"rdnet-{kind}": s["streams"][f"{v}/{kind}"] for kind in kinds}}}
                for g, s in joint.items()}
            for v, kinds in ckpts.items()}


def real_scores(params: dict, ckpts: dict[str, dict[str, Path]], tmp: Path) -> dict:
    """Every variant on every real recording (``restore_training_scenes.score_real``: one load
    and activity mask per recording), image-guided where the recording has frames."""
    from restore_training_scenes import score_real

    from rdnet.errors import FormatError
    from rdnet.events.io import format_of
    from rdnet.events.io.stream import open_events
    from rdnet.restore.real import read_facts, recordings
    facts = read_facts(ROOT / "stages" / "real_recordings.yaml")
    out = {v: {} for v in ckpts}
    for name, path in recordings([ROOT / "data" / "real", ROOT.parent / "shared" / "real"]):
        try:
            format_of(path)
            with open_events(path, sensor_size=facts.sensor_size.get(name)) as src:
                kind = "image" if src.has_frames else "events"
        except FormatError as e:
            log.warning("skipping %s: %s", path, e)
            continue
        scored = score_real(path, name, params, {v: ("rdnet", kinds[kind]) for v, kinds in ckpts.items()}, tmp)
        for v, r in scored["methods"].items():
            out[v][name] = {"restorer": kind, "kept": r["kept_fraction"], "consistency_r2": r["consistency_r2"],
                            "esr": r["esr"], "activity_kept": r["activity"], "background_kept": r["background"],
                            **({"hot_pixels_kept": r["hot_pixels"]} if "hot_pixels" in r else {})}
    return out


def _label(value) -> str:
    """A variant's value as the tables show it (numbers with ``:g``)."""
    return format(value, "g") if isinstance(value, (int, float)) else str(value)


def markdown(res: dict) -> str:
    key = res.get("key", "train.clean_fraction")
    name = key.split(".")[-1]
    what = "with identity pairs" if key == "train.clean_fraction" else "at each value"
    L = [f"Stage-1 restorers trained {what} (`{key}`; {res['command']}, "
         f"{res['seconds'] / 60:.0f} min, seed(s) {res['seeds']}). {_label(res.get('study_fraction', 0.0))} = the "
         "study's committed checkpoints when the script ran (`models/restore_*`), the others trained by it.", ""]
    L += ["**Simulated test split** (the study's event metrics; image-guided / events-only)", "",
          f"| {name} | seed | F1 | count ratio | all-voxel L1 | decision threshold |", "|---|---|---|---|---|---|"]
    raw = res["raw_test"]
    L.append(f"| raw | - | {raw['f1']:.3f} | {raw['count_ratio']:.2f} | {raw['l1_all']:.4f} | - |")
    for v in res["variants"]:
        t = v["test"]
        L.append(f"| {_label(v['fraction'])} | {v['seed']} | {t['image']['f1']:.3f} / {t['events']['f1']:.3f} | "
                 f"{t['image']['count_ratio']:.2f} / {t['events']['count_ratio']:.2f} | "
                 f"{t['image']['l1_all']:.4f} / {t['events']['l1_all']:.4f} | "
                 f"{t['image']['threshold']:.3f} / {t['events']['threshold']:.3f} |")
    L += ["", "**Recordings built from the test split** (`rdnet restore` on the degraded events, on the undegraded "
          "events as input, and on one circuit-generator rendering): consistency R^2 minus the raw stream's, count "
          "ratio against the undegraded events, F1 (image-guided / events-only)", "",
          f"| {name} | seed | rdnet: dR^2 | rdnet: count ratio | clean input: dR^2 | clean input: count ratio | "
          "clean input: F1 | circuit: dR^2 | circuit: count ratio |", "|---|---|---|---|---|---|---|---|---|"]
    for v in res["variants"]:
        s = v["simulated"]

        def pair(group, key, fmt):
            st = s[group]["streams"]
            return " / ".join(format(st[f"rdnet-{k}"][key], fmt) for k in ("image", "events"))
        L.append(f"| {_label(v['fraction'])} | {v['seed']} | {pair('rdnet', 'r2_minus_raw', '+.3f')} | "
                 f"{pair('rdnet', 'count_ratio', '.2f')} | {pair('clean input', 'r2_minus_raw', '+.3f')} | "
                 f"{pair('clean input', 'count_ratio', '.2f')} | {pair('clean input', 'f1', '.3f')} | "
                 f"{pair('circuit', 'r2_minus_raw', '+.3f')} | {pair('circuit', 'count_ratio', '.2f')} |")
    names = sorted({n for v in res["variants"] for n in v["real"]})
    L += ["", "**Real recordings** (as stage `restore_real` scores them; image-guided where the recording has "
          "frames): events kept, activity / background kept, consistency R^2 (raw DAVIS346: 0.348)", "",
          f"| {name} | seed | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]

    def cell(r):
        if r is None:
            return "-"
        c = f", R^2 {r['consistency_r2']:.3f}" if r.get("consistency_r2") is not None else ""
        hot = f", hot {100 * r['hot_pixels_kept']:.0f} %" if r.get("hot_pixels_kept") is not None else ""
        return (f"{100 * r['kept']:.1f} %: {100 * r['activity_kept']:.1f} / {100 * r['background_kept']:.1f} %"
                + hot + c)
    for v in res["variants"]:
        L.append(f"| {_label(v['fraction'])} | {v['seed']} | " + " | ".join(cell(v["real"].get(n)) for n in names) + " |")
    return "\n".join(L) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--key", default="train.clean_fraction", help="the train key to vary")
    ap.add_argument("--values", "--fractions", dest="values", nargs="*", default=["0", "0.2", "0.4"],
                    help="its values (YAML scalars); the value of params.yaml is the study's checkpoints")
    ap.add_argument("--seeds", type=int, nargs="*", default=[0])
    ap.add_argument("--parallel", type=int, default=2, help="trainings at once (1 thread each)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_clean_fraction.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("rdnet").setLevel(logging.WARNING)
    import torch
    from consistency_validity import sources
    from restore_learned_eval import eval_pairs
    from restore_train_range import train, write_results

    from rdnet.config import load_params
    torch.set_num_threads(1)
    params = load_params(ROOT / "params.yaml")
    import yaml
    section_name, key = args.key.split(".", 1)
    if section_name != "train" or key not in params["train"]:
        ap.error(f"--key {args.key}: not a key of params.yaml's train section")
    values = [yaml.safe_load(v) for v in args.values]
    study_value = params["train"][key]
    iterations = int(params["train"]["iterations"])
    start = time.perf_counter()
    command = "python benchmarks/restore_clean_fraction.py " + (
        f"--key {args.key} --values " if args.key != "train.clean_fraction" else "--fractions ")
    res = {"command": command + " ".join(map(_label, values)) + " --seeds " + " ".join(map(str, args.seeds)),
           "key": args.key, "seeds": args.seeds, "study_fraction": study_value, "variants": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        jobs, ckpts = [], {}
        for f in values:
            for seed in args.seeds:
                for kind, task in TASKS.items():
                    if f == study_value:
                        ckpts[(f, seed, kind)] = ROOT / "models" / STUDY_MODELS[kind] / f"seed{seed}" / "model.pt"
                    else:
                        jobs.append(((f, seed, kind), task, seed, tmp / f"v{_label(f)}_{task}_seed{seed}", f))
        pairs = ROOT / "data" / "pairs" / "train.h5"
        with ThreadPoolExecutor(max_workers=args.parallel) as pool:
            done = pool.map(lambda j: train(j[1], pairs, j[3], j[2], iterations, [f"{args.key}={j[4]}"]),
                            jobs)
            for key, (path, _) in zip([j[0] for j in jobs], done):
                ckpts[key] = path
        log.info("trained %d restorers in %.0f s", len(jobs), time.perf_counter() - start)
        scored = eval_pairs(ROOT / "data" / "pairs" / "test.h5",
                            {f"{_label(f)}/{s}/{k}": p for (f, s, k), p in ckpts.items()}, [])
        res["raw_test"] = {m: scored["raw"][m] for m in ("f1", "count_ratio", "l1_all")}
        variants = {f"{_label(f)}/{seed}": (f, seed) for f in values for seed in args.seeds}
        by_variant = {v: {k: ckpts[(f, seed, k)] for k in TASKS} for v, (f, seed) in variants.items()}
        srcs = sources("rdnet", params, tmp, 0, ()) + sources("clean", params, tmp, 0, ()) + \
            sources("circuit", params, tmp, 1, ())                  # the circuit draw rendered once
        simulated = simulated_scores(params, by_variant, srcs, tmp)
        real = real_scores(params, by_variant, tmp)
        for v, (f, seed) in variants.items():
            test = {k: {m: scored[f"{v}/{k}"][m] for m in ("f1", "count_ratio", "l1_all", "threshold")} for k in TASKS}
            res["variants"].append({"fraction": f, "seed": seed, "test": test, "simulated": simulated[v],
                                    "real": real[v]})
    res["seconds"] = time.perf_counter() - start
    write_results(args.out, res, markdown)
    print(markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
