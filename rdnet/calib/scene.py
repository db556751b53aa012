"""A small procedural scene for testing the calibration: a smooth random texture that
moves (steady drift with pauses, or back and forth) under an illumination with a dark
and a bright half, above a static textured band. Rendered analytically (subpixel shifts
by linear interpolation of a periodic texture), so frames can be drawn at any rate."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from rdnet.events.recording import Frames


@dataclass(frozen=True)
class SceneSpec:
    """``motion``: 'drift' (speed ``speed_px_s`` modulated by a half-wave sine of period
    ``period_s``, so the texture stops and starts) or 'backforth' (sinusoidal oscillation
    of amplitude ``amplitude_px`` and period ``period_s``). ``static_fraction``: top rows
    that never move. ``dark_gain``: illumination of the left half (right half = 1).
    ``texture_px``: feature size (std of the Gaussian smoothing of the noise)."""

    width: int = 64
    height: int = 64
    duration_us: int = 1_000_000
    fps_hz: float = 100.0
    motion: Literal["drift", "backforth"] = "drift"
    speed_px_s: float = 150.0
    amplitude_px: float = 6.0
    period_s: float = 0.4
    static_fraction: float = 0.25
    dark_gain: float = 0.06
    texture_px: float = 1.0
    contrast: tuple = (0.05, 1.0)


def _texture(h: int, w: int, sigma: float, lo: float, hi: float, rng: np.random.Generator) -> np.ndarray:
    noise = rng.random((h, w)).astype(np.float32)
    # periodic smoothing: wrap-pad, blur, crop (the texture is shifted cyclically)
    p = int(4 * sigma) + 1
    big = np.pad(noise, p, mode="wrap")
    sm = cv2.GaussianBlur(big, (0, 0), sigma)[p:-p, p:-p]
    sm = (sm - sm.min()) / max(float(sm.max() - sm.min()), 1e-6)
    return (lo + (hi - lo) * sm).astype(np.float32)


def draw_texture(spec: SceneSpec, rng: np.random.Generator) -> np.ndarray:
    """The scene's periodic texture ((H, 2W) float32), the one random draw of :func:`render`
    (pass it back to render the same scene again, at any rate)."""
    return _texture(spec.height, 2 * spec.width, spec.texture_px, spec.contrast[0], spec.contrast[1], rng)


def position(spec: SceneSpec, t_s: np.ndarray) -> np.ndarray:
    """Horizontal texture offset (pixels) at times ``t_s``."""
    w = 2 * np.pi / spec.period_s
    if spec.motion == "backforth":
        return spec.amplitude_px * np.sin(w * t_s)
    # integral of speed * max(0, sin(w t)): moves on half periods, rests on the others
    k = np.floor(t_s / spec.period_s)
    ph = t_s - k * spec.period_s
    half = spec.period_s / 2
    per_half = 2 * spec.speed_px_s / w
    inside = np.where(ph < half, spec.speed_px_s * (1 - np.cos(w * ph)) / w, per_half)
    return k * per_half + inside


def render(spec: SceneSpec, rng: np.random.Generator, fps_hz: float | None = None,
           texture: np.ndarray | None = None, preroll_us: int = 0) -> tuple[Frames, np.ndarray]:
    """Frames (float32 linear) at ``fps_hz`` (default ``spec.fps_hz``) and the texture used
    (pass it back to render the same scene at another rate). ``preroll_us``: also the
    frames of the scene before t = 0, from about ``-preroll_us`` (a whole number of frame
    periods, so a frame falls on t = 0 and the frames from there on are the same as
    without it)."""
    H, W = spec.height, spec.width
    fps = spec.fps_hz if fps_hz is None else fps_hz
    n = int(round(spec.duration_us * 1e-6 * fps)) + 1
    n_pre = int(round(preroll_us * 1e-6 * fps))
    n += n_pre
    t_us = np.rint((np.arange(n) - n_pre) * 1e6 / fps).astype(np.int64)
    if texture is None:
        texture = draw_texture(spec, rng)
    TW = texture.shape[1]
    gain = np.ones((H, W), np.float32)
    gain[:, : W // 2] = spec.dark_gain
    rows_static = int(round(spec.static_fraction * H))
    cols = np.arange(W, dtype=np.float64)
    off = position(spec, t_us * 1e-6)
    frames = np.empty((n, H, W), np.float32)
    for i, o in enumerate(off):
        u = np.mod(cols - o, TW)
        j = np.floor(u)
        f = (u - j).astype(np.float32)
        j0 = j.astype(np.int64) % TW          # u can round up to TW itself
        j1 = (j0 + 1) % TW
        img = texture[:, j0] * (1 - f) + texture[:, j1] * f
        img[:rows_static] = texture[:rows_static, :W]
        frames[i] = img * gain
    return Frames(frames, t_us, np.zeros(n, np.int64)), texture
