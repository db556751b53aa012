"""NAFNet building blocks (Chen, Chu, Zhang, Sun, "Simple Baselines for Image
Restoration", ECCV 2022), the backbone family RDNet's stage networks are built from.

* :class:`LayerNorm2d` -- layer normalisation over the channel axis of an NCHW tensor
  (per pixel), NAFNet Sec. 3.2.
* :class:`SimpleGate` -- split the channels in two halves and multiply them (NAFNet Eq. 3).
* :class:`SimplifiedChannelAttention` -- global average pool + 1x1 conv, multiplied back
  (NAFNet Eq. 5).
* :class:`NAFBlock` -- the nonlinear-activation-free block: a depth-wise-conv branch and a
  feed-forward branch, each residual with a learnt per-channel scale (beta, gamma)
  initialised at zero so each block starts as the identity.
* :class:`Downsample` (2x2 stride-2 conv, doubles channels) and :class:`Upsample`
  (1x1 conv + PixelShuffle(2), halves channels), as in NAFNet's UNet.
* :func:`naf_stack` -- ``depth`` NAFBlocks of one width.

Parameter count of one NAFBlock of width ``c`` with the default expansions (2, 2):
``7 c^2 + 33 c``; :func:`nafblock_params` gives the general formula.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


#: LayerNorm2d's inference path uses the numba kernel :func:`rdnet.nn.cpu_kernels.layer_norm_rows`
#: below this channel count (torch's fused layer norm is as fast from 32 channels on).
NUMBA_NORM_MAX_CHANNELS = 32


class LayerNorm2d(nn.Module):
    """LayerNorm over channels of (B, C, H, W), with per-channel affine weight and bias.

    A channels_last input (the memory format of inference on CPU,
    :func:`rdnet.restore.learned.prepare_for_inference`) outside autograd is normalised
    over the last axis of its (B, H, W, C) view in one pass instead of eight elementwise
    ones: on a CPU float32 tensor of fewer than
    :data:`NUMBA_NORM_MAX_CHANNELS` channels by the numba kernel
    :func:`rdnet.nn.cpu_kernels.layer_norm_rows` (torch's ``layer_norm`` pays a fixed cost
    per row that dominates for 8-16 channels), otherwise by torch's fused ``layer_norm``.
    Either result equals the formula below up to float rounding. Contiguous inputs and
    every pass that records gradients -- all of training -- take the formula as written.
    """

    def __init__(self, channels: int, eps: float = 1e-6):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if _inference_layout(x):
            rows = x.permute(0, 2, 3, 1)                 # (B, H, W, C), contiguous
            if x.device.type == "cpu" and x.dtype == torch.float32 and x.shape[1] < NUMBA_NORM_MAX_CHANNELS:
                from rdnet.nn.cpu_kernels import layer_norm_rows    # lazy: numba for inference only
                y = torch.empty_like(x)                  # channels_last, as x
                c = x.shape[1]
                layer_norm_rows(rows.reshape(-1, c).numpy(), self.weight.detach().numpy(),
                                self.bias.detach().numpy(), self.eps,
                                out=y.permute(0, 2, 3, 1).reshape(-1, c).numpy())
                return y
            y = F.layer_norm(rows, (x.shape[1],), self.weight, self.bias, self.eps)
            return y.permute(0, 3, 1, 2)           # a channels_last (B, C, H, W) tensor again
        mu = x.mean(1, keepdim=True)
        var = (x - mu).pow(2).mean(1, keepdim=True)
        y = (x - mu) * torch.rsqrt(var + self.eps)
        return y * self.weight.view(1, -1, 1, 1) + self.bias.view(1, -1, 1, 1)


class SimpleGate(nn.Module):
    """x -> x[:, :C/2] * x[:, C/2:] (NAFNet Eq. 3); halves the channel count."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a, b = x.chunk(2, dim=1)
        return a * b


