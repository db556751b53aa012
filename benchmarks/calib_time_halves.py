"""``rdnet calibrate`` on each half of the real DAVIS346 recording (issue 12: is what it names on
the whole recording found again on independent data from the same camera, and how much
recording does that take?).

The calibration proof names every concealed effect when its scenes run 4 s but misses some at
1 s (``benchmarks/proof_more_data.py``). DAVIS346's recording is 2.36 s long, with 78,830
events, and the calibration names a latency of about 8 ms on it in 9 of 10 seeds
(``calib_stability.py``). This script cuts the recording at the frame nearest its middle. Each
half keeps its own frames and the events between its first and last frame. It calibrates each
half in process as ``calibrate_real`` calibrates the whole: params.yaml, the stage's ``--set``
list read from dvc.yaml (the ideal base), and seeds 0..N-1. Per half and seed it records what
is named, the latency's size, and the held-out discrepancy before and after.

Writes ``benchmarks/results/calib_time_halves.{json,md}``.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_time_halves.py [--seeds 0 1 2 3 4]
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from calib_stability import REAL, stage_sets  # noqa: E402
from latency_consistency_scan import md_table_lines, scan  # noqa: E402

log = logging.getLogger("calib_time_halves")


def halves(rec):
    """The recording cut at the frame nearest its middle: two recordings, each with its frames
    and the events from its first frame's time to its last one's."""
    from rdnet.events.recording import Frames, Recording
    fr = rec.frames
    mid = int(np.argmin(np.abs(fr.t_us - (fr.t_us[0] + fr.t_us[-1]) / 2)))
    out = []
    for lo, hi in ((0, mid + 1), (mid, len(fr))):
        f = Frames(fr.images[lo:hi], fr.t_us[lo:hi], fr.exposure_us[lo:hi])
        ev = rec.events.slice_time(int(f.t_us[0]), int(f.t_us[-1]) + 1)
        out.append(Recording(rec.width, rec.height, events=ev, frames=f, sensor=rec.sensor))
    return out


#: pixel-intervals the frames-only latency scan scores (``latency_consistency_scan.py``'s default)
SCAN_MIN_CHANGE = 0.2


def cross_half_consistency(parts, rows: list[dict], sensor) -> list[dict]:
    """Per half, two checks without the simulator. The event-frame consistency R^2
    (``rdnet.deblur.consistency``, the sensor's thresholds) of its events as recorded and
    shifted earlier (``rdnet.restore.run.shifted``) by the median latency the *other* half's
    calibrations fitted over their seeds. And the frames-only latency scan of its events
    (:func:`rdnet.calib.consistency.latency_scan`, as ``latency_consistency_scan.py`` runs it
    on the whole recording): the shift its frames prefer, with a bootstrap interval."""
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    from rdnet.restore.run import shifted
    out = []
    for h, part in enumerate(parts):
        other = [r["latency_fitted_us"] for r in rows if r["half"] != h + 1 and r["latency_fitted_us"] is not None]
        lat = float(np.median(other)) if other else None
        streams = {"recorded": part.events}
        if lat is not None:
            streams["shifted"] = next(shifted([part.events], lat))
        r2 = compare_consistency(LogFrames.of(part.frames, part.events, sensor.log_eps), streams,
                                 sensor.threshold_on, sensor.threshold_off)
        sc = scan(part, sensor.log_eps, SCAN_MIN_CHANGE)
        out.append({"half": h + 1, "other_half_latency_us": lat, "r2_recorded": float(r2["recorded"]["r2_fitted"]),
                    "r2_other_half_latency": float(r2["shifted"]["r2_fitted"]) if lat is not None else None,
                    "scan_latency_us": float(sc["latency_us"]), "scan_ci95_us": [float(v) for v in sc["ci95_us"]],
                    "scan_at_edge": bool(sc["at_edge"])})
    return out


def main() -> None:
    from rdnet.cli.calibrate import base_degrade
    from rdnet.config import load_params, section
    from rdnet.eval.report import write_text_atomic
    from rdnet.events.io import load

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(5)))
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--reuse", action="store_true",
                    help="take the calibrations from the results JSON already there; redo the cross-half consistency")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    sets = stage_sets(ROOT / "dvc.yaml")
    params = load_params(ROOT / "params.yaml", sets)
    sensor, cfg, interp = section(params, "sensor"), section(params, "calibrate"), section(params, "interpolate")
    degrade = base_degrade(section(params, "degrade"), "ideal", sets)
    rec = load(REAL)
    parts = halves(rec)
    t_all = time.perf_counter()
    if args.reuse:
        prev = json.loads((args.results / "calib_time_halves.json").read_text())
        rows, args.seeds, wall = prev["rows"], prev["seeds"], prev["wall_s"]
    else:
        rows = calibrate_halves(parts, args.seeds, sensor, degrade, cfg, interp)
        wall = round(time.perf_counter() - t_all, 1)
    out = {"recording": str(REAL.relative_to(ROOT)), "sets": sets, "seeds": args.seeds, "rows": rows,
           "wall_s": wall, "cross_half_consistency": cross_half_consistency(parts, rows, sensor)}
    write_text_atomic(args.results / "calib_time_halves.json", json.dumps(out, indent=1) + "\n")
    write_text_atomic(args.results / "calib_time_halves.md", markdown(out))
    print(markdown(out))


def calibrate_halves(parts, seeds, sensor, degrade, cfg, interp) -> list[dict]:
    from rdnet.calib.calibrate import calibrate
    rows = []
    for h, part in enumerate(parts):
        for seed in seeds:
            t0 = time.perf_counter()
            cal = calibrate(part, sensor, degrade, cfg, seed=seed, interpolate=interp,
                            source=f"{REAL.name} half {h + 1}")
            rep = cal.report
            named = [e for e in rep["effects"] if e["missing"]]
            lat = next((e["parameters"].get("latency_us") for e in named if e["name"] == "latency"), None)
            fitted_lat = next((e for e in rep["effects"] if e["name"] == "latency" and e.get("fitted")), None)
            row = {"half": h + 1, "seed": seed, "events": len(part.events), "frames": len(part.frames),
                   "t_us": [int(part.frames.t_us[0]), int(part.frames.t_us[-1])],
                   "named": [e["name"] for e in named], "latency_us": lat,
                   "latency_gain_z": None if fitted_lat is None or not fitted_lat["seed_std"] else
                   fitted_lat["heldout_gain"] / fitted_lat["seed_std"],
                   "latency_fitted_us": None if fitted_lat is None else fitted_lat["parameters"].get("latency_us"),
                   "heldout_before": rep["discrepancy"]["heldout_before"],
                   "heldout_after": rep["discrepancy"]["heldout_after"],
                   "interpolation": rep["frame_interpolation"]["chosen"],
                   "runtime_s": round(time.perf_counter() - t0, 1)}
            rows.append(row)
            print(f"half {h + 1} seed {seed}: named {row['named']} latency {lat} "
                  f"({row['runtime_s']} s)", flush=True)
    return rows


def markdown(out: dict) -> str:
    rows = out["rows"]
    lines = ["# `rdnet calibrate` on each half of the DAVIS346 recording", "",
             f"`python benchmarks/calib_time_halves.py --seeds {' '.join(map(str, out['seeds']))}` "
             f"({out['wall_s'] / 60:.1f} min). The recording is cut at the frame nearest its middle. Each half is "
             "calibrated in process as `calibrate_real` calibrates the whole (the ideal base, params.yaml).", ""]
    for h in (1, 2):
        sel = [r for r in rows if r["half"] == h]
        if not sel:
            continue
        sets = Counter(", ".join(r["named"]) or "nothing" for r in sel)
        lat = [r["latency_us"] / 1000 for r in sel if r["latency_us"] is not None]
        lines.append(f"- half {h}: {sel[0]['events']:,} events, {sel[0]['frames']} frames; named: "
                     + "; ".join(f"{k} in {v} of {len(sel)} seeds" for k, v in sets.most_common())
                     + (f"; latency {min(lat):.1f}-{max(lat):.1f} ms where named" if lat else ""))
    lines.append("")
    cross = out.get("cross_half_consistency") or []
    if cross:
        lines += ["Checks without the simulator, per half: the event-frame consistency R^2 of its events "
                  "(`rdnet.deblur.consistency`) as recorded and shifted earlier by the median latency the *other* "
                  "half's calibrations fitted (10 seeds); and the frames-only latency scan of its events "
                  f"(`rdnet.calib.consistency.latency_scan`, pixel-intervals with |d log I| >= {SCAN_MIN_CHANGE:g}, "
                  "as `latency_consistency_scan.py` scans the whole recording: 6.5 ms there), with its bootstrap "
                  "95 % interval:", ""]
        lines += md_table_lines(["half", "R^2 as recorded", "other half's latency", "R^2 shifted by it",
                                 "frames-only scan", "95 % interval"],
                                [[str(c["half"]), f"{c['r2_recorded']:.4f}",
                                  "-" if c["other_half_latency_us"] is None else f"{c['other_half_latency_us'] / 1000:.1f} ms",
                                  "-" if c["r2_other_half_latency"] is None else f"{c['r2_other_half_latency']:.4f}",
                                  f"{c['scan_latency_us'] / 1000:.2f} ms" + (" (at the grid's edge)" if c["scan_at_edge"] else ""),
                                  f"{c['scan_ci95_us'][0] / 1000:.2f}-{c['scan_ci95_us'][1] / 1000:.2f} ms"] for c in cross])
        lines.append("")
    lines += md_table_lines(["half", "seed", "named", "latency (ms)", "latency's gain z (fitted)", "held-out before -> after",
                             "interpolation", "s"],
                            [[str(r["half"]), str(r["seed"]), ", ".join(r["named"]) or "nothing",
                              "-" if r["latency_us"] is None else f"{r['latency_us'] / 1000:.1f}",
                              "-" if r["latency_gain_z"] is None else
                              f"{r['latency_gain_z']:.1f} ({r['latency_fitted_us'] / 1000:.1f} ms)",
                              f"{r['heldout_before']:.3f} -> {r['heldout_after']:.3f}", r["interpolation"],
                              f"{r['runtime_s']:.1f}"] for r in rows])
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
