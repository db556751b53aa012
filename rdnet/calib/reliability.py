"""Reliability of the calibration's confidence over the proof's cases (issue 12, item 4:
effects named with confidence c should be right about c of the time).

Every candidate effect the calibration scored in a proof case (every entry of the case's
``report["effects"]``, named or not, with its ``confidence``) is one prediction "this effect
is missing"; it is right when the effect is the case's concealed effect (``true_effect``),
and never right in a null case (there the right answer is to name nothing). Each proof
case's truth changes no candidate effect other than its concealed one
(:mod:`rdnet.calib.proof`), so this is the whole truth.

:func:`reliability_table` bins the confidences (equal-width bins over [0, 1], the last one
closed) and gives per bin the count, mean confidence and fraction right; the expected
calibration error is ``ECE = sum_b n_b / N |mean confidence_b - fraction right_b|``, the
Brier score the mean of ``(confidence - right)^2``. Candidates never evaluated (evidence
"not evaluated", confidence 0) are kept: a confidence of 0 is what the report states.

Used by the ``calibration_proof`` stage (metrics and ``reliability.md``) and by
``benchmarks/calib_reliability.py`` (any proof folder on disk).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rdnet.config import read_json
from rdnet.errors import FormatError, ValidationError


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
        raise ValidationError("confidence", "confidence and right must be 1-D and of equal length")
    if c.size and (not np.all(np.isfinite(c)) or c.min() < 0.0 or c.max() > 1.0):
        raise ValidationError("confidence", "confidences must lie in [0, 1]")
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


def block_rows(folder: str | Path, proof: dict, block: str) -> list[dict]:
    """Candidate rows of every case of one proof block: ``proof`` is its metrics (as
    :func:`rdnet.calib.proof.run_proof` returns them and writes to ``folder/proof.json``),
    each case's report is read from ``folder/<case>/report.json``."""
    rows = []
    cases = proof.get("cases") if isinstance(proof, dict) else None
    if not isinstance(cases, list) or not all(isinstance(c, dict) and "case" in c and "true_effect" in c
                                              for c in cases):
        raise FormatError(Path(folder) / "proof.json", "cases", "expected a list of {case, true_effect, ...}")
    for case in cases:
        rp = Path(folder) / case["case"] / "report.json"
        if not rp.is_file():
            raise FormatError(rp, None, f"report of case {case['case']} (block {block}) is missing")
        try:
            rows += candidate_rows(read_json(rp), case["true_effect"], block=block, case=case["case"])
        except (KeyError, TypeError, ValueError) as e:
            raise FormatError(rp, "effects", f"not a calibration report's effects list ({type(e).__name__}: {e})") from None
    return rows


def proof_blocks(folder: str | Path) -> dict[str, Path]:
    """The blocks of a proof folder: ``rdnet`` (folder/proof.json) and every subfolder with a proof.json."""
    folder = Path(folder)
    blocks = {}
    if (folder / "proof.json").is_file():
        blocks["rdnet"] = folder
    for sub in sorted(p for p in folder.iterdir() if p.is_dir()):
        if (sub / "proof.json").is_file():
            blocks[sub.name] = sub
    if not blocks:
        raise FormatError(folder, "proof.json", "no proof.json in the folder or its subfolders")
    return blocks


def load_rows(folder: str | Path) -> list[dict]:
    """Candidate rows of every case of every block of a proof folder on disk."""
    rows = []
    for block, d in proof_blocks(folder).items():
        rows += block_rows(d, read_json(d / "proof.json"), block)
    return rows


def summarise(rows: list[dict], n_bins: int = 5) -> dict:
    """The reliability tables of all candidates and of the named ones only, the number of
    cases and null cases, and the named-but-wrong and concealed-but-not-named candidates."""
    def table(sel):
        return reliability_table([r["confidence"] for r in sel], [r["right"] for r in sel], n_bins)
    named = [r for r in rows if r["named"]]
    cases = {(r["block"], r["case"]) for r in rows}
    concealed = {(r["block"], r["case"]) for r in rows if r["right"]}
    return {"all_candidates": table(rows), "named_only": table(named),
            "cases": len(cases), "null_cases": len(cases - concealed),
            "named_wrong": [{k: r[k] for k in ("block", "case", "effect", "confidence")}
                            for r in named if not r["right"]],
            "missed": [{k: r[k] for k in ("block", "case", "effect", "confidence")}
                       for r in rows if r["right"] and not r["named"]]}


