"""How many generator runs the proof's count match takes (``rdnet.calib.proof.match_count``),
and how close it gets, on every concealed case of the three blocks of the
``calibration_proof`` stage (recordings made exactly as the stage makes them,
``benchmarks/calib_case_profile.case_recording``). The bisection it replaced took 14 runs
per circuit case and 18 per rdnet case (the uncompensated count, 12 or 16 halvings, the
final value), plus the base count's run in both.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/proof_count_match.py      # about 10 minutes

Writes ``benchmarks/results/proof_count_match.{json,md}``.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

from rdnet.calib import proof as P
from rdnet.config import load_params, section
from rdnet.sim.interpolate import InterpolateConfig

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from calib_case_profile import case_recording  # noqa: E402
from restore_train_range import write_results  # noqa: E402

log = logging.getLogger("proof_count_match")
BLOCKS = (("rdnet", "rdnet", 1), ("oversample4", "rdnet", 4), ("circuit", "circuit", 1))


def counted(fn):
    """``match_count`` that also records how many runs it made (the start included)."""
    runs = []

    def wrapper(count_at, start, *a, **k):
        n = [1]

        def counting(x):
            n[0] += 1
            return count_at(x)
        out = fn(counting, start, *a, **k)
        runs.append(n[0])
        return out
    return wrapper, runs


def markdown(res: dict) -> str:
    lines = ["Generator runs of the proof's count match per concealed case (the uncompensated run "
             "included; the base count's run not), and the matched count against the base count "
             "(`python benchmarks/proof_count_match.py`). The bisection before took 14 (circuit) or 18 runs.", "",
             "| block | cases | runs: min | median | max | mean | count error: max (%) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for b, rows in res["blocks"].items():
        r = np.array([x["runs"] for x in rows])
        e = max(abs(x["count"] / x["base_count"] - 1.0) for x in rows)
        lines.append(f"| {b} | {len(rows)} | {r.min()} | {np.median(r):g} | {r.max()} | {r.mean():.1f} | {100 * e:.3f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--seed", type=int, default=2024, help="the stage's --seed")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "proof_count_match.json")
    args = ap.parse_args()
    logging.getLogger("rdnet").setLevel(logging.ERROR)
    cfg = section(load_params(args.params), "calibrate")
    interp = InterpolateConfig(max_upsample=cfg.max_upsample)
    original = P.match_count
    res = {"benchmark": "proof_count_match", "tolerance": P.COUNT_MATCH_TOL, "blocks": {}}
    try:
        for block, generator, oversample in BLOCKS:
            rows = []
            for case in P.cases_for(generator)[generator]:
                if case.compensate is None:
                    continue
                P.match_count, runs = counted(original)
                t0 = time.perf_counter()
                _, _, truth = case_recording(case.name, generator, oversample, cfg, interp, args.seed)
                rows.append({"case": case.name, "runs": runs[0], "count": truth["count"],
                             "base_count": truth["base_count"], "seconds": time.perf_counter() - t0})
                log.info("%s %s: %d runs, count %d for %d", block, case.name, runs[0], truth["count"],
                         truth["base_count"])
            res["blocks"][block] = rows
    finally:
        P.match_count = original
    write_results(args.out, res, markdown)


if __name__ == "__main__":
    main()
