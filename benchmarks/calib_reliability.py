"""Reliability of the calibration's confidence over the proof's cases (issue 12, item 4:
effects named with confidence c should be right about c of the time).

Reads a proof results folder (default ``results/calibration/proof``, as written by the
``calibration_proof`` stage): every block with a ``proof.json`` (the folder itself: block
``rdnet``; each subfolder that has one, e.g. ``oversample4`` and ``circuit``) and each case's
``<block>/<case>/report.json``, and writes the tables of :mod:`rdnet.calib.reliability`
(the one implementation; the stage writes the same into its metrics and
``results/calibration/proof/reliability.md``) over all blocks and per block, for all
candidates and for the named ones only. ``--evaluated-only`` drops the candidates that
were never evaluated.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_reliability.py
    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_reliability.py --proof /tmp/proof --results /tmp/rel

The committed results were made from the full ``dvc repro calibration_proof`` run (95 cases) in
another worktree: ``--proof ../wt-proof/results/calibration/proof --label results/calibration/proof``.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from rdnet.calib.reliability import load_rows, markdown, reliability
from rdnet.calib.report import write_json
from rdnet.eval.report import write_text_atomic

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("calib_reliability")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--proof", type=Path, default=ROOT / "results" / "calibration" / "proof")
    ap.add_argument("--label", default=None,
                    help="how the proof folder is named in the results (default: its path, relative to the repo)")
    ap.add_argument("--bins", type=int, default=5)
    ap.add_argument("--evaluated-only", action="store_true", help="drop the candidates never evaluated")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "calib_reliability",
                    help="output stem (.json and .md are added)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    rows = load_rows(args.proof)
    if args.evaluated_only:
        rows = [r for r in rows if r["evaluated"]]
    rel = reliability(rows, args.bins)
    pr = args.proof.resolve()
    proof = args.label or (str(pr.relative_to(ROOT)) if pr.is_relative_to(ROOT) else str(pr))
    result = {"proof": proof, "bins": args.bins, "evaluated_only": args.evaluated_only,
              "overall": rel["overall"], "blocks": rel["blocks"], "rows": rows}
    write_json(args.results.with_suffix(".json"), result)
    write_text_atomic(args.results.with_suffix(".md"), markdown(result, proof))
    o = result["overall"]["all_candidates"]
    log.info("%d predictions over %d cases: ECE %.3f, Brier %.3f", o["count"], result["overall"]["cases"],
             o["ece"], o["brier"])


if __name__ == "__main__":
    main()
