"""Where the independent circuit generator's pixels differ from rdnet's simulator under the same
declared config (issue 12, item 2: the part of the proof's held-out residual that is the pixel
model, about 0.05 of the circuit block's excess after the fit once the frames are the truth's
own; docs/calibration.md, "The proof with the truth's own frames").

It takes one of the proof's nulls (``--case``: ``null_declared_right``, 1 Hz shot noise and
300 us jitter declared right, the default; ``null_thresholds``, thresholds 1.3x;
``null_frame_rate_60``, 60 fps frames) on its scene, drawn as the ``calibration_proof`` stage draws it, run for
``--duration-scale`` x 1 s. It renders the events twice from the same 400 fps frames: with the
circuit generator (``rdnet.circuit``, the block ``circuit``) and with rdnet's simulator (the
block ``oversample4``), on the circuit null's texture, each with ``--seeds`` truth seeds. Per region of the scene (the
static rows and the moving ones, each in its dark left half and bright right half) it compares the event count, the
ON share, and the spread of the per-pixel counts over the region's pixels: quantiles of the
per-pixel count, and the standard deviation of log(n + 1) against its Poisson expectation.
rdnet against rdnet with another seed gives the seed-to-seed level.

Writes ``benchmarks/results/circuit_vs_rdnet_pixels[_<case>].{json,md}`` (no suffix for the default).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/circuit_vs_rdnet_pixels.py
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from latency_consistency_scan import md_table_lines  # noqa: E402

NULLS = ("null_declared_right", "null_thresholds", "null_frame_rate_60")
QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9, 0.99)


def streams(case_name: str, duration_scale: int, seed: int, truth_seeds: list[int]) -> tuple[dict, object]:
    from rdnet.calib.proof import TRUTH_PREROLL_US, TRUTH_WARMUP_US, block_draws, cases_for, make_recording
    from rdnet.calib.scene import SceneSpec
    from rdnet.sim.settings import SensorConfig
    todo = cases_for("both")
    out = {}
    spec0 = SceneSpec()
    spec = dataclasses.replace(spec0, duration_us=spec0.duration_us * duration_scale)
    # the circuit block's draws (as the stage takes them): its null's texture, for both generators
    tex = {c.name: d for c, d in block_draws(todo["circuit"], spec0, seed)}["circuit_" + case_name][0]
    for gen, block_cases, name, oversample in (("circuit", todo["circuit"], "circuit_" + case_name, 1),
                                               ("rdnet", todo["rdnet"], case_name, 4)):
        case = next(c for c in block_cases if c.name == name)
        spec = dataclasses.replace(spec, **dict(case.scene))
        for ts in truth_seeds:
            rec, _ = make_recording(case, spec, SensorConfig(), None, oversample, None, 4, TRUTH_WARMUP_US,
                                    TRUTH_PREROLL_US, draws=(tex, int(ts)))
            out[(gen, ts)] = rec.events
    return out, spec


def regions(spec) -> dict:
    H, W = spec.height, spec.width
    static = int(round(spec.static_fraction * H))
    m = {}
    rows = np.arange(H)[:, None]
    cols = np.arange(W)[None, :]
    m["static, dark half"] = (rows < static) & (cols < W // 2)
    m["static, bright half"] = (rows < static) & (cols >= W // 2)
    m["moving, dark half"] = (rows >= static) & (cols < W // 2)
    m["moving, bright half"] = (rows >= static) & (cols >= W // 2)
    return m


def describe(n: np.ndarray, on: np.ndarray, mask: np.ndarray, duration_s: float) -> dict:
    """The region ``mask`` of a stream's per-pixel counts ``n`` (ON events: ``on``)."""
    v = n[mask].astype(np.float64)
    lg = np.log1p(v)
    return {"events": int(v.sum()), "rate_hz_per_px": float(v.mean() / duration_s),
            "on_share": float(on[mask].sum() / max(v.sum(), 1)),
            "quantiles": np.quantile(v, QUANTILES).tolist(),
            "std_log": float(lg.std()), "fano": float(v.var() / max(v.mean(), 1e-9))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=NULLS, default=NULLS[0], help="the proof's null (both generators have it)")
    ap.add_argument("--duration-scale", type=int, default=4)
    ap.add_argument("--seed", type=int, default=2024, help="the stage's --seed (the scene's draws)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[10_000_001, 10_000_002], help="truth seeds")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args()
    evs, spec = streams(args.case, args.duration_scale, args.seed, args.seeds)
    dur = spec.duration_us * 1e-6
    counts = {k: (ev.count_per_pixel(), ev.count_per_pixel(1)) for k, ev in evs.items()}   # once per stream
    rows = []
    for reg, mask in regions(spec).items():
        for (gen, ts), (n, on) in counts.items():
            rows.append({"region": reg, "generator": gen, "truth_seed": ts, **describe(n, on, mask, dur)})
    out = {"case": args.case, "duration_s": dur, "seeds": args.seeds, "rows": rows}
    stem = "circuit_vs_rdnet_pixels" + ("" if args.case == NULLS[0] else "_" + args.case)
    (args.results / f"{stem}.json").write_text(json.dumps(out, indent=1) + "\n")
    md = ["# The circuit generator's pixels against rdnet's, same declared config and frames", "",
          f"`python benchmarks/circuit_vs_rdnet_pixels.py --case {args.case}` (case `{args.case}`, {dur:.0f} s of the proof's scene at 400 "
          f"fps, truth seeds {', '.join(map(str, args.seeds))}). Per region: events, rate per pixel, ON share, per-pixel "
          f"count quantiles ({', '.join(f'{q:g}' for q in QUANTILES)}), std of log(n + 1) and the Fano factor of the "
          "per-pixel counts over the region's pixels.", ""]
    md += md_table_lines(["region", "generator", "seed", "events", "Hz / px", "ON share", "count quantiles",
                          "std log(n+1)", "Fano"],
                         [[r["region"], r["generator"], str(r["truth_seed"]), f"{r['events']:,}", f"{r['rate_hz_per_px']:.2f}",
                           f"{r['on_share']:.3f}", " / ".join(f"{q:.0f}" for q in r["quantiles"]),
                           f"{r['std_log']:.3f}", f"{r['fano']:.2f}"] for r in rows])
    (args.results / f"{stem}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
