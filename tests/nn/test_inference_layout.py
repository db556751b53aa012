"""The inference paths of the stage networks on a CPU (rdnet.restore.learned.prepare_for_inference:
channels_last, outside autograd): LayerNorm2d (numba kernel below 32 channels, torch's fused
layer norm above), NAFBlock with its scales folded into the 1x1 convs, and RestoreNet's sparse
heads. Each gives the formula's values up to float rounding (the sparse decision: the same voxels
exactly), the layout kept; contiguous inputs and gradient-recording passes (training) unchanged."""
import numpy as np
import pytest
import torch
from _nets import count_inputs, perturbed_count_net

from rdnet.nn.blocks import LayerNorm2d

torch.set_num_threads(1)


def _norm(seed=0, c=8):
    g = torch.Generator().manual_seed(seed)
    ln = LayerNorm2d(c)
    with torch.no_grad():
        ln.weight.copy_(torch.rand(c, generator=g) + 0.5)
        ln.bias.copy_(torch.randn(c, generator=g))
    return ln, 3.0 * torch.randn(2, c, 9, 11, generator=g) + 1.0


def _formula(ln, x):
    mu = x.mean(1, keepdim=True)
    var = (x - mu).pow(2).mean(1, keepdim=True)
    return (x - mu) * torch.rsqrt(var + ln.eps) * ln.weight.view(1, -1, 1, 1) + ln.bias.view(1, -1, 1, 1)


def test_layernorm_channels_last_inference_matches_the_formula():
    ln, x = _norm()
    xc = x.contiguous(memory_format=torch.channels_last)
    with torch.inference_mode():
        want = _formula(ln, x)
        assert torch.equal(ln(x), want)                                   # contiguous: the formula itself
        got = ln(xc)
    assert got.is_contiguous(memory_format=torch.channels_last) and got.shape == x.shape
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)
    with torch.no_grad():
        torch.testing.assert_close(ln(xc), want, rtol=1e-5, atol=1e-5)


def test_layernorm_with_gradients_takes_the_formula_whatever_the_layout():
    ln, x = _norm(1)
    xc = x.contiguous(memory_format=torch.channels_last).requires_grad_(True)
    y = ln(xc)
    assert torch.equal(y.detach(), _formula(ln, xc.detach()))            # bit for bit: the training path
    y.sum().backward()
    assert xc.grad is not None and ln.weight.grad is not None


def test_restore_net_heads_in_channels_last_agree_with_contiguous():
    net = perturbed_count_net(2, 0.3)
    g = torch.Generator().manual_seed(3)
    x = torch.poisson(torch.full((1, 6, 14, 18), 0.5), generator=g)
    img = torch.rand(1, 1, 14, 18, generator=g)
    with torch.inference_mode():
        mu, logit = net(img, x, return_heads=True)
        net.to(memory_format=torch.channels_last)
        cl = torch.channels_last
        mu2, logit2 = net(img.contiguous(memory_format=cl), x.contiguous(memory_format=cl), return_heads=True)
    # float rounding only: the inference path folds the channel attention and beta / gamma
    # into the 1x1 convs' weights (NAFBlock._folded), so sums run in another order
    torch.testing.assert_close(mu2, mu, rtol=1e-5, atol=5e-5)
    torch.testing.assert_close(logit2, logit, rtol=1e-5, atol=5e-5)


def test_layer_norm_rows_known_values_and_the_formula():
    from rdnet.nn.cpu_kernels import layer_norm_rows
    x = np.array([[1.0, -1.0, 1.0, -1.0], [5.0, 5.0, 5.0, 5.0], [0.0, 0.0, 0.0, 4.0]], np.float32)
    w = np.array([1.0, 2.0, 3.0, 4.0], np.float32)
    b = np.array([0.5, 0.0, 0.0, -1.0], np.float32)
    y = layer_norm_rows(x, w, b, 0.0)
    # row 0: mean 0, variance 1 -> x * w + b; row 1: constant, (x - mean) = 0 -> nan-free bias
    np.testing.assert_allclose(y[0], [1.5, -2.0, 3.0, -5.0], rtol=1e-6)
    y1 = layer_norm_rows(x[1:2], w, b, 1e-6)
    np.testing.assert_array_equal(y1[0], b)
    # row 2: mean 1, variance 3 -> (x - 1) / sqrt(3)
    np.testing.assert_allclose(y[2], (np.array([-1, -1, -1, 3]) / np.sqrt(3)) * w + b, rtol=1e-6)
    g = np.random.default_rng(0)
    z = (3 * g.standard_normal((257, 8)) + 1).astype(np.float32)
    want = torch.nn.functional.layer_norm(torch.from_numpy(z), (8,), torch.from_numpy(w.repeat(2)),
                                          torch.from_numpy(np.tile(b, 2)), 1e-6).numpy()
    np.testing.assert_allclose(layer_norm_rows(z, w.repeat(2), np.tile(b, 2), 1e-6), want, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError):
        layer_norm_rows(z.astype(np.float64), w, b, 1e-6)


