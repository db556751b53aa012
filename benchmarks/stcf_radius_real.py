"""STCF's operating curves on the real recordings at radii 1-3 (issue 11: DVXplorer background
kept <= 15 % with the person >= 75 %, better than BAF).

``restore_real`` and ``benchmarks/restore_operating_curves.py`` score STCF
(:func:`rdnet.baselines.stcf.stcf_mask`: keep an event when at least k of its neighbours within
``radius`` fired within ``tau_us`` before it) at the study's radius 1 only. This script sweeps
radius 1-3, tau 10 / 30 / 60 ms and every k, after the hot-pixel pass (the ``restore``
section's settings, as ``rdnet restore`` applies it before every method), and scores each point
with ``restore_real``'s measures: the share of the raw events kept inside the activity mask and
outside it (:func:`rdnet.eval.noref.activity_mask`, :func:`~rdnet.eval.noref.mask_fractions`),
and on recordings with frames the event-frame consistency R^2 (the ``sensor`` thresholds and
``log_eps`` of params.yaml). The filter runs on the whole stream at once, not through ``rdnet
restore``'s windows (STCF carries its timestamp map from window to window, so the two agree:
the study's point, radius 1, 10 ms, k 2, reproduces ``restore_real``'s STCF row on the
DVXplorer take and on DAVIS346). Recordings: those of ``data/real`` and ``../shared/real`` that
rdnet reads (``stages/real_recordings.yaml`` for their facts).

The settings were not chosen on any recording: the grid is the whole sweep, and the Markdown
lists, per recording, the points that meet the DVXplorer goal's corner on that recording.

Writes ``benchmarks/results/stcf_radius_real.{json,md}``.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/stcf_radius_real.py
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from real_filtering import real_recordings  # noqa: E402

RADII = (1, 2, 3)
TAUS_US = (10_000, 30_000, 60_000)


def main() -> None:
    from rdnet.baselines.stcf import stcf_mask

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "stcf_radius_real")
    args = ap.parse_args()
    results = {}
    for rec in real_recordings():
        raw, ev = rec.raw, rec.events
        raw_r2 = rec.consistency(raw) if rec.consistency else None
        points = []
        for r in RADII:
            for tau in TAUS_US:
                for k in range(1, (2 * r + 1) ** 2):
                    kept = ev.select(stcf_mask(ev, tau, k, r))
                    p = {"radius": r, "tau_ms": tau // 1000, "k": k, "kept": round(len(kept) / len(raw), 5),
                         **rec.shares(kept)}
                    if rec.consistency is not None:
                        p["consistency"] = round(rec.consistency(kept), 5)
                    points.append(p)
                    if p["activity"] < 0.05:
                        break
        results[rec.name] = {"events": len(raw), "raw_consistency": raw_r2, "points": points}
        print(rec.name, len(points), "points", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(results) + "\n")
    args.out.with_suffix(".md").write_text(markdown(results))


def markdown(results: dict) -> str:
    lines = ["STCF (`rdnet.baselines.stcf`) at radius 1-3, tau 10 / 30 / 60 ms and every k, after the "
             "hot-pixel pass, scored as `restore_real` scores (`python benchmarks/stcf_radius_real.py`). "
             "Per recording and setting of radius and tau: the k whose point keeps the least background "
             "while keeping at least 75 % of the activity (the DVXplorer goal's corner: background <= 15 %), "
             "and the point at the study's k = 2.", ""]
    for name, res in results.items():
        raw = res["raw_consistency"]
        lines += [f"**{name}** ({res['events']:,} events{'' if raw is None else f', raw consistency {raw:.3f}'})", "",
                  "| radius | tau (ms) | k = 2: activity / background kept" + (" / consistency" if raw is not None else "")
                  + " | lowest background with activity >= 75 %: k, activity / background"
                  + (" / consistency" if raw is not None else "") + " |", "|---|---|---|---|"]
        for r in RADII:
            for tau in TAUS_US:
                pts = [p for p in res["points"] if p["radius"] == r and p["tau_ms"] == tau // 1000]

                def fmt(p):
                    s = f"{100 * p['activity']:.1f} / {100 * p['background']:.1f} %"
                    return s + (f" / {p['consistency']:.3f}" if "consistency" in p else "")
                k2 = next((p for p in pts if p["k"] == 2), None)
                ok = [p for p in pts if p["activity"] >= 0.75]
                best = min(ok, key=lambda p: p["background"]) if ok else None
                lines.append(f"| {r} | {tau // 1000} | {fmt(k2) if k2 else '-'} | "
                             + (f"k = {best['k']}: {fmt(best)}" if best else "-") + " |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
