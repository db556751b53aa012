"""Round 1 of ``rdnet calibrate``'s forward selection on DAVIS346, seed by seed (issue 12,
item 5: which candidates compete for the first effect, and how close they are).

For each ``--seed`` (as ``benchmarks/calib_stability.py``: the ``calibrate_real`` stage's
``--set`` list, ``--params params.yaml``), in process: every fitted round-1 candidate's
held-out gain, its seed spread, ``z`` = gain / spread, whether it is significant, the drop
of its own statistic in seed spreads, and the significant look-alikes of the largest-gain
candidate (:func:`rdnet.calib.fit.look_alikes`); which effect has the largest gain and
which the selection named (:func:`rdnet.calib.fit.surest`: of the two, the larger
``gain - spread``). Writes ``benchmarks/results/calib_round1.{json,md}``.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_round1.py        # seeds 0..9, about 1.5 min
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from calib_stability import REAL, stage_sets  # noqa: E402


def round1(seed: int, rec, sensor, degrade, cfg, interp) -> dict:
    from rdnet.calib.calibrate import calibrate
    from rdnet.calib.fit import look_alikes
    cal = calibrate(rec, sensor, degrade, cfg, seed=seed, interpolate=interp, source=str(REAL))
    fitted = [c for c in cal.fit.rounds[0] if c.fitted]
    largest = max((c for c in fitted if not c.vetoed), key=lambda c: c.gain, default=None)
    alike = [o.effect.name for o, _, _ in look_alikes(largest, cal.fit.rounds[0], cfg) if o.significant] \
        if largest is not None and largest.significant else []
    return {"seed": seed, "named": [c.effect.name for c in cal.fit.selected],
            "interpolation": cal.report["frame_interpolation"]["chosen"],
            "largest_gain": None if largest is None else largest.effect.name,
            "significant_look_alikes_of_largest": alike,
            "candidates": [{"name": c.effect.name, "gain": c.gain, "spread": c.spread, "z": c.z,
                            "significant": c.significant, "vetoed": c.vetoed, "signature_z": c.signature_z}
                           for c in fitted]}


def markdown(rows: list[dict]) -> str:
    n_alike = sum(bool(r["significant_look_alikes_of_largest"]) for r in rows)
    n_changed = sum(bool(r["named"]) and r["named"][0] != r["largest_gain"] for r in rows)
    lines = ["# Round 1 of `rdnet calibrate` on DAVIS346, seed by seed", "",
             "`benchmarks/calib_round1.py`: every fitted round-1 candidate as gain +- seed spread (z; * = "
             "significant), the significant look-alikes of the largest gain, and what the selection named "
             "first (`surest`: the larger gain - spread among them).", "",
             f"The largest gain has a significant look-alike in {n_alike} of {len(rows)} seeds; the named "
             f"effect is not the largest gain in {n_changed}.", "",
             "| seed | interpolation | fitted candidates | largest gain | its significant look-alikes | named |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        cands = "; ".join(f"{c['name']} {c['gain']:.2f} +- {c['spread']:.2f} (z {c['z']:.1f}"
                          f"{'*' if c['significant'] else ''})" for c in r["candidates"])
        lines.append(f"| {r['seed']} | {r['interpolation']} | {cands} | {r['largest_gain']} | "
                     f"{', '.join(r['significant_look_alikes_of_largest']) or '-'} | {', '.join(r['named']) or '-'} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "calib_round1")
    args = ap.parse_args()
    from rdnet.config import load_params, section
    from rdnet.eval.report import write_text_atomic
    from rdnet.events.io import load
    params = load_params(args.params, stage_sets(ROOT / "dvc.yaml"))
    sensor, degrade = section(params, "sensor"), section(params, "degrade")
    cfg, interp = section(params, "calibrate"), section(params, "interpolate")
    rec = load(REAL)
    rows = []
    for seed in args.seeds:
        rows.append(round1(seed, rec, sensor, degrade, cfg, interp))
        print(json.dumps({k: rows[-1][k] for k in ("seed", "named", "largest_gain", "significant_look_alikes_of_largest")}),
              flush=True)
    args.results.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.results.with_suffix(".json"), json.dumps({"recording": str(REAL), "rows": rows}, indent=1) + "\n")
    write_text_atomic(args.results.with_suffix(".md"), markdown(rows))


if __name__ == "__main__":
    main()
