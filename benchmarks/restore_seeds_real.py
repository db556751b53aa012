"""Every training seed of the study's exported restorers on the real recordings (issue 11).

``restore_real`` scores seed 0 of each restorer (``models/restore_image``: image-guided, on
recordings with frames; ``models/restore_events``: events-only, on the others). A change to
the training data (here: the frame interpolation's warp, ``benchmarks/study_warp_compare.py``)
can look better or worse on one seed by chance, so this scores every seed of one or more
study runs the way ``restore_real`` does (:func:`rdnet.restore.real.score_recording`: events
kept, activity / background kept, ESR, consistency R^2 with frames, the share of output events
that are not recorded events, known hot pixels kept), with raw and BAF beside them. Each run is
a project checkout whose ``models/`` holds the trained restorers (``NAME=ROOT``; a run with
only the events-only restorers scores the recordings without frames only).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_seeds_real.py \\
        --runs bilinear=. bicubic_clamped=/tmp/wt_clamp --out benchmarks/results/restore_seeds_real
    # -> .json and .md (about 1 min per run and seed on 2 cores)
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from restore_training_scenes import RECORDINGS, score_real_recordings  # noqa: E402

log = logging.getLogger("restore_seeds_real")


def checkpoints(root: Path, seeds: list[int], has_frames: bool) -> dict[int, Path]:
    """seed -> model.pt of the restorer ``restore_real`` would use on such a recording."""
    task = "restore_image" if has_frames else "restore_events"
    out = {s: root / "models" / task / f"seed{s}" / "model.pt" for s in seeds}
    return {s: p for s, p in out.items() if p.is_file()}


def run(runs: dict[str, Path], seeds: list[int], names: list[str], work: Path) -> dict:
    """:func:`restore_training_scenes.score_real_recordings` with every run's seeds as learned
    restorers (``NAME/SEED``), plus each recording's ``has_frames``."""
    from rdnet.config import load_params
    from rdnet.events.io import open_events
    from rdnet.restore.real import recordings
    found = dict(recordings([ROOT / "data" / "real", ROOT.parent / "shared" / "real"]))

    def learned(rec: str) -> dict[str, Path]:
        with open_events(found[rec]) as src:
            fr = src.frames()
        frames[rec] = fr is not None and len(fr) > 0
        return {f"{name}/{s}": ck for name, root in runs.items()
                for s, ck in checkpoints(root, seeds, frames[rec]).items()}
    frames: dict[str, bool] = {}
    scored = score_real_recordings(names, load_params(ROOT / "params.yaml"), learned, work)
    return {"seeds": seeds, "runs": {k: str(v) for k, v in runs.items()},
            "recordings": {rec: {"has_frames": frames[rec], **r} for rec, r in scored.items()}}


def markdown(res: dict) -> str:
    lines = ["# The study's restorers, every seed, on the real recordings", "",
             "`benchmarks/restore_seeds_real.py`; scored as `restore_real` scores them (image-guided restorer "
             "where the recording has frames, events-only elsewhere). Runs: " +
             ", ".join(f"**{k}** (`{v}`)" for k, v in res["runs"].items()) + ".", "",
             "| recording | run | seed | events kept | activity kept | background kept | not in the recording "
             "| known hot pixels kept | ESR | consistency R^2 |", "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]

    def row(rec, run, seed, m):
        c, hot = m.get("consistency_r2"), m.get("hot_pixels")
        return (f"| {rec} | {run} | {seed} | {100 * m['kept_fraction']:.1f} % | {100 * m['activity']:.1f} % | "
                f"{100 * m['background']:.1f} % | {100 * m['not_recorded_fraction']:.1f} % | "
                f"{'-' if hot is None else f'{100 * hot:.1f} %'} | {m['esr']:.3f} | {'-' if c is None else f'{c:.3f}'} |")
    for rec, r in res["recordings"].items():
        ms = r["methods"]
        for key in ("raw", "baf"):
            if key in ms:
                lines.append(row(rec, key, "-", ms[key]))
        for name in res["runs"]:
            keys = [k for k in ms if k.startswith(f"{name}/")]
            for k in keys:
                lines.append(row(rec, name, k.split("/")[1], ms[k]))
            if len(keys) > 1:
                mean = {f: float(np.mean([ms[k][f] for k in keys])) for f in ("kept_fraction", "activity", "background",
                                                                           "not_recorded_fraction", "esr")}
                cs = [ms[k]["consistency_r2"] for k in keys if ms[k].get("consistency_r2") is not None]
                mean["consistency_r2"] = float(np.mean(cs)) if cs else None
                hots = [ms[k]["hot_pixels"] for k in keys if ms[k].get("hot_pixels") is not None]
                mean["hot_pixels"] = float(np.mean(hots)) if hots else None
                lines.append(row(rec, f"**{name}**", "mean", mean))
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", nargs="+", default=[f"study={ROOT}"], help="NAME=ROOT of each study checkout")
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--recordings", nargs="*", default=list(RECORDINGS))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_seeds_real")
    args = ap.parse_args(argv)
    runs = {}
    for r in args.runs:
        name, _, root = r.partition("=")
        runs[name] = Path(root).resolve()
    with tempfile.TemporaryDirectory() as tmp:
        res = run(runs, args.seeds, args.recordings, Path(tmp))
    from rdnet.calib.report import write_json
    from rdnet.eval.report import write_text_atomic
    write_json(args.out.with_suffix(".json"), res)
    write_text_atomic(args.out.with_suffix(".md"), markdown(res))
    print(markdown(res))


if __name__ == "__main__":
    main()
