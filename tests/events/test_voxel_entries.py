"""rdnet.events.voxel.voxel_events reads only the non-zero entries (rdnet.events.voxel.
entry_events): the same events as the dense float64 implementation it replaced, for
integer and float grids, signed and per polarity, any scale and both modes."""
from __future__ import annotations

import numpy as np
import pytest

from rdnet.errors import ValidationError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.voxel import entry_events, voxel_events


def _dense_reference(grid, t0_us, duration_us, mode="hard", scale=1.0):
    """voxel_events as it was (a float64 copy of the whole grid, then int64)."""
    grid = np.asarray(grid)
    split = grid.ndim == 4
    bins, H, W = grid.shape[-3:]
    counts = np.rint(grid.astype(np.float64) * float(scale)).astype(np.int64).ravel()
    if split:
        assert not (counts < 0).any()
        counts[counts.size // 2:] *= -1
    nz = np.flatnonzero(counts)
    n = np.abs(counts[nz])
    idx = np.repeat(nz, n)
    first = np.repeat(np.cumsum(n) - n, n)
    j = np.arange(idx.size, dtype=np.int64) - first
    nn = np.repeat(n, n)
    b = (idx // (H * W)) % bins
    if mode == "hard":
        lo = -((-b * duration_us) // bins)
        hi = np.where(b == bins - 1, duration_us, -((-(b + 1) * duration_us) // bins) - 1)
        span = np.maximum(hi - lo + 1, 1)
        t = t0_us + np.minimum(lo + ((2 * j + 1) * span) // (2 * nn), duration_us)
    else:
        t = t0_us - (-(b * duration_us) // max(bins - 1, 1))
    pix = idx % (H * W)
    order = np.argsort(t, kind="stable")
    arr = np.empty(idx.size, EVENT_DTYPE)
    arr["t"], arr["x"], arr["y"] = t[order], (pix % W)[order], (pix // W)[order]
    arr["p"] = (counts[idx] > 0)[order]
    return Events(arr, W, H, validate=False)


def _same(a: Events, b: Events):
    assert (a.width, a.height) == (b.width, b.height)
    np.testing.assert_array_equal(a.array, b.array)


@pytest.mark.parametrize("mode", ["hard", "bilinear"])
@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.int8, np.float32, np.float64])
@pytest.mark.parametrize("split", [False, True])
@pytest.mark.parametrize("scale", [1.0, 0.37])
def test_voxel_events_equal_the_dense_implementation(mode, dtype, split, scale):
    rng = np.random.default_rng(7)
    shape = (2, 4, 6, 9) if split else (4, 6, 9)
    sparse = rng.random(shape) < 0.2
    if np.issubdtype(dtype, np.integer):
        grid = (rng.integers(0 if split else -3, 4, shape) * sparse).astype(dtype)
    else:    # near-half values on both sides, exact halves (rint: half to even) and zeros
        grid = (rng.integers(0 if split else -3, 4, shape) + rng.choice([-0.5, -0.49, 0.0, 0.49, 0.5], shape)) * sparse
        grid = np.abs(grid).astype(dtype) if split else grid.astype(dtype)
    for t0, dur in ((0, 100), (-12345, 7), (10**9, 40_000)):
        _same(voxel_events(grid, t0, dur, mode=mode, scale=scale), _dense_reference(grid, t0, dur, mode, scale))


def test_entry_events_known_values_and_checks():
    # signed (bins 2, H 1, W 3): +2 at bin 0 x 1 (times 0..4: 1, 3), -1 at bin 1 x 2 (5..10: 8)
    ev = entry_events(np.array([1, 5]), np.array([2, -1]), (2, 1, 3), 100, 10)
    assert ev.t.tolist() == [101, 103, 108] and ev.x.tolist() == [1, 1, 2] and ev.p.tolist() == [1, 1, 0]
    # per polarity (2, bins 1, H 1, W 2): 1 ON at x 0, 3 OFF at x 1; count 0 gives nothing
    ev = entry_events(np.array([0, 1, 3]), np.array([1, 0, 3]), (2, 1, 1, 2), 0, 6)
    assert ev.t.tolist() == [1, 3, 3, 5] and ev.x.tolist() == [1, 0, 1, 1] and ev.p.tolist() == [0, 1, 0, 0]
    assert len(entry_events(np.zeros(0, np.int64), np.zeros(0, np.int64), (2, 3, 4, 5), 0, 10)) == 0
    with pytest.raises(ValidationError, match="negative"):
        entry_events(np.array([0]), np.array([-1]), (2, 1, 1, 2), 0, 6)
    with pytest.raises(ValidationError, match="increasing"):
        entry_events(np.array([3, 1]), np.array([1, 1]), (2, 1, 1, 2), 0, 6)
    with pytest.raises(ValidationError, match="increasing"):
        entry_events(np.array([4]), np.array([1]), (2, 1, 1, 2), 0, 6)          # outside the grid
    with pytest.raises(ValidationError, match="differ"):
        entry_events(np.array([0, 1]), np.array([1]), (2, 1, 1, 2), 0, 6)
    with pytest.raises(ValidationError, match="duration"):
        entry_events(np.array([0]), np.array([1]), (2, 1, 1, 2), 0, 0)
    with pytest.raises(ValidationError, match="shape"):
        entry_events(np.array([0]), np.array([1]), (3, 1, 1, 2), 0, 6)
    with pytest.raises(ValidationError, match="negative"):
        voxel_events(-np.ones((2, 1, 1, 2), np.int64), 0, 6)
