"""Where do the proof scenes' events come from under each frame interpolation? (issue 12: the
measurement behind "The interpolation choice is judged on the final pixel sample" in
docs/calibration.md.)

The calibration proof's scene (:mod:`rdnet.calib.scene`, 64 x 64) has a still illumination
edge between column 31 (dark half, gain 0.06) and column 32 (bright half) under moving
texture. Its frames are analytic, so the truth can be rendered at any rate. Per motion
('drift', 'backforth') and texture draw, the ideal sensor (:func:`rdnet.calib.fit.default_simulate`,
SensorConfig() and no degradation, seed 0) is run on

* the scene rendered at 1600 fps (then linearly upsampled at most 4x): the reference;
* the 100 fps frames the calibration gets, upsampled by ``flow``, ``linear`` and ``selected``
  as the proof's calibrations do (``interpolate.max_upsample`` 16),

and the events are counted in the edge column (31, odd: a search sample of every 2nd column
never sees it), in the rest of the dark half (columns 0-30), in the bright half, and over the
moving rows only (below the static band). Flow's estimate is smooth across the still edge,
so its warps drag bright texture into the dark column next to it.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/flow_edge_drag.py
    # -> benchmarks/results/flow_edge_drag.{json,md} (about 1 min)
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("flow", "linear", "selected")
EDGE_COL = 31


def ideal_events(images: np.ndarray, t_us: np.ndarray):
    """The ideal sensor's events (SensorConfig(), no degradation, seed 0) on upsampled frames."""
    from rdnet.calib.fit import default_simulate
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    return default_simulate(images, t_us, SensorConfig(), DegradeConfig(), np.random.default_rng(0))


def counts_map(images: np.ndarray, t_us: np.ndarray) -> np.ndarray:
    """(H, W) event counts of :func:`ideal_events`."""
    ev = ideal_events(images, t_us)
    h, w = images.shape[1:3]
    return np.bincount(ev.y.astype(np.int64) * w + ev.x, minlength=h * w).reshape(h, w).astype(np.int64)


def regions(m: np.ndarray, static_rows: int) -> dict:
    """Event counts per region of a counts map (moving rows only for the column regions)."""
    mov = m[static_rows:]
    return {"total": int(m.sum()), "edge_column": int(mov[:, EDGE_COL].sum()),
            "dark_rest": int(mov[:, :EDGE_COL].sum()), "bright_half": int(mov[:, EDGE_COL + 1:].sum()),
            "edge_column_share": float(mov[:, EDGE_COL].sum() / max(m.sum(), 1))}


def run(motion: str, texture_seed: int) -> dict:
    from rdnet.calib.scene import SceneSpec, draw_texture, render
    from rdnet.sim.interpolate import InterpolateConfig, upsample_all
    spec = SceneSpec(motion=motion)
    assert spec.width // 2 == EDGE_COL + 1, "the dark half ends at column 31"
    tex = draw_texture(spec, np.random.default_rng(texture_seed))
    static_rows = int(round(spec.static_fraction * spec.height))
    fine, _ = render(spec, None, fps_hz=1600.0, texture=tex)
    ims, t = upsample_all(fine.images, fine.t_us, InterpolateConfig(method="linear", max_upsample=4), warn=False)
    out = {"motion": motion, "texture_seed": texture_seed, "reference_1600fps": regions(counts_map(ims, t), static_rows)}
    frames, _ = render(spec, None, texture=tex)
    for m in METHODS:
        ims, t = upsample_all(frames.images, frames.t_us, InterpolateConfig(method=m, max_upsample=16), warn=False)
        out[m] = regions(counts_map(ims, t), static_rows)
    return out


def main(argv: list[str] | None = None) -> int:
    from rdnet.calib.report import write_json
    from rdnet.eval.report import write_text_atomic
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--texture-seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "flow_edge_drag")
    args = ap.parse_args(argv)
    rows = [run(motion, s) for motion in ("drift", "backforth") for s in args.texture_seeds]
    write_json(args.out.with_suffix(".json"), {"benchmark": "flow_edge_drag", "edge_column": EDGE_COL, "runs": rows})
    lines = ["# Events per region of the proof scene, by frame interpolation", "",
             f"`benchmarks/flow_edge_drag.py`: ideal sensor, seed 0; moving rows; edge column = {EDGE_COL} "
             "(dark side of the still illumination edge); reference = the scene rendered at 1600 fps.", "",
             "| motion | texture | frames | all events | edge column (share of all) | dark half, other columns | bright half |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        for key in ("reference_1600fps",) + METHODS:
            g = r[key]
            lines.append(f"| {r['motion']} | {r['texture_seed']} | {key} | {g['total']:,} | {g['edge_column']:,} "
                         f"({100 * g['edge_column_share']:.1f} %) | {g['dark_rest']:,} | {g['bright_half']:,} |")
    write_text_atomic(args.out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
