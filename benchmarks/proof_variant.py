"""The calibration proof, or a subset of its cases, under changed ``calibrate`` settings,
against the committed proof (issue 12: does a setting name more concealed effects, or
anything in a null?).

Runs the ``calibration_proof`` stage script (``stages/calibration_proof.py``: every block,
the independent circuit generator and the 4x-denser truth included, each case with the
draws it gets in the whole proof) with params.yaml's settings changed by ``--set`` (keys of
the ``calibrate`` section) on the cases of ``--cases`` (default: every case), into a
temporary folder, and compares each case with ``metrics/calibration_proof.json``: what it
names, the true effect's rank, the held-out discrepancy after. Writes
``benchmarks/results/proof_variant_<tag>.json`` and ``.md``.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/proof_variant.py --tag seeds5 --set seeds=5 \\
        --cases latency_with_jitter_s2A circuit_latency_with_jitter_s2A ...

``--seed S`` runs the proof on other draws of its scenes and true events (the stage's
``--seed``; committed: 2024): how much its counts move from draw to draw
(``--tag draw<S>``; its per-case comparison is then with other draws of the same names).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from rdnet.calib.proof import generator_dir, metric_blocks
from rdnet.eval.report import write_text_atomic

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from latency_consistency_scan import md_table_lines  # noqa: E402


def _blocks(metrics: dict) -> dict:
    """{block: {case: entry}} of a proof metrics file (:func:`rdnet.calib.proof.metric_blocks`)."""
    return {k: v["cases"] for k, v in metric_blocks(metrics).items()}


def run_variant(overrides: dict, cases: list[str] | None, workers: int, seed: int | None = None) -> tuple[dict, float]:
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    unknown = set(overrides) - set(params["calibrate"])
    if unknown:
        raise SystemExit(f"--set: not keys of the calibrate section: {', '.join(sorted(unknown))}")
    params["calibrate"].update(overrides)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        cmd = [sys.executable, str(ROOT / "stages" / "calibration_proof.py"), "--params", str(tmp / "params.yaml"),
               "--out", str(tmp / "proof"), "--metrics", str(tmp / "metrics.json"), "--workers", str(workers)]
        if cases:
            cmd += ["--cases", *cases]
        if seed is not None:
            cmd += ["--seed", str(seed)]
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        metrics = json.loads((tmp / "metrics.json").read_text())
        for block, cases in _blocks(metrics).items():
            folder = generator_dir(tmp / "proof", block)
            for name, entry in cases.items():
                entry["candidates"] = _candidates(json.loads((folder / name / "report.json").read_text()))
        return metrics, wall


def _candidates(report: dict) -> dict:
    """Per fitted candidate of a case's report: confidence, held-out gain and its seed
    spread, and its own statistic's drop in seed spreads (signature z)."""
    return {e["name"]: {"confidence": e["confidence"], "heldout_gain": e["heldout_gain"], "seed_std": e["seed_std"],
                        "signature_z": (e.get("signature") or {}).get("z")}
            for e in report["effects"] if e.get("fitted")}


def compare(variant: dict, committed: dict) -> list[dict]:
    rows = []
    old = _blocks(committed)
    for block, cases in _blocks(variant).items():
        for name, v in cases.items():
            c = old.get(block, {}).get(name)
            rows.append({"block": block, "case": name, "named": v["named"], "named_right": v["named_right"],
                         "rank": v["rank"], "heldout_after": v["heldout_after"], "candidates": v["candidates"],
                         "committed": None if c is None else {k: c[k] for k in ("named", "named_right", "rank",
                                                                                  "heldout_after")}})
    return rows


def markdown(tag: str, overrides: dict, rows: list[dict], wall_s: float, seed: int | None = None) -> str:
    changed = [r for r in rows if r["committed"] is not None and
               (r["named"] != r["committed"]["named"] or r["rank"] != r["committed"]["rank"])]
    right = sum(r["named_right"] for r in rows)
    right0 = sum(bool(r["committed"] and r["committed"]["named_right"]) for r in rows)
    settings = ", ".join(f"{k}={v}" for k, v in overrides.items()) or (
        "as in params.yaml" + (" (a code variant)" if seed is None else ""))
    draw = "" if seed is None else (
        f", on the draw of scenes and true events of --seed {seed} (committed: 2024; the per-case columns compare "
        f"different draws of the same case names)")
    head = (f"# Proof variant `{tag}`: calibrate {settings}{draw}\n\n"
            f"{len(rows)} cases ({wall_s:.0f} s on this host); named right (or nothing in a null): {right} with the "
            f"variant, {right0} committed; {len(changed)} cases name or rank differently.\n\n")
    head_row = ["block", "case", "named", "rank", "held-out after", "committed: named", "rank", "held-out after"]
    table = "\n".join(md_table_lines(head_row,
                     [[r["block"], r["case"], ", ".join(r["named"]) or "none", str(r["rank"] or "-"), f"{r['heldout_after']:.3f}",
                       ", ".join(r["committed"]["named"]) or "none" if r["committed"] else "-",
                       str(r["committed"]["rank"] or "-") if r["committed"] else "-",
                       f"{r['committed']['heldout_after']:.3f}" if r["committed"] else "-"] for r in rows]))
    return head + table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tag", required=True, help="names the results files")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a key of params.yaml's calibrate section (repeatable)")
    ap.add_argument("--cases", nargs="+", default=None, help="case names as in the proof reports (default: all)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=None,
                    help="the stage's --seed (scenes and true events; default: the stage's, 2024, as committed); "
                         "with another seed the committed cases are other draws, so compare the counts")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args()
    overrides = {}
    for item in args.set:
        key, sep, val = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: expected KEY=VALUE")
        overrides[key.strip()] = yaml.safe_load(val)
    variant, wall = run_variant(overrides, args.cases, args.workers, args.seed)
    committed = json.loads((ROOT / "metrics" / "calibration_proof.json").read_text())
    rows = compare(variant, committed)
    out = {"tag": args.tag, "calibrate": overrides, "cases": args.cases, "seed": args.seed, "wall_s": round(wall, 1),
           "rows": rows,
           "summary": {k: v["summary"] for k, v in metric_blocks(variant).items()}}
    write_text_atomic(args.results / f"proof_variant_{args.tag}.json", json.dumps(out, indent=1) + "\n")
    write_text_atomic(args.results / f"proof_variant_{args.tag}.md", markdown(args.tag, overrides, rows, wall, args.seed) + "\n")
    print(markdown(args.tag, overrides, rows, wall, args.seed))


if __name__ == "__main__":
    main()
