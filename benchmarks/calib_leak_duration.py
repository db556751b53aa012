"""Does a longer recording let the calibration name a weak leak on a running sensor? (issue 12)

The proof's leak cases at strength ``s1`` (0.6 Hz under about 1 Hz of shot-noise resets)
with the "real" sensor started as a running one (5 s on the first frame held still, then
0.5 s of the scene moving before the recording: ``truth_warmup_us`` / ``truth_preroll_us``
of :func:`rdnet.calib.proof.make_recording`) and the calibration's warm-up on
(``calibrate.warmup_us`` 3 s), at each recording length. Each length runs the same cases
from the same seed, so only the length differs. Writes
``benchmarks/results/calib_leak_duration.{json,md}`` (docs/calibration.md "Stationary truths").

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_leak_duration.py --workers 2
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = {"rdnet": ("leak_under_shot_noise", "leak_under_shot_noise_s1B"),
         "circuit": ("circuit_leak_under_shot_noise_s1A", "circuit_leak_under_shot_noise_s1B")}


def blocks(durations_us, warmup_us: int) -> list:
    """One proof block per generator and length (each from the same seed in
    :func:`rdnet.calib.proof.run_blocks`, so only the length differs)."""
    from rdnet.calib.proof import Block, cases_for
    from rdnet.calib.scene import SceneSpec
    from rdnet.calib.settings import CalibrateConfig
    from rdnet.sim.interpolate import InterpolateConfig
    out = []
    for gen, names in CASES.items():
        cases = tuple(c for c in cases_for(gen)[gen] if c.name in names)
        for d in durations_us:
            out.append(Block(f"{gen}@{d}", cases, None, dict(
                spec=SceneSpec(duration_us=d), cfg=CalibrateConfig(warmup_us=warmup_us),
                interpolate=InterpolateConfig(max_upsample=16), truth_warmup_us=5_000_000, truth_preroll_us=500_000)))
    return out


def rows_of(key: str, metrics: dict) -> list[dict]:
    gen, d = key.split("@")
    return [{"generator": gen, "duration_us": int(d), "case": r["case"], "named": r["named"],
             "rank": r["rank"], "leak_rel_error": r.get("param_max_rel_error"),
             "heldout_before": r["heldout_before"], "heldout_after": r["heldout_after"],
             "noise_floor": r["heldout_noise_floor"]} for r in metrics["cases"]]


def markdown(rows: list[dict]) -> str:
    out = ["| generator | length | case | named | rank of leak | leak error | held-out before -> after | noise floor |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        e = "-" if r["leak_rel_error"] is None else f"{100 * r['leak_rel_error']:.0f} %"
        out.append(f"| {r['generator']} | {r['duration_us'] / 1e6:g} s | {r['case']} | {', '.join(r['named']) or 'none'} | "
                   f"{r['rank']} | {e} | {r['heldout_before']:.2f} -> {r['heldout_after']:.2f} | {r['noise_floor']:.2f} |")
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--durations-us", type=int, nargs="+", default=[1_000_000, 3_000_000])
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--warmup-us", type=int, default=3_000_000, help="calibrate.warmup_us of the calibration")
    ap.add_argument("--workers", type=int, default=1, help="cases run at once, one process each")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "calib_leak_duration.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    from rdnet.calib.proof import run_blocks
    runs = run_blocks(blocks(args.durations_us, args.warmup_us), args.seed, workers=args.workers)
    rows = [r for key, m in runs.items() for r in rows_of(key, m)]
    from rdnet.eval.report import write_text_atomic
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.out, json.dumps({"seed": args.seed, "warmup_us": args.warmup_us, "rows": rows}, indent=1) + "\n")
    write_text_atomic(args.out.with_suffix(".md"), markdown(rows))
    print(markdown(rows))


if __name__ == "__main__":
    main()
