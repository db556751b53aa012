"""Event voxel grids (RDNet paper, Eq. 7).

For an exposure window [t0, t0 + T] split into ``bins`` equal bins, bin ``k`` of pixel
(x, y) holds the signed sum of the polarities (+1 ON, -1 OFF) of the events in
[t0 + k T / bins, t0 + (k + 1) T / bins). The last bin is closed on the right so that
an event at exactly t0 + T is counted.

``mode="bilinear"`` instead places each event at the continuous position
tau = (bins - 1) (t - t0) / T and splits its polarity linearly between bins floor(tau)
and floor(tau) + 1 (the EFNet / E-RAFT convention). Both modes conserve the signed
count: summing over bins gives the signed event count per pixel.

Normalisation (``normalize``): ``None`` keeps raw signed counts (the default, what the
networks consume); ``"maxabs"`` divides by the largest absolute value;
``"std"`` divides the non-zero entries by their standard deviation (EFNet style).
"""
from __future__ import annotations

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events


def voxel_grid(events: Events, bins: int, t0_us: int, duration_us: int, *,
               mode: str = "hard", normalize: str | None = None) -> np.ndarray:
    """(bins, height, width) float32 voxel grid of the events in [t0, t0 + duration]."""
    if bins < 1:
        raise ValidationError("bins", f"must be >= 1, got {bins}")
    if duration_us <= 0:
        raise ValidationError("duration_us", f"must be > 0, got {duration_us}")
    t0_us, duration_us = int(t0_us), int(duration_us)
    H, W = events.height, events.width
    i0 = int(np.searchsorted(events.t, t0_us, "left"))
    i1 = int(np.searchsorted(events.t, t0_us + duration_us, "right"))
    a = events.array[i0:i1]
    pol = a["p"].astype(np.float32) * 2.0 - 1.0
    pix = a["y"].astype(np.int64) * W + a["x"].astype(np.int64)
    # Integer arithmetic for the bin index: float (t - t0) / T * bins can fall just below
    # an exact bin boundary and put the event in the previous bin.
    dt = a["t"] - np.int64(t0_us)
    size = bins * H * W
    if mode == "hard":
        b = np.minimum(dt * bins // duration_us, bins - 1)
        grid = np.bincount(b * (H * W) + pix, weights=pol, minlength=size)
    elif mode == "bilinear":
        num = dt * (bins - 1)            # tau = num / T, split exactly into floor and fraction
        lo = num // duration_us
        frac = (num - lo * duration_us).astype(np.float64) / float(duration_us)
        hi = np.minimum(lo + 1, bins - 1)
        grid = np.bincount(lo * (H * W) + pix, weights=pol * (1.0 - frac), minlength=size)
        grid += np.bincount(hi * (H * W) + pix, weights=pol * frac, minlength=size)
    else:
        raise ValidationError("mode", f"unknown voxel mode {mode!r}; use 'hard' or 'bilinear'")
    grid = grid.reshape(bins, H, W).astype(np.float32)
    return normalize_voxel(grid, normalize)


def normalize_voxel(grid: np.ndarray, normalize: str | None) -> np.ndarray:
    if normalize is None or normalize == "none":
        return grid
    if normalize == "maxabs":
        m = float(np.abs(grid).max())
        return grid / m if m > 0 else grid
    if normalize == "std":
        nz = grid[grid != 0]
        s = float(nz.std()) if nz.size > 1 else 0.0
        return grid / s if s > 0 else grid
    raise ValidationError("normalize", f"unknown normalisation {normalize!r}; use none, maxabs or std")
