"""A small procedural scene for testing the calibration: a smooth random texture that
moves (steady drift with pauses, or back and forth) under an illumination with a dark
and a bright half, above a static textured band. Rendered analytically, so frames can be
drawn at any rate: the periodic texture is a band-limited function (the trigonometric
interpolant of its samples, its Nyquist term dropped) and each frame samples it shifted
exactly (a phase ramp on its Fourier series along x). A translating scene then looks the
same at every subpixel phase, as it does through a lens, which band-limits the image
before the pixels sample it. Sampling a piecewise-linear interpolant of the texture
instead (the renderer before 2026-11-30) blurs each frame by an amount that follows the
phase of its shift, a flicker of the texture's contrast that no camera records and that
frames rendered 4x denser (the oversample4 and circuit truths of the proof) show between
the recorded frames, where no interpolation of the recorded frames can predict it
(docs/calibration.md, "A band-limited proof scene")."""
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
    gain = np.ones((H, W), np.float32)
    gain[:, : W // 2] = spec.dark_gain
    rows_static = int(round(spec.static_fraction * H))
    off = position(spec, t_us * 1e-6)
    frames = np.empty((n, H, W), np.float32)
    for i, img in enumerate(shifted_texture(texture, off, W)):
        img[:rows_static] = texture[:rows_static, :W]
        frames[i] = img * gain
    return Frames(frames, t_us, np.zeros(n, np.int64)), texture


def shifted_texture(texture: np.ndarray, offsets_px: np.ndarray, width: int):
    """The first ``width`` columns of the periodic ``texture`` (H, TW) shifted right by each
    of ``offsets_px`` (float pixels), one float32 (H, width) array each: samples of the
    texture's band-limited interpolant (module docstring), so a whole-pixel shift is the
    texture rolled (up to the dropped Nyquist term) and no subpixel phase blurs it. Values
    below 0 (the interpolant's ringing; the texture is smooth, so rare and small) are clipped
    to 0: light is not negative."""
    TW = texture.shape[1]
    spectrum = np.fft.rfft(texture.astype(np.float64), axis=1)
    if TW % 2 == 0:
        spectrum[:, -1] = 0.0        # the Nyquist term: not a real function once shifted by a fraction
    k = np.fft.rfftfreq(TW)
    for o in np.asarray(offsets_px, np.float64):
        img = np.fft.irfft(spectrum * np.exp(-2j * np.pi * k * o), n=TW, axis=1)[:, :width]
        yield np.maximum(img, 0.0).astype(np.float32)
