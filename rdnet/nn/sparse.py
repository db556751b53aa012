"""Sparse network inputs: a voxel grid given by its non-zero entries, and the first
convolution computed from those entries alone.

An event window of a real camera fills a tiny share of its voxel grid: a 40 ms window of
the DAVIS346 road recording holds about 1,300 events in 2 x 10 x 260 x 346 = 1.8 million
voxels (0.07 %). The dense path builds that grid, pads it to the network's size and runs
the event branch's intro 3x3 convolution over every voxel; :func:`sparse_conv2d` adds each
entry's weighted kernel into the output instead (bias everywhere, then one
``index_add_``), the same sums in another order, so equal to the dense convolution up to
float rounding. Only the first layer reads the grid; every later layer is dense as before.
:class:`rdnet.nn.models.RestoreNet` takes a :class:`SparseVoxels` in place of its counts
tensor in :meth:`~rdnet.nn.models.RestoreNet.sparse_heads`, and
:class:`rdnet.restore.learned.LearnedRestorer` passes one when a window is sparse enough
(:data:`SPARSE_MAX_DENSITY`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

#: A window whose share of non-zero voxels is at most this goes through the sparse path.
#: Measured on these 2 cores for the DAVIS346 size (20 x 260 x 346 voxels, 3x3 conv to 8
#: channels, medians of 10 calls): sparse 0.8 / 2.5 / 6.3 / 15 ms at 0.07 / 0.3 / 1 / 3 %
#: non-zero, dense (grid, padding, conv) 4-12 ms whatever the density: the two meet near 0.5 %.
SPARSE_MAX_DENSITY = 0.005


@dataclass(frozen=True)
class SparseVoxels:
    """One (C, H, W) grid by its non-zero entries: ``index`` (int64 flat C-order positions,
    increasing) and ``values`` (float32), e.g. from :func:`rdnet.events.voxel.voxel_entries`
    (a per-polarity (2, bins, H, W) grid is read as 2 * bins channels)."""

    index: np.ndarray
    values: np.ndarray
    shape: tuple[int, int, int]
    #: the memory format of the tensors made from it (:meth:`dense`, :func:`sparse_conv2d`),
    #: the one a dense input would have had (channels_last: the CPU inference layout)
    channels_last: bool = False

    def __post_init__(self):
        if len(self.shape) != 3:
            raise ValueError(f"SparseVoxels.shape must be (C, H, W), got {self.shape}")
        if self.index.shape != self.values.shape or self.index.ndim != 1:
            raise ValueError(f"{self.index.shape} positions and {self.values.shape} values differ")

    @classmethod
    def of(cls, index: np.ndarray, values: np.ndarray, shape: tuple, channels_last: bool = False) -> "SparseVoxels":
        """From a grid's entries, any leading axes of ``shape`` folded into channels."""
        shape = tuple(int(s) for s in shape)
        return cls(np.asarray(index, np.int64), np.asarray(values, np.float32),
                   (int(np.prod(shape[:-2])), shape[-2], shape[-1]), bool(channels_last))

    @property
    def density(self) -> float:
        return self.index.size / max(int(np.prod(self.shape)), 1)

    def coords(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(c, y, x) of every entry."""
        _, H, W = self.shape
        return self.index // (H * W), (self.index // W) % H, self.index % W

    def at(self, c, y, x) -> np.ndarray:
        """The grid's values at the voxels (c, y, x) (index arrays): the entry's value, or 0."""
        _, H, W = self.shape
        flat = (np.asarray(c, np.int64) * H + np.asarray(y, np.int64)) * W + np.asarray(x, np.int64)
        pos = np.minimum(np.searchsorted(self.index, flat), max(self.index.size - 1, 0))
        hit = self.index[pos] == flat if self.index.size else np.zeros(flat.shape, bool)
        return np.where(hit, self.values[pos] if self.index.size else 0.0, 0.0).astype(np.float32)

    def dense(self, device="cpu") -> torch.Tensor:
        """The (1, C, H, W) float32 grid."""
        grid = np.zeros(int(np.prod(self.shape)), np.float32)
        grid[self.index] = self.values
        t = torch.from_numpy(grid.reshape(1, *self.shape)).to(device)
        return t.contiguous(memory_format=torch.channels_last) if self.channels_last else t


def sparse_conv2d(x: SparseVoxels, conv: torch.nn.Conv2d, out_hw: tuple[int, int]) -> torch.Tensor:
    """``conv`` (stride 1, no dilation, no groups, zero 'same' padding) applied to the grid
    ``x`` zero-padded at the bottom / right to ``out_hw``: (1, out_channels, *out_hw), equal
    to ``conv(F.pad(x.dense(), ...))`` up to the order of the float sums, in ``x``'s memory
    format."""
    C, H, W = x.shape
    Ho, Wo = (int(s) for s in out_hw)
    w = conv.weight                                        # (O, C, kh, kw)
    O, Cw, kh, kw = w.shape
    pad = conv.padding if isinstance(conv.padding, tuple) else (-1, -1)    # 'same' / 'valid' strings: refused
    ph, pw = pad
    if (conv.stride != (1, 1) or conv.dilation != (1, 1) or conv.groups != 1 or conv.padding_mode != "zeros"
            or (2 * ph, 2 * pw) != (kh - 1, kw - 1)):
        raise ValueError("sparse_conv2d needs a stride-1, undilated, ungrouped conv with zero 'same' padding")
    if Cw != C:
        raise ValueError(f"the conv reads {Cw} channels, the grid has {C}")
    if Ho < H or Wo < W:
        raise ValueError(f"output size {out_hw} is smaller than the grid's {(H, W)}")
    dev, taps = w.device, kh * kw
    bias = conv.bias if conv.bias is not None else torch.zeros(O, device=dev, dtype=w.dtype)
    out = torch.empty(Ho * Wo + 1, O, device=dev, dtype=w.dtype)    # rows = pixels (channels_last memory)
    out[:] = bias                                                   # + 1 row for the taps that fall outside
    if x.index.size:
        c, y, xx = (torch.from_numpy(a).to(dev) for a in x.coords())
        tap = torch.arange(taps, device=dev)
        # input (c, y, x) reaches output (y - ky + ph, x - kx + pw) through tap (ky, kx)
        i = y[:, None] - (tap // kw)[None] + ph
        j = xx[:, None] - (tap % kw)[None] + pw
        target = torch.where((i >= 0) & (i < Ho) & (j >= 0) & (j < Wo), i * Wo + j, Ho * Wo)
        table = w.permute(1, 2, 3, 0).reshape(C * taps, O)           # row (c, ky, kx): the O weights
        vals = torch.from_numpy(x.values).to(dev, w.dtype)
        contrib = table.index_select(0, (c[:, None] * taps + tap[None]).reshape(-1))
        contrib *= vals.repeat_interleave(taps)[:, None]
        out.index_add_(0, target.reshape(-1), contrib)
    out = out[:-1]
    y_cl = out.view(1, Ho, Wo, O).permute(0, 3, 1, 2)
    return y_cl if x.channels_last else y_cl.contiguous()
