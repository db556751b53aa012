"""Sparse network inputs (rdnet.nn.sparse, rdnet.events.voxel.voxel_entries): a voxel grid
given by its non-zero entries, the intro conv computed from them, and RestoreNet's sparse
heads on such an input, each against the dense path."""
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from _nets import count_inputs, perturbed_count_net

from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.voxel import voxel_entries, voxel_grid
from rdnet.nn.sparse import SparseVoxels, sparse_conv2d


def _events(n=400, W=13, H=9, T=1000, seed=0):
    g = np.random.default_rng(seed)
    a = np.zeros(n, EVENT_DTYPE)
    a["t"] = np.sort(g.integers(0, T + 1, n))          # includes events at exactly t0 + T
    a["x"], a["y"], a["p"] = g.integers(0, W, n), g.integers(0, H, n), g.integers(0, 2, n)
    return Events(a, W, H)


@pytest.mark.parametrize("mode", ["hard", "bilinear"])
@pytest.mark.parametrize("polarity", ["signed", "split"])
def test_voxel_entries_are_the_grids_non_zero_entries(mode, polarity):
    ev = _events()
    grid = voxel_grid(ev, 5, 0, 1000, mode=mode, polarity=polarity)
    index, values, shape = voxel_entries(ev, 5, 0, 1000, mode=mode, polarity=polarity)
    assert shape == grid.shape and values.dtype == np.float32
    np.testing.assert_array_equal(index, np.flatnonzero(grid))      # increasing, zeros left out
    np.testing.assert_array_equal(values, grid.ravel()[index])      # the same float sums, bit for bit


def test_voxel_entries_known_values():
    a = np.zeros(4, EVENT_DTYPE)
    a["t"], a["x"], a["y"], a["p"] = [0, 10, 10, 99], [1, 1, 1, 0], [0, 0, 0, 1], [1, 1, 0, 0]
    ev = Events(a, 2, 2)
    # hard, 2 bins of 50 us, split: ON (x1, y0) twice in bin 0; OFF (x1, y0) in bin 0; OFF (x0, y1) in bin 1
    index, values, shape = voxel_entries(ev, 2, 0, 100, polarity="split")
    assert shape == (2, 2, 2, 2)
    np.testing.assert_array_equal(index, [1, 4 * 2 + 1, 4 * 3 + 2])
    np.testing.assert_array_equal(values, [2.0, 1.0, 1.0])
    # signed: ON and OFF of one voxel cancel to 1 there; nothing at a cancelled zero
    index, values, _ = voxel_entries(ev, 2, 0, 100)
    np.testing.assert_array_equal(index, [1, 4 + 2])
    np.testing.assert_array_equal(values, [1.0, -1.0])
    empty = voxel_entries(ev, 2, 200, 100)
    assert empty[0].size == 0 and empty[1].size == 0


def test_sparse_voxels_lookup_and_dense():
    x = SparseVoxels.of(np.array([1, 7, 20]), np.array([2.0, 1.0, 3.0]), (2, 1, 3, 4))
    assert x.shape == (2, 3, 4) and x.density == pytest.approx(3 / 24)
    c, y, xx = x.coords()
    np.testing.assert_array_equal(c, [0, 0, 1]) and np.testing.assert_array_equal(y, [0, 1, 2])
    np.testing.assert_array_equal(xx, [1, 3, 0])
    np.testing.assert_array_equal(x.at([0, 0, 1, 1], [0, 1, 2, 0], [1, 2, 0, 0]), [2.0, 0.0, 3.0, 0.0])
    d = x.dense()
    assert d.shape == (1, 2, 3, 4) and float(d.sum()) == 6.0 and float(d[0, 1, 2, 0]) == 3.0
    cl = SparseVoxels.of(x.index, x.values, x.shape, channels_last=True).dense()
    assert cl.is_contiguous(memory_format=torch.channels_last) and torch.equal(cl, d)
    assert SparseVoxels.of(np.zeros(0, np.int64), np.zeros(0), (2, 3, 4)).at([1], [2], [3]).tolist() == [0.0]


