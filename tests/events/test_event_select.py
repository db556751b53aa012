"""rdnet.events.select: a restored voxel grid written as events that keep the input's own
timestamps. Known answers per voxel (kept, thinned, added, polarity changed), the voxel grid
of the result equal to the restored grid, and bad input refused."""
import numpy as np
import pytest

from rdnet.errors import ValidationError
from rdnet.events import Events, voxel_grid
from rdnet.events.select import (capped_entries, event_voxels, floored_entries, select_events, shared_count,
                                 signed_entries)
from rdnet.events.voxel import entry_events

W, H, BINS, T0, DUR = 5, 4, 4, 1000, 400          # bins of 100 us: [1000, 1100), ...


def _ev(rows):
    t, x, y, p = (np.array(c) for c in zip(*rows))
    return Events.from_columns(t, x, y, p, W, H, sort=True)


def _entries(grid):
    flat = grid.reshape(-1)
    i = np.flatnonzero(flat)
    return i, flat[i]


def test_event_voxels_match_voxel_grid():
    ev = _ev([(1000, 0, 0, 1), (1099, 1, 0, 0), (1100, 1, 0, 0), (1400, 4, 3, 1)])    # 1400: last bin, closed
    grid = np.zeros((2, BINS, H, W), np.int64).reshape(-1)
    np.add.at(grid, event_voxels(ev, BINS, T0, DUR), 1)
    np.testing.assert_array_equal(grid.reshape(2, BINS, H, W), voxel_grid(ev, BINS, T0, DUR, polarity="split"))


def test_known_answers_per_voxel():
    ev = _ev([(1010, 0, 0, 1), (1020, 0, 0, 1), (1090, 0, 0, 1),     # 3 ON in one voxel
              (1150, 1, 1, 0),                                      # 1 OFF
              (1250, 2, 2, 1)])                                     # 1 ON
    grid = voxel_grid(ev, BINS, T0, DUR, polarity="split").astype(np.int64)
    grid[0, 0, 0, 0] = 1           # thinned to 1: the middle one of the three is kept
    grid[1, 1, 1, 1] = 3           # 1 input + 2 added in the bin [1100, 1200)
    grid[0, 2, 2, 2] = 0           # dropped ...
    grid[1, 2, 2, 2] = 1           # ... and an OFF event instead, in its bin
    grid[0, 3, 3, 4] = 2           # no input there: 2 added
    out = select_events(ev, *_entries(grid), grid.shape, T0, DUR)
    np.testing.assert_array_equal(voxel_grid(out, BINS, T0, DUR, polarity="split"), grid)
    got = set(zip(out.t.tolist(), out.x.tolist(), out.y.tolist(), out.p.tolist()))
    assert (1020, 0, 0, 1) in got and (1010, 0, 0, 1) not in got and (1090, 0, 0, 1) not in got
    assert (1150, 1, 1, 0) in got and (1250, 2, 2, 1) not in got
    added = [e for e in got if e not in {(1150, 1, 1, 0), (1020, 0, 0, 1)}]
    # the added events are where entry_events spreads them
    extra = np.zeros_like(grid)
    extra[1, 1, 1, 1], extra[1, 2, 2, 2], extra[0, 3, 3, 4] = 2, 1, 2
    ref = entry_events(*_entries(extra), grid.shape, T0, DUR)
    assert sorted(added) == sorted(zip(ref.t.tolist(), ref.x.tolist(), ref.y.tolist(), ref.p.tolist()))
    assert np.all(np.diff(out.t) >= 0)


def test_unchanged_grid_gives_the_input_back_and_thinning_spreads_evenly():
    rng = np.random.default_rng(0)
    n = 400
    ev = Events.from_columns(rng.integers(T0, T0 + DUR, n), rng.integers(0, W, n), rng.integers(0, H, n),
                             rng.integers(0, 2, n), W, H, sort=True)
    grid = voxel_grid(ev, BINS, T0, DUR, polarity="split").astype(np.int64)
    out = select_events(ev, *_entries(grid), grid.shape, T0, DUR)
    np.testing.assert_array_equal(out.array, ev.array)
    # one voxel with 4 events thinned to 2: ranks 1 and 3 (floor((2j + 1) 4 / 4))
    one = _ev([(1001, 0, 0, 1), (1002, 0, 0, 1), (1003, 0, 0, 1), (1004, 0, 0, 1)])
    g = voxel_grid(one, BINS, T0, DUR, polarity="split").astype(np.int64)
    g[0, 0, 0, 0] = 2
    assert select_events(one, *_entries(g), g.shape, T0, DUR).t.tolist() == [1002, 1004]
    # every voxel's count, random grids: the result's grid is the restored grid
    for seed in range(5):
        r = np.random.default_rng(seed)
        want = np.clip(grid + r.integers(-2, 3, grid.shape), 0, None)
        res = select_events(ev, *_entries(want), want.shape, T0, DUR)
        np.testing.assert_array_equal(voxel_grid(res, BINS, T0, DUR, polarity="split"), want)
        kept = np.isin(res.t * 1000 + res.y * 10 + res.x, ev.t * 1000 + ev.y * 10 + ev.x)
        assert kept.sum() >= np.minimum(want, grid).sum()