@pytest.mark.parametrize("c", [8, 40])          # below NUMBA_NORM_MAX_CHANNELS: the numba kernel; above: torch's
def test_layernorm_channels_last_inference_both_kernels(c):
    ln, x = _norm(2, c)
    with torch.inference_mode():
        got = ln(x.contiguous(memory_format=torch.channels_last))
        want = _formula(ln, x)
    assert got.is_contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_nafblock_folded_inference_equals_the_block():
    from rdnet.nn.blocks import NAFBlock
    torch.manual_seed(4)
    blk = NAFBlock(8).eval()
    with torch.no_grad():
        for p in blk.parameters():
            p.add_(0.3 * torch.randn(p.shape))           # beta, gamma not zero: both branches count
    x = torch.randn(2, 8, 12, 10)
    with torch.inference_mode():
        want = blk(x)
        blk.to(memory_format=torch.channels_last)
        xc = x.contiguous(memory_format=torch.channels_last)
        one = blk(xc[:1])                                 # one sample: the folded path
        two = blk(xc)                                     # a batch: the block as written
    torch.testing.assert_close(one, want[:1], rtol=1e-5, atol=5e-5)
    torch.testing.assert_close(two, want, rtol=1e-5, atol=5e-5)
    assert torch.equal(xc, x.contiguous(memory_format=torch.channels_last))   # input not modified


@pytest.mark.parametrize("channels_last", [False, True])
def test_sparse_heads_keep_the_dense_decision_exactly(channels_last):
    from rdnet.nn.decision import decided_entries, decision_dict, logit_threshold, sparse_decided_entries
    net = perturbed_count_net(5, 0.3)
    x, img = count_inputs(0.4)
    if channels_last:
        net.to(memory_format=torch.channels_last)
        x, img = (t.contiguous(memory_format=torch.channels_last) for t in (x, img))
    with torch.inference_mode():
        mu, logit = net(img, x, return_heads=True)
        # thresholds at the median, at a quantile near the top and at a kept logit itself
        for t in (0.5, float(torch.sigmoid(logit.flatten().sort().values[-40])), 0.2):
            decision = decision_dict(t)
            keep, mu_at = net.sparse_heads(img, x, logit_threshold(t))
            assert torch.equal(keep, logit >= logit_threshold(t))
            want = decided_entries(mu, logit, decision)
            got = sparse_decided_entries(net, img, x, decision)
            assert 0 < want[0].size < logit.numel()
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
            b, c, y, xx = np.nonzero(keep.numpy())
            torch.testing.assert_close(mu_at(b, c, y, xx), mu[keep], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("offset", [4.0, -4.0, 0.25])
def test_offset_threshold_is_the_smallest_float32_passing(offset):
    from rdnet.nn.decision import offset_threshold
    d = np.float32(offset)
    # 4.0000005 with offset 4: about 4 million float32 o near 0 round to the same sum
    for t in (0.3, -0.4471, 3.99, 4.0000005, 4.0, 1e-8, -7.2, 1e30, -3e38):
        a = np.float32(offset_threshold(t, offset))
        assert np.float32(a + d) >= np.float32(t)
        assert np.float32(np.nextafter(a, np.float32(-np.inf)) + d) < np.float32(t)
    assert offset_threshold(float("-inf"), offset) == float("-inf")
    assert offset_threshold(float("inf"), offset) == float("inf")
