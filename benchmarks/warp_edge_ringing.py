"""What a bicubic warp costs at a sharp edge (issue 12, the caveat of ``calibrate.warp``).

A bicubic warp keeps a texture's contrast where a bilinear one blurs it
(``tests/sim/test_interpolate_warp.py``, ``benchmarks/interpolation_phase.py``), but at a
sharp edge it rings: the warped frame undershoots on the dark side and overshoots on the
bright side. In log intensity the undershoot of a dark side is magnified, so an ideal
sensor fires extra events there. This measures it on a straight edge of one
pixel's sharpness (16x supersampled, box-filtered pixels), moving 1.3 px per frame at
100 fps, for several dark levels against a bright side of 0.9: the ideal sensor's event
count on the 100 fps frames upsampled by flow with each warp, against the same edge
rendered at 6400 fps. For such an edge a bilinear warp is exact (a box-filtered pixel is
linear in the edge's position inside it), so every event beyond the reference comes from
the ringing.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/warp_edge_ringing.py
    # -> benchmarks/results/warp_edge_ringing.{json,md} (about 10 s)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from flow_edge_drag import ideal_events  # noqa: E402

BRIGHT = 0.9
DARK = (0.01, 0.02, 0.05, 0.1, 0.2)
FRAME_US = 10_000
SPEED_PX = 1.3          # per frame
SUPERSAMPLE = 16


def edge_frames(n_frames: int, per_frame: int, dark: float, h: int = 40, w: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """(frames, t_us) of the edge at ``per_frame`` times the frame rate (box-filtered pixels)."""
    x = np.arange(w * SUPERSAMPLE) / SUPERSAMPLE
    k = np.arange(n_frames * per_frame + 1)
    pos = 16.0 + SPEED_PX * k / per_frame
    rows = np.where(x[None, :] < pos[:, None], BRIGHT, dark).reshape(len(k), w, SUPERSAMPLE).mean(-1)
    frames = np.ascontiguousarray(np.broadcast_to(rows[:, None, :], (len(k), h, w))).astype(np.float32)
    return frames, np.round(k * FRAME_US / per_frame).astype(np.int64)


def run() -> list[dict]:
    from rdnet.sim.interpolate import InterpolateConfig, upsample_all
    rows = []
    for dark in DARK:
        ref = ideal_events(*edge_frames(20, 64, dark))
        frames, t = edge_frames(20, 1, dark)
        row = {"dark": dark, "contrast": BRIGHT / dark, "reference_events": int(len(ref))}
        for warp in ("bilinear", "bicubic", "bicubic_clamped"):
            ims, ts = upsample_all(frames, t, InterpolateConfig(method="flow", max_upsample=16, warp=warp), warn=False)
            row[f"{warp}_events"] = int(len(ideal_events(ims, ts)))
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    from rdnet.calib.report import write_json
    from rdnet.eval.report import write_text_atomic
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "warp_edge_ringing")
    args = ap.parse_args(argv)
    rows = run()
    write_json(args.out.with_suffix(".json"), {"benchmark": "warp_edge_ringing", "bright": BRIGHT,
                                               "speed_px_per_frame": SPEED_PX, "frame_us": FRAME_US, "rows": rows})
    lines = ["# Events at a sharp moving edge: bilinear against bicubic warps (and bicubic clamped)", "",
             f"`benchmarks/warp_edge_ringing.py`: a straight edge (bright {BRIGHT}, box-filtered pixels) moving "
             f"{SPEED_PX} px per {FRAME_US // 1000} ms frame; ideal sensor (thresholds 0.2) on the 100 fps frames "
             "upsampled by flow with each warp, against the edge rendered at 6400 fps.", "",
             "| dark side | contrast | reference events | bilinear | bicubic | bicubic excess | bicubic_clamped | "
             "bicubic_clamped excess |", "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        ex = {w: r[f"{w}_events"] / max(r["reference_events"], 1) - 1 for w in ("bicubic", "bicubic_clamped")}
        lines.append(f"| {r['dark']} | {r['contrast']:.0f}:1 | {r['reference_events']:,} | {r['bilinear_events']:,} | "
                     f"{r['bicubic_events']:,} | {100 * ex['bicubic']:+.1f} % | {r['bicubic_clamped_events']:,} | "
                     f"{100 * ex['bicubic_clamped']:+.1f} % |")
    write_text_atomic(args.out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