@pytest.mark.parametrize("channels_last", [False, True])
@pytest.mark.parametrize("k, bias", [(3, True), (1, True), (5, False)])
def test_sparse_conv2d_equals_the_dense_conv_of_the_padded_grid(channels_last, k, bias):
    g = torch.Generator().manual_seed(k)
    conv = torch.nn.Conv2d(6, 4, k, padding=k // 2, bias=bias)
    with torch.no_grad():
        conv.weight.copy_(torch.randn(conv.weight.shape, generator=g))
    rng = np.random.default_rng(1)
    C, H, W = 6, 11, 13
    index = np.sort(rng.choice(C * H * W, 60, replace=False))
    index = np.r_[0, index[(index > 0) & (index < C * H * W - 1)], C * H * W - 1]     # both corners
    x = SparseVoxels.of(index, rng.integers(1, 4, index.size), (C, H, W), channels_last)
    with torch.inference_mode():
        got = sparse_conv2d(x, conv, (16, 16))
        want = conv(F.pad(x.dense(), (0, 3, 0, 5)))
    assert got.shape == want.shape == (1, 4, 16, 16)
    assert got.is_contiguous(memory_format=torch.channels_last if channels_last else torch.contiguous_format)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)
    empty = SparseVoxels.of(np.zeros(0, np.int64), np.zeros(0), (C, H, W))
    with torch.inference_mode():
        torch.testing.assert_close(sparse_conv2d(empty, conv, (H, W)), conv(empty.dense()), rtol=1e-6, atol=1e-6)


def test_sparse_conv2d_refuses_what_it_does_not_compute():
    x = SparseVoxels.of(np.array([0]), np.array([1.0]), (2, 4, 4))
    for conv in (torch.nn.Conv2d(2, 3, 3, stride=2, padding=1), torch.nn.Conv2d(2, 3, 3, padding=0),
                 torch.nn.Conv2d(2, 3, 3, padding="same"), torch.nn.Conv2d(3, 3, 3, padding=1)):
        with pytest.raises(ValueError):
            sparse_conv2d(x, conv, (4, 4))
    with pytest.raises(ValueError):
        sparse_conv2d(x, torch.nn.Conv2d(2, 3, 3, padding=1), (3, 4))       # smaller than the grid


@pytest.mark.parametrize("channels_last", [False, True])
def test_sparse_heads_on_a_sparse_input_keep_the_dense_decision(channels_last):
    from rdnet.nn.decision import logit_threshold
    net = perturbed_count_net(5, 0.3)
    dense, img = count_inputs(0.1)
    flat = dense[0].numpy().ravel()
    index = np.flatnonzero(flat)
    x = SparseVoxels.of(index, flat[index], (6, 13, 19), channels_last)
    if channels_last:
        net.to(memory_format=torch.channels_last)
        dense, img = (t.contiguous(memory_format=torch.channels_last) for t in (dense, img))
    with torch.inference_mode():
        mu, logit = net(img, dense, return_heads=True)
        for t in (0.5, 0.2, 0.8):
            keep_d, mu_d = net.sparse_heads(img, dense, logit_threshold(t))
            keep_s, mu_s = net.sparse_heads(img, x, logit_threshold(t))
            assert 0 < int(keep_s.sum()) < keep_s.numel()
            assert torch.equal(keep_s, keep_d)
            b, c, y, xx = np.nonzero(keep_s.numpy())
            torch.testing.assert_close(mu_s(b, c, y, xx), mu[keep_d], rtol=1e-5, atol=1e-5)
            torch.testing.assert_close(mu_s(b, c, y, xx), mu_d(b, c, y, xx), rtol=1e-5, atol=1e-5)
    few = index < 4 * 13 * 19
    with pytest.raises(ValueError, match="expected 6 event channels, got 4"):
        net.sparse_heads(img, SparseVoxels.of(index[few], flat[index][few], (4, 13, 19)), 0.0)
