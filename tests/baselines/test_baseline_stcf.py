import numpy as np
import pytest

from rdnet.baselines.stcf import stcf_filter, stcf_mask, stcf_voxel
from rdnet.errors import ValidationError
from rdnet.events import Events


def edge_plus_noise(seed=0, H=40, W=60, T=60000, n_noise=400):
    """A vertical edge sweeping left to right (every pixel fires once as it passes, with
    200 us jitter) plus uniformly random isolated noise events. Returns events, is_signal."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(W), np.arange(H))
    te = xs.ravel() * (T / W) + rng.uniform(0, 200, H * W)
    tn = rng.uniform(0, T, n_noise)
    t = np.concatenate([te, tn]).astype(np.int64)
    x = np.concatenate([xs.ravel(), rng.integers(0, W, n_noise)])
    y = np.concatenate([ys.ravel(), rng.integers(0, H, n_noise)])
    p = np.concatenate([np.ones(H * W), rng.integers(0, 2, n_noise)]).astype(np.uint8)
    sig = np.r_[np.ones(H * W, bool), np.zeros(n_noise, bool)]
    order = np.argsort(t, kind="stable")
    return Events.from_columns(t[order], x[order], y[order], p[order], W, H), sig[order]


def test_keeps_edge_removes_isolated_noise():
    ev, sig = edge_plus_noise()
    keep = stcf_mask(ev, tau_us=5000, k=2, radius=1)
    # measured: 99.2 % of edge events kept (the first column has no past support),
    # 6.8 % of noise kept (noise landing next to the edge)
    assert keep[sig].mean() > 0.95
    assert keep[~sig].mean() < 0.15
    out = stcf_filter(ev, tau_us=5000, k=2, radius=1)
    assert len(out) == keep.sum() and (out.width, out.height) == (ev.width, ev.height)
    np.testing.assert_array_equal(out.array, ev.array[keep])


def test_known_small_case():
    # three events in a row at adjacent pixels, then one far away and one too late
    t = [0, 10, 20, 30, 100_000]
    x = [5, 6, 7, 20, 8]
    y = [5, 5, 5, 20, 5]
    ev = Events.from_columns(t, x, y, [1, 1, 1, 1, 1], 32, 32)
    np.testing.assert_array_equal(stcf_mask(ev, 1000, k=1), [False, True, True, False, False])
    # k=2 with radius 1: the third event has only one neighbour (6,5); (5,5) is 2 px away
    np.testing.assert_array_equal(stcf_mask(ev, 1000, k=2), [False] * 5)
    np.testing.assert_array_equal(stcf_mask(ev, 1000, k=2, radius=2), [False, False, True, False, False])


def test_self_and_polarity_options():
    ev = Events.from_columns([0, 10, 20], [3, 3, 4], [3, 3, 3], [1, 1, 0], 8, 8)
    assert stcf_mask(ev, 100, k=1).tolist() == [False, False, True]
    assert stcf_mask(ev, 100, k=1, include_self=True).tolist() == [False, True, True]
    assert stcf_mask(ev, 100, k=1, same_polarity=True).tolist() == [False, False, False]


def test_voxel_variant():
    vox = np.zeros((4, 10, 10), np.float32)
    vox[1, 2, 2] = 1          # isolated
    vox[2, 5, 4:7] = [1, -1, 2]   # a short line: each has >= 1 neighbour
    vox[3, 5, 7] = 1          # continues the line one bin later
    out = stcf_voxel(vox, k=1, radius=1, window_bins=2)
    assert out[1, 2, 2] == 0
    np.testing.assert_array_equal(out[2, 5, 4:7], [1, -1, 2])
    assert out[3, 5, 7] == 1   # supported by (5,6) in the previous bin
    assert vox[1, 2, 2] == 1   # input untouched
    assert stcf_voxel(vox, k=1, window_bins=1)[3, 5, 7] == 0


def test_bad_parameters():
    ev, _ = edge_plus_noise(n_noise=10)
    with pytest.raises(ValidationError):
        stcf_filter(ev, tau_us=0)
    with pytest.raises(ValidationError):
        stcf_filter(ev, k=0)
    assert len(stcf_filter(Events.empty(4, 4))) == 0
