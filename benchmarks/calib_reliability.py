"""Reliability of the calibration's confidence over the proof's cases (issue 12, item 4:
effects named with confidence c should be right about c of the time).

Reads a proof results folder (default ``results/calibration/proof``, as written by the
``calibration_proof`` stage): every block with a ``proof.json`` (the folder itself: block
``rdnet``; each subfolder that has one, e.g. ``oversample4`` and ``circuit``) and each case's
``<block>/<case>/report.json``. Every candidate effect the calibration scored in a case
(every entry of ``report["effects"]``, named or not, with its ``confidence``) is one
prediction "this effect is missing"; it is right when the effect is the case's concealed
effect (``true_effect`` in proof.json), and never right in a null case (there the right
answer is to name nothing). Each case's truth changes no candidate effect other than its
concealed one (see :mod:`rdnet.calib.proof`), so this is the whole truth.

The table bins the confidences (``--bins`` equal-width bins over [0, 1], the last one
closed) and gives per bin the count, mean confidence and the fraction right; the expected
calibration error is ``ECE = sum_b n_b / N |mean confidence_b - fraction right_b|``; the
Brier score is the mean of ``(confidence - right)^2``. It is given over all blocks and per
block, for all candidates and for the named ones only. Candidates that were never
evaluated (evidence "not evaluated", confidence 0) are kept, as a confidence of 0
is what the report states for them; ``--evaluated-only`` drops them.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_reliability.py
    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_reliability.py --proof /tmp/proof --results /tmp/rel

The committed results were made from the full ``dvc repro calibration_proof`` run (95 cases) in
another worktree: ``--proof ../wt-proof/results/calibration/proof --label results/calibration/proof``.
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from rdnet.calib.report import write_json
from rdnet.errors import FormatError
from rdnet.eval.report import write_text_atomic

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("calib_reliability")


def candidate_rows(report: dict, true_effect: str | None, *, block: str = "", case: str = "") -> list[dict]:
    """One row per candidate effect of a case's ``report.json``: its confidence, whether it
    was named, and whether naming it would be right (it is the case's concealed effect;
    nothing is right in a null case, ``true_effect`` None)."""
    return [{"block": block, "case": case, "effect": e["name"], "confidence": float(e["confidence"]),
             "named": bool(e["missing"]), "right": true_effect is not None and e["name"] == true_effect,
             "evaluated": e.get("evidence") != "not evaluated"}
            for e in report["effects"]]


def reliability_table(confidence, right, n_bins: int = 5) -> dict:
    """Reliability of confidences against outcomes: ``n_bins`` equal-width bins over [0, 1]
    (bin b holds ``b/n <= c < (b+1)/n``, the last also c = 1), each with its count, mean
    confidence and fraction right (None when empty); the expected calibration error (ECE,
    count-weighted mean of |mean confidence - fraction right|) and the Brier score."""
    c = np.asarray(confidence, dtype=float)
    r = np.asarray(right, dtype=bool)
    if c.shape != r.shape or c.ndim != 1:
        raise ValueError("confidence and right must be 1-D and of equal length")
    if c.size and (not np.all(np.isfinite(c)) or c.min() < 0.0 or c.max() > 1.0):
        raise ValueError("confidences must lie in [0, 1]")
    idx = np.minimum((c * n_bins).astype(int), n_bins - 1)
    bins, ece = [], 0.0
    for b in range(n_bins):
        m = idx == b
        n = int(m.sum())
        mean_c = float(c[m].mean()) if n else None
        frac = float(r[m].mean()) if n else None
        if n:
            ece += n / c.size * abs(mean_c - frac)
        bins.append({"range": [b / n_bins, (b + 1) / n_bins], "count": n, "right": int(r[m].sum()),
                     "mean_confidence": mean_c, "fraction_right": frac})
    return {"count": int(c.size), "right": int(r.sum()), "bins": bins,
            "ece": float(ece) if c.size else None,
            "brier": float(np.mean((c - r) ** 2)) if c.size else None}


def proof_blocks(folder: Path) -> dict[str, Path]:
    """The blocks of a proof folder: ``rdnet`` (folder/proof.json) and every subfolder with a proof.json."""
    blocks = {}
    if (folder / "proof.json").is_file():
        blocks["rdnet"] = folder
    for sub in sorted(p for p in folder.iterdir() if p.is_dir()):
        if (sub / "proof.json").is_file():
            blocks[sub.name] = sub
    if not blocks:
        raise FormatError(folder, "proof.json", "no proof.json in the folder or its subfolders")
    return blocks


def load_rows(folder: Path) -> list[dict]:
    """Candidate rows of every case of every block of a proof folder."""
    rows = []
    for block, d in proof_blocks(folder).items():
        proof = json.loads((d / "proof.json").read_text())
        for case in proof["cases"]:
            rp = d / case["case"] / "report.json"
            if not rp.is_file():
                raise FormatError(rp, None, f"report of case {case['case']} (block {block}) is missing")
            rows += candidate_rows(json.loads(rp.read_text()), case["true_effect"], block=block, case=case["case"])
    return rows


def summarise(rows: list[dict], n_bins: int) -> dict:
    def table(sel):
        return reliability_table([r["confidence"] for r in sel], [r["right"] for r in sel], n_bins)
    named = [r for r in rows if r["named"]]
    cases = {(r["block"], r["case"]) for r in rows}
    concealed = {(r["block"], r["case"]) for r in rows if r["right"]}
    out = {"all_candidates": table(rows), "named_only": table(named),
           "cases": len(cases), "null_cases": len(cases - concealed),
           "named_wrong": [{k: r[k] for k in ("block", "case", "effect", "confidence")} for r in named if not r["right"]],
           "missed": [{k: r[k] for k in ("block", "case", "effect", "confidence")}
                      for r in rows if r["right"] and not r["named"]]}
    return out


def markdown(result: dict) -> str:
    def bins_table(t):
        lines = ["| confidence | candidates | right | mean confidence | fraction right |", "|---|---|---|---|---|"]
        for b in t["bins"]:
            lo, hi = b["range"]
            mc = "-" if b["mean_confidence"] is None else f"{b['mean_confidence']:.3f}"
            fr = "-" if b["fraction_right"] is None else f"{b['fraction_right']:.3f}"
            lines.append(f"| {lo:.1f}-{hi:.1f} | {b['count']} | {b['right']} | {mc} | {fr} |")
        ece = "-" if t["ece"] is None else f"{t['ece']:.3f}"
        brier = "-" if t["brier"] is None else f"{t['brier']:.3f}"
        lines += ["", f"{t['count']} predictions, {t['right']} right; ECE {ece}, Brier {brier}."]
        return lines

    o = result["overall"]
    lines = ["# Reliability of the calibration's confidence over the proof cases", "",
             f"Proof folder: `{result['proof']}`; blocks: "
             + ", ".join(f"{b} ({result['blocks'][b]['cases']} cases)" for b in result["blocks"]) + ". "
             "Each candidate effect of each case is a prediction 'this effect is missing' with its confidence; "
             "it is right when it is the case's concealed effect (never in a null case).", "",
             "## All candidates, all blocks", ""] + bins_table(o["all_candidates"])
    lines += ["", "## Named effects only, all blocks", ""] + bins_table(o["named_only"])
    lines += ["", "## Per block", "", "| block | cases | candidates | ECE | Brier | named | named right "
              "| concealed effects not named |", "|---|---|---|---|---|---|---|---|"]
    for b, s in result["blocks"].items():
        a, n = s["all_candidates"], s["named_only"]
        lines.append(f"| {b} | {s['cases']} | {a['count']} | {a['ece']:.3f} | {a['brier']:.3f} | {n['count']} | "
                     f"{n['right']} | {len(s['missed'])} |")
    if o["named_wrong"]:
        lines += ["", "Named wrongly: " + "; ".join(f"{r['block']}/{r['case']}: {r['effect']} ({r['confidence']:.3f})"
                                                    for r in o["named_wrong"]) + "."]
    if o["missed"]:
        lines += ["", "Concealed effect not named: " + "; ".join(
            f"{r['block']}/{r['case']}: {r['effect']} ({r['confidence']:.3g})" for r in o["missed"]) + "."]
    lines.append("")
    return "\n".join(lines)


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
    blocks = {b: summarise([r for r in rows if r["block"] == b], args.bins)
              for b in dict.fromkeys(r["block"] for r in rows)}
    pr = args.proof.resolve()
    proof = args.label or (str(pr.relative_to(ROOT)) if pr.is_relative_to(ROOT) else str(pr))
    result = {"proof": proof, "bins": args.bins, "evaluated_only": args.evaluated_only,
              "overall": summarise(rows, args.bins), "blocks": blocks, "rows": rows}
    write_json(args.results.with_suffix(".json"), result)
    write_text_atomic(args.results.with_suffix(".md"), markdown(result))
    o = result["overall"]["all_candidates"]
    log.info("%d predictions over %d cases: ECE %.3f, Brier %.3f", o["count"], result["overall"]["cases"],
             o["ece"], o["brier"])


if __name__ == "__main__":
    main()
