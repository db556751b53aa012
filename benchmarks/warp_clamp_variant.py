"""A variant of ``calibrate.warp: bicubic`` that was measured and not adopted (issue 12):
the bicubic warp clamped to the range of the source pixels around each sample (the 2 x 2
block that bilinear reads, or the 4 x 4 block that bicubic reads), the anti-ringing clamp of
image scalers. It runs ``benchmarks/warp_edge_ringing.py`` (a sharp moving edge, where
bicubic rings) and the proof-scene part of ``benchmarks/interpolation_phase.py`` (textures,
where bicubic times events as the 6400 fps reference does) with ``rdnet.sim.interpolate._remap``
replaced by a 4 x 4 clamped version for bicubic warps, and with the library's own 2 x 2 clamp
(``interpolate.warp: bicubic_clamped``; this script's own 2 x 2 version gave the same numbers
before the library had it, session 39).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/warp_clamp_variant.py
    # -> benchmarks/results/warp_clamp_variant.md (about 1 min)
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import interpolation_phase  # noqa: E402
import warp_edge_ringing  # noqa: E402


def clamped_remap(block: int):
    """``_remap`` whose bicubic result is clipped to the min / max of the ``block`` x ``block``
    source pixels the sample reads (4: bicubic's; the library's ``bicubic_clamped`` is the
    2 x 2 block bilinear reads)."""
    import rdnet.sim.interpolate as ip
    plain = ip._remap
    kernel = np.ones((block, block), np.uint8)
    anchor = (block // 2 - 1, block // 2 - 1)

    def remap(img, warp_map, interpolation=cv2.INTER_LINEAR, clamp=False, bounds=None):
        out = plain(img, warp_map, interpolation)
        if interpolation != cv2.INTER_CUBIC:
            return out
        lo = cv2.erode(img, kernel, anchor=anchor, borderType=cv2.BORDER_REPLICATE)
        hi = cv2.dilate(img, kernel, anchor=anchor, borderType=cv2.BORDER_REPLICATE)
        mx, my = np.floor(warp_map[..., 0]), np.floor(warp_map[..., 1])
        lo = cv2.remap(lo, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        hi = cv2.remap(hi, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return np.clip(out, lo, hi)
    return remap


def _cells(edge: list[dict], scenes: dict, warp: str) -> list[str]:
    """A table row's cells for ``warp``: the edge excess at the three sharpest contrasts, then
    flow / selected on both proof scenes (events, share in the last fifth, mean phase)."""
    cells = [" / ".join(f"{100 * (r[f'{warp}_events'] / r['reference_events'] - 1):+.1f} %" for r in edge[:3])]
    for motion in ("drift", "backforth"):
        for m in ("flow", "selected"):
            r = scenes[motion][f"100 fps, {m}, {warp} warp"]
            cells.append(f"{r['events']:,}, {r['share_per_fifth'][-1]:.3f}, {r['mean_phase']:.3f}")
    return cells


def main() -> int:
    import rdnet.sim.interpolate as ip
    from rdnet.eval.report import write_text_atomic
    lines = ["# Bicubic warps clamped to their source pixels' range (a variant, not adopted)", "",
             "`benchmarks/warp_clamp_variant.py`. Edge: events of the ideal sensor against the 6400 fps "
             "reference (`warp_edge_ringing.py`). Proof scene: flow / `selected` with bicubic warps, events, share "
             "in the last fifth of the frame interval and mean phase (`interpolation_phase.py`; reference in the "
             "first row of each scene).", "",
             "| clamp | edge excess at 90:1 / 45:1 / 18:1 | drift: flow | drift: selected | back and forth: flow | "
             "back and forth: selected |", "|---|---|---|---|---|---|"]

    def scenes(warps):
        return {motion: {r["stream"]: r for r in interpolation_phase.proof_scene(motion, warps=warps)}
                for motion in ("drift", "backforth")}
    edge, plain_scenes = warp_edge_ringing.run(), scenes(("bicubic", "bicubic_clamped"))
    plain = ip._remap
    ip._remap = clamped_remap(4)
    try:
        edge4, scenes4 = warp_edge_ringing.run(), scenes(("bicubic",))
    finally:
        ip._remap = plain
    lines += ["| none (the adopted bicubic) | " + " | ".join(_cells(edge, plain_scenes, "bicubic")) + " |",
              "| 2 x 2, `interpolate.warp: bicubic_clamped` | "
              + " | ".join(_cells(edge, plain_scenes, "bicubic_clamped")) + " |",
              "| 4 x 4 | " + " | ".join(_cells(edge4, scenes4, "bicubic")) + " |"]
    refs = {m: plain_scenes[m]["6400 fps reference"] for m in ("drift", "backforth")}
    lines.append("| reference (6400 fps) | 0 | " + " | ".join(
        f"{refs[m]['events']:,}, {refs[m]['share_per_fifth'][-1]:.3f}, {refs[m]['mean_phase']:.3f}"
        for m in ("drift", "drift", "backforth", "backforth")) + " |")
    write_text_atomic(ROOT / "benchmarks" / "results" / "warp_clamp_variant.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
