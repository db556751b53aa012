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

:func:`voxel_events` goes the other way: a (restored, real-valued) voxel grid rounded to
whole events, e.g. to write the output of the restoration network as an event stream;
:func:`entry_events` does the same from the grid's non-zero entries alone (positions and
counts), for callers that know them without the dense grid.

Per-polarity grids (``polarity="split"``): a (2, bins, height, width) grid of the ON
(index 0) and OFF (index 1) event *counts* per bin, each non-negative (a signed grid is
``split[0] - split[1]``, but ON and OFF events of one voxel no longer cancel). This is
the input and output of the count-output restoration network
(:class:`rdnet.nn.models.RestoreNet` with ``output="counts"``); :func:`voxel_events`
turns such a grid back into events too.
"""
from __future__ import annotations

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import EVENT_DTYPE, Events


POLARITY_MODES = ("signed", "split")


def voxel_grid(events: Events, bins: int, t0_us: int, duration_us: int, *,
               mode: str = "hard", normalize: str | None = None,
               polarity: str = "signed") -> np.ndarray:
    """(bins, height, width) float32 voxel grid of the events in [t0, t0 + duration];
    with ``polarity="split"`` a (2, bins, height, width) grid of ON and OFF counts
    (module docstring; ``normalize`` then scales both channels by one divisor)."""
    shape, terms = _voxel_terms(events, bins, t0_us, duration_us, mode, polarity)
    size = int(np.prod(shape))
    grid = sum(np.bincount(index, weights=w, minlength=size) for index, w in terms)
    return normalize_voxel(grid.reshape(shape).astype(np.float32), normalize)


def voxel_entries(events: Events, bins: int, t0_us: int, duration_us: int, *,
                  mode: str = "hard", polarity: str = "signed") -> tuple[np.ndarray, np.ndarray, tuple]:
    """The non-zero entries of :func:`voxel_grid` (no normalisation) without the dense
    grid: ``(index, values, shape)``, their flat C-order positions in ``shape``
    (increasing), their float32 values -- equal to the dense grid's there, the same sums
    in the same order -- and the grid's shape. For windows that hold far fewer events
    than voxels (``rdnet restore`` on a DAVIS346: about 1,300 events in 1.8 million
    voxels)."""
    shape, terms = _voxel_terms(events, bins, t0_us, duration_us, mode, polarity)
    pos, inverse = np.unique(np.concatenate([i for i, _ in terms]), return_inverse=True)
    # one bincount per term, added up: the sums voxel_grid forms, in the same order
    values, start = np.zeros(pos.size), 0
    for i, w in terms:
        values = values + np.bincount(inverse[start:start + i.size], weights=w, minlength=pos.size)
        start += i.size
    values = values.astype(np.float32)
    nz = values != 0
    return pos[nz].astype(np.int64), values[nz], shape


def _voxel_terms(events: Events, bins: int, t0_us: int, duration_us: int, mode: str,
                 polarity: str) -> tuple[tuple, list[tuple[np.ndarray, np.ndarray]]]:
    """The grid shape and its terms: one or two (flat index, float64 weight) arrays per
    event, the grid being the sum of each term's weights at its indices."""
    if polarity not in POLARITY_MODES:
        raise ValidationError("polarity", f"unknown polarity mode {polarity!r}; use 'signed' or 'split'")
    if bins < 1:
        raise ValidationError("bins", f"must be >= 1, got {bins}")
    if duration_us <= 0:
        raise ValidationError("duration_us", f"must be > 0, got {duration_us}")
    t0_us, duration_us = int(t0_us), int(duration_us)
    H, W = events.height, events.width
    i0 = int(np.searchsorted(events.t, t0_us, "left"))
    i1 = int(np.searchsorted(events.t, t0_us + duration_us, "right"))
    a = events.array[i0:i1]
    pix = a["y"].astype(np.int64) * W + a["x"].astype(np.int64)
    if polarity == "signed":
        pol = a["p"].astype(np.float64) * 2.0 - 1.0
        shape = (bins, H, W)
    else:   # ON events to plane 0, OFF events to plane 1, each with weight 1
        pol = np.ones(a.size, np.float64)
        pix = pix + (a["p"] == 0).astype(np.int64) * (bins * H * W)
        shape = (2, bins, H, W)
    # Integer arithmetic for the bin index: float (t - t0) / T * bins can fall just below
    # an exact bin boundary and put the event in the previous bin.
    dt = a["t"] - np.int64(t0_us)
    if mode == "hard":
        b = np.minimum(dt * bins // duration_us, bins - 1)
        return shape, [(b * (H * W) + pix, pol)]
    if mode == "bilinear":
        num = dt * (bins - 1)            # tau = num / T, split exactly into floor and fraction
        lo = num // duration_us
        frac = (num - lo * duration_us).astype(np.float64) / float(duration_us)
        hi = np.minimum(lo + 1, bins - 1)
        return shape, [(lo * (H * W) + pix, pol * (1.0 - frac)), (hi * (H * W) + pix, pol * frac)]
    raise ValidationError("mode", f"unknown voxel mode {mode!r}; use 'hard' or 'bilinear'")


def normalization_scale(grid: np.ndarray, normalize: str | None) -> float:
    """The divisor :func:`normalize_voxel` applies to ``grid`` (1.0 when it leaves the
    grid as is); multiplying a normalised grid by it gives signed counts again."""
    if normalize is None or normalize == "none":
        return 1.0
    if normalize == "maxabs":
        m = float(np.abs(grid).max()) if grid.size else 0.0
        return m if m > 0 else 1.0
    if normalize == "std":
        nz = grid[grid != 0]
        s = float(nz.std()) if nz.size > 1 else 0.0
        return s if s > 0 else 1.0
    raise ValidationError("normalize", f"unknown normalisation {normalize!r}; use none, maxabs or std")


def normalize_voxel(grid: np.ndarray, normalize: str | None) -> np.ndarray:
    scale = normalization_scale(grid, normalize)
    return grid if scale == 1.0 else grid / scale


def voxel_events(grid: np.ndarray, t0_us: int, duration_us: int, *, mode: str = "hard",
                 scale: float = 1.0) -> Events:
    """Events whose voxel grid over [t0, t0 + duration] is ``grid`` rounded to whole
    events: the inverse of :func:`voxel_grid` for integer grids.

    ``grid`` (bins, height, width) holds signed counts (times ``1 / scale`` when it was
    normalised: ``scale`` is :func:`normalization_scale` of the raw grid). Each entry
    becomes ``|round(v * scale)|`` events of polarity ``sign(v)``. A per-polarity grid
    (2, bins, height, width) of non-negative ON/OFF counts (``polarity="split"`` of
    :func:`voxel_grid`) gives ``round(v * scale)`` ON events per entry of plane 0 and OFF
    events per entry of plane 1 (negative entries are a ValidationError). ``mode="hard"`` spreads
    the n events of bin k evenly over the bin's integer microseconds (exact inverse when
    ``duration_us >= bins``: every bin then holds at least one integer time);
    ``mode="bilinear"`` puts them at the bin's time
    position t0 + k T / (bins - 1) (rounded up). Returns time-sorted events (stable in bin, row,
    column order for equal times) on a ``width`` x ``height`` sensor.

    Only the non-zero entries are converted (:func:`entry_events` does the rest): an
    integer grid with ``scale == 1`` is read as it is, a float grid with ``scale == 1`` is
    rounded in its own precision (the same integers as rounding in float64: a float32 value
    is a float64 value, and rounding to an integer is exact), other scales in float64.
    """
    grid = np.asarray(grid)
    split = grid.ndim == 4
    if not (grid.ndim == 3 or (split and grid.shape[0] == 2)):
        raise ValidationError("voxel", "expected (bins, height, width) or (2, bins, height, width), "
                              f"got shape {grid.shape}")
    flat = grid.reshape(-1)          # a view for the C-contiguous grids the callers pass
    if float(scale) != 1.0:
        rounded = np.rint(flat.astype(np.float64) * float(scale))
    elif np.issubdtype(grid.dtype, np.integer) or grid.dtype == np.bool_:
        rounded = flat                  # whole counts already
    else:
        rounded = np.rint(flat)         # in the grid's own precision
    nz = np.flatnonzero(rounded)
    counts = rounded[nz].astype(np.int64)
    return entry_events(nz, counts, grid.shape, t0_us, duration_us, mode=mode)


def entry_events(index: np.ndarray, counts: np.ndarray, shape: tuple, t0_us: int, duration_us: int, *,
                 mode: str = "hard") -> Events:
    """The events of a voxel grid of ``shape`` ((bins, H, W) signed or (2, bins, H, W) per
    polarity, as in :func:`voxel_events`) given by its non-zero entries alone: ``index``,
    their flat C-order positions, increasing, and ``counts``, their whole event counts
    (signed for a signed grid, >= 0 for a per-polarity one: negative is a ValidationError).
    Entries of count 0 give no event. ``voxel_events(grid, ...)`` is
    ``entry_events(flatnonzero(c), c[flatnonzero(c)], grid.shape, ...)`` with ``c`` the
    rounded grid; a caller that already knows the few non-zero voxels of a large grid
    (:func:`rdnet.nn.decision.decided_entries`) skips the dense grid."""
    shape = tuple(int(s) for s in shape)
    split = len(shape) == 4
    if not (len(shape) == 3 or (split and shape[0] == 2)):
        raise ValidationError("voxel", "expected (bins, height, width) or (2, bins, height, width), "
                              f"got shape {shape}")
    if duration_us <= 0:
        raise ValidationError("duration_us", f"must be > 0, got {duration_us}")
    bins, H, W = shape[-3:]
    nz = np.asarray(index, np.int64).ravel()
    v = np.asarray(counts, np.int64).ravel()
    if nz.shape != v.shape:
        raise ValidationError("voxel", f"{nz.size} entry positions and {v.size} counts differ")
    if nz.size and (nz[0] < 0 or nz[-1] >= int(np.prod(shape)) or (nz.size > 1 and np.any(np.diff(nz) <= 0))):
        raise ValidationError("voxel", "entry positions must be increasing flat indices inside the grid")
    if split:
        if (v < 0).any():
            raise ValidationError("voxel", "a per-polarity (2, bins, H, W) grid holds negative counts")
        v = np.where(nz >= bins * H * W, -v, v)               # plane 1: OFF events, as negative counts
    n = np.abs(v)
    idx = np.repeat(nz, n)                                   # one entry per event
    first = np.repeat(np.cumsum(n) - n, n)
    j = np.arange(idx.size, dtype=np.int64) - first          # event number inside its entry
    nn = np.repeat(n, n)
    b = (idx // (H * W)) % bins
    t0_us, duration_us = int(t0_us), int(duration_us)
    if mode == "hard":
        # the integer times of bin b: ceil(b T / bins) .. ceil((b + 1) T / bins) - 1 (last: .. T)
        lo = -((-b * duration_us) // bins)
        hi = np.where(b == bins - 1, duration_us, -((-(b + 1) * duration_us) // bins) - 1)
        span = np.maximum(hi - lo + 1, 1)
        t = t0_us + np.minimum(lo + ((2 * j + 1) * span) // (2 * nn), duration_us)
    elif mode == "bilinear":
        t = t0_us - (-(b * duration_us) // max(bins - 1, 1))     # ceil: lands in bin b
    else:
        raise ValidationError("mode", f"unknown voxel mode {mode!r}; use 'hard' or 'bilinear'")
    pix = idx % (H * W)
    order = np.argsort(t, kind="stable")
    arr = np.empty(idx.size, EVENT_DTYPE)
    arr["t"] = t[order]
    arr["x"] = (pix % W)[order]
    arr["y"] = (pix // W)[order]
    arr["p"] = np.repeat(v > 0, n)[order]
    return Events(arr, W, H, validate=False)
