"""numba kernels for the inference of the small stage networks on a CPU.

torch's CPU ``layer_norm`` pays a fixed cost per normalised row, which dominates when the
rows are as short as a tiny network's channel count: on a 346 x 260 frame (the DAVIS346
sensor) it takes about 2.4 ms for 8 channels and 0.46 ms for 16 on 2 cores, while the
whole 8-channel tensor can be read and written in about 0.1 ms. :func:`layer_norm_rows`
normalises the rows of a (rows, channels) float32 array in one pass per row, rows split
across numba's threads (times below). From 32 channels on
torch is as fast, so :class:`rdnet.nn.blocks.LayerNorm2d` uses the kernel below
:data:`rdnet.nn.blocks.NUMBA_NORM_MAX_CHANNELS` only (and only for channels_last CPU tensors outside autograd, i.e.
inference as :func:`rdnet.restore.learned.prepare_for_inference` sets it up).

The arithmetic is the formula of LayerNorm2d in float32: mean, then the mean squared
deviation from it, ``(x - mean) / sqrt(var + eps) * weight + bias``. The compiler may
reorder the channel sums and fuse multiply-adds (numba ``fastmath`` flags ``reassoc`` and
``contract`` only: no assumption about NaN or infinity), which vectorises a row's sums over
its 8 or 16 channels. Medians of 50 calls in three runs on this 2-core host (2026-11-26;
its speed varies from run to run): 0.32-0.56 ms instead of 0.51-0.78 ms in channel order
for the 8-channel 352 x 264 tensor, 0.12-0.20 ms instead of 0.28-0.29 ms for the 16-channel
one at half that size. The results differ from torch's (vectorised, Welford) and from a sum
in channel order by float rounding (below 1e-6 on unit-variance rows).

The first call in a process costs about 0.3-0.5 s (numba sets up its compiler and loads the
cached machine code; loading it on a background thread does not help, the work holds the
GIL). ``rdnet restore`` with the learned restorer gains it back after about 2 s of a
DAVIS346 recording (``benchmarks/bench_restore.py``); on shorter ones it is a net loss.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True, boundscheck=False, fastmath={'reassoc', 'contract'})
def _layer_norm_rows(x, weight, bias, eps, out):
    n, c = x.shape
    inv = np.float32(1.0) / np.float32(c)
    for i in prange(n):
        mu = np.float32(0.0)
        for k in range(c):
            mu += x[i, k]
        mu *= inv
        var = np.float32(0.0)
        for k in range(c):
            d = x[i, k] - mu
            var += d * d
        s = np.float32(1.0) / np.sqrt(var * inv + eps)
        for k in range(c):
            out[i, k] = (x[i, k] - mu) * s * weight[k] + bias[k]


def layer_norm_rows(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, eps: float,
                    out: np.ndarray | None = None) -> np.ndarray:
    """Layer norm of every row of the float32 array ``x`` (rows, channels) with the
    per-channel ``weight`` and ``bias``, written into ``out`` (a new array when None;
    it may not overlap ``x``). Returns ``out``."""
    if x.ndim != 2 or x.dtype != np.float32:
        raise ValueError(f"expected a 2-d float32 array, got {x.dtype} {x.shape}")
    c = x.shape[1]
    if weight.shape != (c,) or bias.shape != (c,):
        raise ValueError(f"weight {weight.shape} and bias {bias.shape} must be ({c},)")
    if out is None:
        out = np.empty_like(x)
    elif out.shape != x.shape or out.dtype != np.float32:
        raise ValueError(f"out {out.dtype} {out.shape} does not match x {x.dtype} {x.shape}")
    _layer_norm_rows(x, weight.astype(np.float32, copy=False), bias.astype(np.float32, copy=False),
                     np.float32(eps), out)
    return out


def concurrent_calls_safe() -> bool:
    """Whether :func:`layer_norm_rows` may run in several threads at once: numba's threading
    layer is not ``workqueue`` (which aborts the process on concurrent launches; omp and tbb
    take them). Loads the compiled kernel first (a tiny call), so concurrent first calls
    never compile or load it twice."""
    import numba
    one = np.zeros((1, 1), np.float32)
    layer_norm_rows(one, np.ones(1, np.float32), np.zeros(1, np.float32), 1e-6)
    return numba.threading_layer() != "workqueue"