class SimplifiedChannelAttention(nn.Module):
    """x * Conv1x1(GlobalAvgPool(x)) (NAFNet Eq. 5)."""

    def __init__(self, channels: int):
        super().__init__()
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.conv = nn.Conv2d(channels, channels, 1, bias=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.conv(self.pool(x))


class NAFBlock(nn.Module):
    """NAFNet block (Fig. 3c of the NAFNet paper).

    ``x + beta * conv3(SCA(SG(dwconv(conv1(LN(x))))))`` followed by
    ``y + gamma * conv5(SG(conv4(LN(y))))``; beta and gamma start at 0.
    """

    def __init__(self, channels: int, dw_expand: int = 2, ffn_expand: int = 2):
        super().__init__()
        c = channels
        dw = c * dw_expand
        self.norm1 = LayerNorm2d(c)
        self.conv1 = nn.Conv2d(c, dw, 1)
        self.conv2 = nn.Conv2d(dw, dw, 3, padding=1, groups=dw)
        self.gate = SimpleGate()
        self.sca = SimplifiedChannelAttention(dw // 2)
        self.conv3 = nn.Conv2d(dw // 2, c, 1)
        ffn = c * ffn_expand
        self.norm2 = LayerNorm2d(c)
        self.conv4 = nn.Conv2d(c, ffn, 1)
        self.conv5 = nn.Conv2d(ffn // 2, c, 1)
        self.beta = nn.Parameter(torch.zeros(1, c, 1, 1))
        self.gamma = nn.Parameter(torch.zeros(1, c, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[0] == 1 and _inference_layout(x):
            return self._folded(x)
        y = self.conv1(self.norm1(x))
        y = self.gate(self.conv2(y))
        y = self.conv3(self.sca(y))
        x = x + y * self.beta
        y = self.conv5(self.gate(self.conv4(self.norm2(x))))
        return x + y * self.gamma

    def _folded(self, x: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` for one channels_last sample outside autograd (inference): the
        channel attention's scale and ``beta`` are folded into conv3's weights, ``gamma``
        into conv5's, which saves three elementwise passes over full-size maps. Equal to
        :meth:`forward` up to float rounding."""
        y = self.gate(self.conv2(self.conv1(self.norm1(x))))
        scale = self.sca.conv(self.sca.pool(y)).view(1, -1, 1, 1)          # (1, dw/2, 1, 1)
        beta, gamma = self.beta.view(-1, 1, 1, 1), self.gamma.view(-1, 1, 1, 1)
        x = x + F.conv2d(y, self.conv3.weight * scale * beta, self.conv3.bias * beta.view(-1))
        y = self.gate(self.conv4(self.norm2(x)))
        return x.add_(F.conv2d(y, self.conv5.weight * gamma, self.conv5.bias * gamma.view(-1)))


def _inference_layout(x: torch.Tensor) -> bool:
    """Whether ``x`` takes the inference paths of :class:`LayerNorm2d` and
    :class:`NAFBlock`: a 4-d channels_last (not contiguous) tensor outside autograd."""
    return (x.dim() == 4 and not torch.is_grad_enabled() and not x.is_contiguous()
            and x.is_contiguous(memory_format=torch.channels_last))


def nafblock_params(c: int, dw_expand: int = 2, ffn_expand: int = 2) -> int:
    """Analytic parameter count of :class:`NAFBlock` (``7 c^2 + 33 c`` for (2, 2))."""
    dw, ffn = c * dw_expand, c * ffn_expand
    return (2 * c            # norm1
            + c * dw + dw    # conv1
            + 9 * dw + dw    # conv2 (depth-wise 3x3)
            + (dw // 2) ** 2 + dw // 2   # sca
            + (dw // 2) * c + c          # conv3
            + 2 * c                      # norm2
            + c * ffn + ffn              # conv4
            + (ffn // 2) * c + c         # conv5
            + 2 * c)                     # beta, gamma


class Downsample(nn.Module):
    """2x2 convolution with stride 2: (B, C, H, W) -> (B, 2C, H/2, W/2)."""

    def __init__(self, channels: int):
        super().__init__()
        self.conv = nn.Conv2d(channels, 2 * channels, 2, stride=2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


class Upsample(nn.Module):
    """1x1 conv to 2C channels then PixelShuffle(2): (B, C, H, W) -> (B, C/2, 2H, 2W)."""

    def __init__(self, channels: int):
        super().__init__()
        if channels % 2:
            raise ValueError(f"Upsample needs an even channel count, got {channels}")
        self.conv = nn.Conv2d(channels, 2 * channels, 1, bias=False)
        self.shuffle = nn.PixelShuffle(2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.shuffle(self.conv(x))


def naf_stack(channels: int, depth: int) -> nn.Sequential:
    """``depth`` NAFBlocks of width ``channels`` (an identity when depth is 0)."""
    return nn.Sequential(*[NAFBlock(channels) for _ in range(depth)])