def test_signed_entries():
    g = np.array([[[2.4, -1.0], [0.0, -2.6]]])                 # (bins 1, H 2, W 2)
    idx, counts, shape = signed_entries(g)
    assert shape == (2, 1, 2, 2)
    dense = np.zeros(shape, np.int64).reshape(-1)
    dense[idx] = counts
    np.testing.assert_array_equal(dense.reshape(shape), [[[[2, 0], [0, 0]]], [[[0, 1], [0, 3]]]])
    with pytest.raises(ValidationError, match="negative"):
        signed_entries(-np.ones((2, 1, 2, 2)))


def test_bad_input_is_refused():
    ev = _ev([(1010, 0, 0, 1)])
    grid = voxel_grid(ev, BINS, T0, DUR, polarity="split")
    i, c = _entries(grid)
    with pytest.raises(ValidationError, match="outside the window"):
        select_events(ev, i, c, grid.shape, 2000, DUR)
    with pytest.raises(ValidationError, match="negative"):
        select_events(ev, i, -c, grid.shape, T0, DUR)
    with pytest.raises(ValidationError, match="increasing"):
        select_events(ev, np.r_[i, i], np.r_[c, c], grid.shape, T0, DUR)
    with pytest.raises(ValidationError, match="2, bins"):
        select_events(ev, i, c, grid.shape[1:], T0, DUR)
    assert len(select_events(ev, i[:0], c[:0], grid.shape, T0, DUR)) == 0


def test_shared_count_is_a_multiset_intersection():
    a = _ev([(1010, 0, 0, 1), (1010, 0, 0, 1), (1020, 1, 0, 0), (1030, 2, 0, 1)])
    b = _ev([(1010, 0, 0, 1), (1020, 1, 0, 1), (1030, 2, 0, 1), (1040, 3, 0, 1)])
    assert shared_count(a, b) == 2                 # one of the two duplicates; polarity counts
    assert shared_count(b, a) == 2 and shared_count(a, a) == 4
    assert shared_count(a, _ev([(1, 0, 0, 0)])[:0]) == 0


def test_capped_entries_never_exceed_the_input():
    ev = _ev([(1010, 0, 0, 1), (1020, 0, 0, 1), (1150, 1, 1, 0)])
    grid = voxel_grid(ev, BINS, T0, DUR, polarity="split").astype(np.int64)
    want = grid.copy()
    want[0, 0, 0, 0] = 5           # more than its 2 inputs: capped at 2
    want[1, 1, 1, 1] = 0           # deleted: stays deleted
    want[0, 3, 3, 4] = 2           # no input there: dropped
    idx, counts = capped_entries(ev, *_entries(want), want.shape, T0, DUR)
    got = np.zeros(want.size, np.int64)
    got[idx] = counts
    expect = np.zeros_like(want)
    expect[0, 0, 0, 0] = 2
    np.testing.assert_array_equal(got.reshape(want.shape), expect)
    assert (counts > 0).all()


def test_floored_entries_never_fall_below_the_input():
    """restore.delete_events: false: every voxel keeps at least its input events (one the
    restorer emptied comes back), counts above the input and added voxels stay."""
    ev = _ev([(1010, 0, 0, 1), (1020, 0, 0, 1), (1150, 1, 1, 0)])
    grid = voxel_grid(ev, BINS, T0, DUR, polarity="split").astype(np.int64)
    want = grid.copy()
    want[0, 0, 0, 0] = 1           # fewer than its 2 inputs: raised to 2
    want[1, 1, 1, 1] = 0           # deleted: comes back with its 1 input
    want[0, 3, 3, 4] = 2           # no input there: an addition, kept
    idx, counts = floored_entries(ev, *_entries(want), want.shape, T0, DUR)
    got = np.zeros(want.size, np.int64)
    got[idx] = counts
    expect = grid.copy()
    expect[0, 3, 3, 4] = 2
    np.testing.assert_array_equal(got.reshape(want.shape), expect)
    assert (counts > 0).all() and (np.diff(idx) > 0).all()
    # entries in any order give the same result; no entries at all give the input back
    i, c = _entries(want)
    idx2, counts2 = floored_entries(ev, i[::-1], c[::-1], want.shape, T0, DUR)
    np.testing.assert_array_equal(idx2, idx)
    np.testing.assert_array_equal(counts2, counts)
    idx3, counts3 = floored_entries(ev, i[:0], c[:0], want.shape, T0, DUR)
    np.testing.assert_array_equal(idx3, _entries(grid)[0])
    np.testing.assert_array_equal(counts3, _entries(grid)[1])