def reliability(rows: list[dict], n_bins: int = 5) -> dict:
    """:func:`summarise` over all rows (``overall``) and per block (``blocks``, in order of first appearance)."""
    return {"bins": n_bins, "overall": summarise(rows, n_bins),
            "blocks": {b: summarise([r for r in rows if r["block"] == b], n_bins)
                       for b in dict.fromkeys(r["block"] for r in rows)}}


def compact(result: dict) -> dict:
    """The part of :func:`reliability` that goes into the proof metrics: the binned tables
    (all candidates, named only) and per block the cases, candidates, ECE and Brier score."""
    o = result["overall"]
    return {"bins": result["bins"], "all_candidates": o["all_candidates"], "named_only": o["named_only"],
            "named_wrong": len(o["named_wrong"]), "missed": len(o["missed"]),
            "blocks": {b: {"cases": s["cases"], "candidates": s["all_candidates"]["count"],
                           "ece": s["all_candidates"]["ece"], "brier": s["all_candidates"]["brier"]}
                       for b, s in result["blocks"].items()}}


def _f(v, fmt: str = ".3f") -> str:
    return "-" if v is None else format(v, fmt)


def bins_table(t: dict) -> list[str]:
    """Markdown lines of one :func:`reliability_table`."""
    lines = ["| confidence | candidates | right | mean confidence | fraction right |", "|---|---|---|---|---|"]
    for b in t["bins"]:
        lo, hi = b["range"]
        lines.append(f"| {lo:.1f}-{hi:.1f} | {b['count']} | {b['right']} | {_f(b['mean_confidence'])} | "
                     f"{_f(b['fraction_right'])} |")
    return lines + ["", f"{t['count']} predictions, {t['right']} right; ECE {_f(t['ece'])}, Brier {_f(t['brier'])}."]


def markdown(result: dict, proof: str) -> str:
    """Markdown of :func:`reliability` for the proof folder named ``proof``."""
    o = result["overall"]
    lines = ["# Reliability of the calibration's confidence over the proof cases", "",
             f"Proof folder: `{proof}`; blocks: "
             + ", ".join(f"{b} ({result['blocks'][b]['cases']} cases)" for b in result["blocks"]) + ". "
             "Each candidate effect of each case is a prediction 'this effect is missing' with its confidence; "
             "it is right when it is the case's concealed effect (never in a null case).", "",
             "## All candidates, all blocks", ""] + bins_table(o["all_candidates"])
    lines += ["", "## Named effects only, all blocks", ""] + bins_table(o["named_only"])
    lines += ["", "## Per block", "", "| block | cases | candidates | ECE | Brier | named | named right "
              "| concealed effects not named |", "|---|---|---|---|---|---|---|---|"]
    for b, s in result["blocks"].items():
        a, n = s["all_candidates"], s["named_only"]
        lines.append(f"| {b} | {s['cases']} | {a['count']} | {_f(a['ece'])} | {_f(a['brier'])} | {n['count']} | "
                     f"{n['right']} | {len(s['missed'])} |")
    if o["named_wrong"]:
        lines += ["", "Named wrongly: " + "; ".join(f"{r['block']}/{r['case']}: {r['effect']} ({r['confidence']:.3f})"
                                                    for r in o["named_wrong"]) + "."]
    if o["missed"]:
        lines += ["", "Concealed effect not named: " + "; ".join(
            f"{r['block']}/{r['case']}: {r['effect']} ({r['confidence']:.3g})" for r in o["missed"]) + "."]
    lines.append("")
    return "\n".join(lines)
