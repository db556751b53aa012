"""LayerNorm2d's fused path for channels_last inputs outside autograd (inference on CPU,
rdnet.restore.learned.prepare_for_inference): the formula's values up to float rounding,
the layout kept; contiguous inputs and gradient-recording passes (training) unchanged."""
import torch
from _nets import perturbed_count_net

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
    torch.testing.assert_close(mu2, mu, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(logit2, logit, rtol=1e-5, atol=1e-5)
