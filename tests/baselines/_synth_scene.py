"""Analytic test scene for the baselines: a textured pattern translating horizontally
during an exposure, its blurry frame (mean of the latent frames), the sharp middle frame
and ideal events (log-intensity threshold crossings of each pixel, threshold ``C``)."""
from __future__ import annotations

import numpy as np

from rdnet.events import Events


def translating_scene(seed=4, H=48, W=64, C=0.2, T_us=20000, shift_px=12.0, nt=2000):
    rng = np.random.default_rng(seed)
    base = np.full((H, W + 40), 0.2)
    for _ in range(12):  # random rectangles of random intensity
        y0, x0 = rng.integers(0, H - 8), rng.integers(0, W + 30)
        base[y0:y0 + rng.integers(4, 16), x0:x0 + rng.integers(3, 12)] = rng.uniform(0.05, 0.9)
    # light 3-tap smoothing so edges span ~2 pixels (no aliasing at sub-pixel shifts)
    base = (np.roll(base, 1, 1) + 2 * base + np.roll(base, -1, 1)) / 4
    base = (np.roll(base, 1, 0) + 2 * base + np.roll(base, -1, 0)) / 4
    ts = np.linspace(0, T_us, nt + 1)

    def frame(t):
        xq = np.arange(W) + 20 + shift_px * (t / T_us - 0.5)
        i0 = np.floor(xq).astype(int)
        f = xq - i0
        return base[:, i0] * (1 - f) + base[:, i0 + 1] * f

    frames = np.stack([frame(t) for t in ts])
    logI = np.log(frames)
    level = np.floor((logI - logI[0]) / C)
    dl = np.diff(level, axis=0).astype(np.int64)
    k, y, x = np.nonzero(dl)
    n = np.abs(dl[k, y, x])
    p = (dl[k, y, x] > 0).astype(np.uint8)
    k, y, x, p = (np.repeat(a, n) for a in (k, y, x, p))
    t = np.round(ts[k + 1]).astype(np.int64)
    events = Events.from_columns(t, x, y, p, W, H, sort=True)
    blurry = 0.5 * (frames[1:] + frames[:-1]).mean(axis=0)   # trapezoid mean over exposure
    return blurry, frame(T_us / 2), events, T_us


def psnr(a, b):
    return float(10 * np.log10(1.0 / np.mean((np.asarray(a, np.float64) - b) ** 2)))
