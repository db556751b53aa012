"""When, within each frame interval, do simulated events happen? (issue 12: the measurement
behind frame interpolation 'cubic' and its use in 'selected', rdnet.sim.interpolate.)

A DVS pixel whose log intensity turns must first undo its last step before it fires the other
way (hysteresis), so its next event comes late. Piecewise-linear interpolation between frames
(``linear``, and ``flow``'s blend of two warps) puts every turning point of every pixel at an
input frame, so simulated events pile up late in each frame interval; a real sensor's (and a
scene rendered at a high rate) are spread evenly. The phase of an event is its position in
its frame interval, (t - t_i) / (t_{i+1} - t_i); for each stream this reports the share of
events in each fifth of the interval and the mean phase (0.5 = even).

* DAVIS346 road (``data/real/davis346_road``, frames 40 ms apart): the recorded events against
  the ideal sensor at the thresholds the calibration fits to it (x2.3, seed 0) on the frames
  upsampled as ``rdnet calibrate`` does (``calibrate`` and ``interpolate`` sections of
  params.yaml, every 2nd pixel).
Methods 'flow' and 'selected' run with both ``interpolate.warp`` resamplings of their warped
frames (bilinear, the study's; bicubic, the calibration's since session 38).

* The calibration proof's scene (:mod:`rdnet.calib.scene`, 64 x 64, both motions, 100 fps):
  the ideal sensor on the scene rendered at 6400 fps (the reference) and on its 100 fps frames
  upsampled by each method.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/interpolation_phase.py
    # -> benchmarks/results/interpolation_phase.{json,md} (about 1 min)
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from calib_stability import stage_sets  # noqa: E402
from flow_edge_drag import ideal_events  # noqa: E402
REAL = ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4"
METHODS = ("flow", "linear", "cubic", "selected")
#: the methods that warp frames, each run with both ``interpolate.warp`` resamplings
WARPED = ("flow", "selected")
BINS = 5


def phases(t_us: np.ndarray, frame_t: np.ndarray) -> np.ndarray:
    """Each event's position in its frame interval, in [0, 1) (events outside the frames dropped)."""
    t = np.asarray(t_us, np.int64)
    i = np.searchsorted(frame_t, t, side="right") - 1
    ok = (i >= 0) & (i < len(frame_t) - 1)
    i, t = i[ok], t[ok]
    return (t - frame_t[i]) / (frame_t[i + 1] - frame_t[i])


def row(label: str, ph: np.ndarray) -> dict:
    h = np.histogram(ph, bins=BINS, range=(0.0, 1.0))[0]
    return {"stream": label, "events": int(ph.size), "share_per_fifth": (h / max(ph.size, 1)).round(4).tolist(),
            "mean_phase": float(ph.mean()) if ph.size else float("nan")}


def davis346() -> list[dict]:
    from rdnet.calib.calibrate import interpolation_configs
    from rdnet.calib.context import build_context
    from rdnet.calib.fit import Objective
    from rdnet.config import load_params, section
    from rdnet.events.io import load
    p = load_params(ROOT / "params.yaml", stage_sets(ROOT / "dvc.yaml"))     # as calibrate_real
    rec = load(REAL)
    cfg, sensor, degrade = section(p, "calibrate"), section(p, "sensor"), section(p, "degrade")
    ft = rec.frames.t_us.astype(np.int64)
    rows = [row("recorded", phases(rec.events.t, ft))]
    base = section(p, "interpolate")
    for m, warp in variants():
        icfg, = interpolation_configs(dataclasses.replace(cfg, interpolation=(m,), warp=warp or cfg.warp), base)
        ctx = build_context(rec, cfg, sensor.log_eps, interpolate=icfg, source=str(REAL))
        ev = Objective(ctx, sensor, degrade, [0]).simulate({"threshold_scale": 2.3}, 0)
        rows.append(row(f"simulated, {label(m, warp)}", phases(ev.t, ft)))
    return rows


def variants(warps: tuple[str, ...] = ("bilinear", "bicubic")) -> list[tuple[str, str | None]]:
    """(method, warp) of every stream: the warping methods with each of ``warps``."""
    return [(m, w) for m in METHODS for w in (warps if m in WARPED else (None,))]


def label(method: str, warp: str | None) -> str:
    return method if warp is None else f"{method}, {warp} warp"


def proof_scene(motion: str, texture_seed: int = 1, warps: tuple[str, ...] = ("bilinear", "bicubic")) -> list[dict]:
    from rdnet.calib.scene import SceneSpec, draw_texture, render
    from rdnet.sim.interpolate import InterpolateConfig, upsample_all
    spec = SceneSpec(motion=motion)
    tex = draw_texture(spec, np.random.default_rng(texture_seed))
    frames, _ = render(spec, None, texture=tex)
    ft = frames.t_us.astype(np.int64)
    fine, _ = render(spec, None, fps_hz=6400.0, texture=tex)
    rows = [row("6400 fps reference", phases(ideal_events(fine.images, fine.t_us).t, ft))]
    for m, warp in variants(warps):
        icfg = InterpolateConfig(method=m, max_upsample=16, warp=warp or "bilinear")
        ims, t = upsample_all(frames.images, frames.t_us, icfg, warn=False)
        rows.append(row(f"100 fps, {label(m, warp)}", phases(ideal_events(ims, t).t, ft)))
    return rows


def main(argv: list[str] | None = None) -> int:
    from rdnet.calib.report import write_json
    from rdnet.eval.report import write_text_atomic
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "interpolation_phase")
    args = ap.parse_args(argv)
    blocks = {}
    if REAL.is_file():
        blocks["DAVIS346 road"] = davis346()
    for motion in ("drift", "backforth"):
        blocks[f"proof scene, {motion}"] = proof_scene(motion)
    write_json(args.out.with_suffix(".json"), {"benchmark": "interpolation_phase", "bins": BINS, "blocks": blocks})
    lines = ["# When events happen within a frame interval, by frame interpolation", "",
             "`benchmarks/interpolation_phase.py`: share of the events in each fifth of their frame interval "
             "(0.2 each when even) and the mean phase (0.5 when even); ideal sensor, seed 0.", "",
             "| recording | stream | events | 0-0.2 | 0.2-0.4 | 0.4-0.6 | 0.6-0.8 | 0.8-1 | mean phase |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, rows in blocks.items():
        for r in rows:
            lines.append(f"| {name} | {r['stream']} | {r['events']:,} | "
                         + " | ".join(f"{v:.3f}" for v in r["share_per_fifth"]) + f" | {r['mean_phase']:.3f} |")
    write_text_atomic(args.out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
