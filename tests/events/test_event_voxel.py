"""Voxel grid (RDNet Eq. 7): conservation of the signed count, bin edges, both modes."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rdnet.errors import ValidationError
from rdnet.events import EVENT_DTYPE, Events, voxel_grid

MODES = ["hard", "bilinear"]


def _events(t, x, y, p, w=8, h=6):
    return Events.from_columns(t, x, y, p, w, h)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300), bins=st.integers(1, 12),
       duration=st.integers(1, 10**7), mode=st.sampled_from(MODES))
def test_sum_over_bins_equals_signed_count(seed, n, bins, duration, mode):
    rng = np.random.default_rng(seed)
    t0 = int(rng.integers(-10**9, 10**9))
    w, h = 7, 5
    arr = np.empty(n, EVENT_DTYPE)
    # events before, inside (edges included) and after the window
    arr["t"] = np.sort(rng.integers(t0 - duration // 2, t0 + duration + duration // 2 + 2, n))
    arr["x"], arr["y"], arr["p"] = rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n)
    ev = Events(arr, w, h)
    grid = voxel_grid(ev, bins, t0, duration, mode=mode)
    assert grid.shape == (bins, h, w) and grid.dtype == np.float32
    inside = ev.select((arr["t"] >= t0) & (arr["t"] <= t0 + duration))
    np.testing.assert_allclose(grid.sum(axis=0), inside.signed_count_per_pixel(), atol=1e-4)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), bins=st.integers(1, 100), duration=st.integers(1, 10**9))
def test_hard_bins_follow_exact_integer_edges(seed, bins, duration):
    """Bin k holds [t0 + k T / bins, t0 + (k + 1) T / bins), also exactly on the edges."""
    rng = np.random.default_rng(seed)
    k = rng.integers(0, bins, 50)
    dt = np.sort(np.concatenate([-(-k * duration // bins), rng.integers(0, duration + 1, 50)]))
    ev = _events(1000 + dt, np.zeros(dt.size), np.zeros(dt.size), np.ones(dt.size))
    grid = voxel_grid(ev, bins, 1000, duration)
    expected = np.bincount(np.minimum(dt * bins // duration, bins - 1), minlength=bins)
    np.testing.assert_array_equal(grid[:, 0, 0], expected)


def test_event_on_a_bin_edge_where_float_division_rounds_down():
    # 228304608 * 100 / 400534400 = 57 exactly, but (228304608 / 400534400) * 100 = 56.99999... in float64
    ev = _events([228_304_608], [0], [0], [1])
    g = voxel_grid(ev, 100, 0, 400_534_400)
    assert g[57, 0, 0] == 1.0 and g.sum() == 1.0


@pytest.mark.parametrize("mode", MODES)
def test_event_at_window_end_counts_in_last_bin(mode):
    t0, T, bins = 500, 1000, 10
    ev = _events([t0 - 1, t0, t0 + T, t0 + T + 1], [1, 2, 3, 4], [0, 0, 0, 0], [1, 1, 0, 1])
    g = voxel_grid(ev, bins, t0, T, mode=mode)
    assert g[-1, 0, 3] == -1.0              # OFF event at exactly t0 + T
    assert g[0, 0, 2] == 1.0                # ON event at exactly t0
    assert g[:, 0, 1].sum() == 0 and g[:, 0, 4].sum() == 0   # outside the window
    assert np.count_nonzero(g) == 2


def test_bilinear_splits_linearly_between_neighbouring_bins():
    # bins = 5 -> tau = 4 (t - t0) / T; t - t0 = 0.3 T -> tau = 1.2: 0.8 to bin 1, 0.2 to bin 2
    ev = _events([300], [0], [0], [1])
    g = voxel_grid(ev, 5, 0, 1000, mode="bilinear")
    np.testing.assert_allclose(g[:, 0, 0], [0, 0.8, 0.2, 0, 0], atol=1e-6)
    g = voxel_grid(ev, 5, 0, 1000, mode="hard")
    np.testing.assert_array_equal(g[:, 0, 0], [0, 1, 0, 0, 0])


@pytest.mark.parametrize("mode", MODES)
def test_one_million_events(mode):
    rng = np.random.default_rng(7)
    n, w, h, T = 1_000_000, 346, 260, 50_000
    arr = np.empty(n, EVENT_DTYPE)
    arr["t"] = np.sort(rng.integers(0, T + 1, n))
    arr["x"], arr["y"], arr["p"] = rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n)
    ev = Events(arr, w, h)
    g = voxel_grid(ev, 10, 0, T, mode=mode)
    np.testing.assert_allclose(g.sum(axis=0), ev.signed_count_per_pixel(), atol=1e-3)
    if mode == "hard":
        per_bin = np.bincount(np.minimum(arr["t"] * 10 // T, 9), weights=arr["p"] * 2.0 - 1.0, minlength=10)
        np.testing.assert_allclose(g.sum(axis=(1, 2)), per_bin)


def test_normalisation_and_argument_checks():
    ev = _events([0, 10, 20, 30], [0, 0, 1, 2], [0, 0, 0, 1], [1, 1, 0, 1])
    raw = voxel_grid(ev, 2, 0, 40)
    assert np.abs(raw).max() == 2.0
    assert np.abs(voxel_grid(ev, 2, 0, 40, normalize="maxabs")).max() == 1.0
    nz = raw[raw != 0]
    np.testing.assert_allclose(voxel_grid(ev, 2, 0, 40, normalize="std")[raw != 0], nz / nz.std())
    for kw in ({"bins": 0}, {"duration_us": 0}, {"mode": "nearest"}, {"normalize": "l2"}):
        args = {"bins": 2, "t0_us": 0, "duration_us": 40, **kw}
        with pytest.raises(ValidationError):
            voxel_grid(ev, **args)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), bins=st.integers(1, 12), duration=st.integers(1, 10**7),
       t0=st.integers(-10**9, 10**9))
def test_voxel_events_inverts_hard_voxel_grids(seed, bins, duration, t0):
    from rdnet.events import voxel_events
    duration = max(duration, bins)           # bins shorter than 1 us hold no integer time
    rng = np.random.default_rng(seed)
    grid = rng.integers(-3, 4, (bins, 5, 7)).astype(np.float32)
    noisy = grid + rng.uniform(-0.45, 0.45, grid.shape).astype(np.float32)    # rounds back to grid
    ev = voxel_events(noisy, t0, duration)
    assert len(ev) == int(np.abs(grid).sum()) and (ev.width, ev.height) == (7, 5)
    assert np.all(np.diff(ev.t) >= 0) and ev.t.min(initial=t0) >= t0 and ev.t.max(initial=t0) <= t0 + duration
    np.testing.assert_array_equal(voxel_grid(ev, bins, t0, duration), grid)
    back = voxel_grid(voxel_events(grid, t0, duration, mode="bilinear"), bins, t0, duration, mode="bilinear")
    np.testing.assert_allclose(back.sum(0), grid.sum(0), atol=1e-4)          # signed count kept


@pytest.mark.parametrize("normalize", [None, "maxabs", "std"])
def test_normalization_scale_undoes_normalize_voxel(normalize):
    from rdnet.events import normalization_scale, normalize_voxel, voxel_events
    grid = np.array([[[0, 2, -4], [1, 0, 3]]], np.float32)
    scale = normalization_scale(grid, normalize)
    np.testing.assert_allclose(normalize_voxel(grid, normalize) * scale, grid)
    assert len(voxel_events(normalize_voxel(grid, normalize), 0, 100, scale=scale)) == 10
    assert normalization_scale(np.zeros((2, 3, 3), np.float32), normalize) == 1.0
