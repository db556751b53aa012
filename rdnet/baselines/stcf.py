"""Spatio-temporal correlation filtering of event noise.

* :func:`stcf_filter` -- the background-activity filter of Delbruck ("Frame-free dynamic
  digital vision", 2008) generalised to the spatio-temporal correlation filter (STCF) of
  Guo & Delbruck ("Low Cost and Latency Event Camera Background Activity Denoising",
  TPAMI 2022): an event is kept if at least ``k`` pixels of its (2r+1) x (2r+1)
  neighbourhood (itself excluded unless ``include_self``; optionally only events of the
  same polarity) fired within the last ``tau_us`` before it. Like the hardware filters it
  keeps one timestamp map (the last event time per pixel, per polarity when
  ``same_polarity``), updated by every event whether kept or not, so ``k`` counts distinct
  supporting pixels. Causal: only past events support an event. One pass over the
  events in a numba kernel (O(N (2r+1)^2)). Streaming: pass one :class:`StcfState` to
  successive calls on consecutive chunks of a stream and the result is exactly that of
  one call on the whole stream (the timestamp map is carried across chunks).
* :func:`stcf_voxel` -- the same idea on a voxel grid (for the study's pairs files, which
  store only voxels): a non-zero voxel is kept if at least ``k`` neighbouring pixels hold
  events in the same bin or the ``window_bins - 1`` previous bins. Vectorized with box
  sums over the occupancy.
"""
from __future__ import annotations

import numba
import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events


#: Timestamp of a pixel that never fired (far enough in the past for any ``tau``).
NEVER_US = np.iinfo(np.int64).min // 2


class StcfState:
    """The timestamp map of :func:`stcf_mask` carried between chunks of one stream:
    ``last`` (1 or 2 polarities, height, width) int64, the last event time per pixel."""

    def __init__(self, width: int, height: int, same_polarity: bool = False):
        self.width, self.height, self.same_polarity = int(width), int(height), bool(same_polarity)
        self.last = np.full((2 if same_polarity else 1, self.height, self.width), NEVER_US, np.int64)

    def check(self, events: Events, same_polarity: bool) -> None:
        if (events.width, events.height) != (self.width, self.height):
            raise ValidationError("state", f"state is for a {self.width}x{self.height} sensor, events are "
                                           f"{events.width}x{events.height}")
        if bool(same_polarity) != self.same_polarity:
            raise ValidationError("state", f"state made with same_polarity={self.same_polarity}")


@numba.njit(cache=True)
def _stcf_kernel(t, x, y, p, last, tau, k, radius, include_self, same_polarity):
    n = t.shape[0]
    height, width = last.shape[1], last.shape[2]
    keep = np.zeros(n, np.bool_)
    for i in range(n):
        ti, xi, yi = t[i], np.int64(x[i]), np.int64(y[i])
        c = np.int64(p[i]) if same_polarity else 0
        support = 0
        for yy in range(max(yi - radius, 0), min(yi + radius + 1, height)):
            for xx in range(max(xi - radius, 0), min(xi + radius + 1, width)):
                if not include_self and yy == yi and xx == xi:
                    continue
                if ti - last[c, yy, xx] <= tau:
                    support += 1
        keep[i] = support >= k
        last[c, yi, xi] = ti
    return keep


def _check(tau_us, k, radius):
    if tau_us <= 0:
        raise ValidationError("tau_us", f"must be > 0, got {tau_us}")
    if k < 1:
        raise ValidationError("k", f"must be >= 1, got {k}")
    if radius < 1:
        raise ValidationError("radius", f"must be >= 1, got {radius}")


def stcf_mask(events: Events, tau_us: int = 10000, k: int = 2, radius: int = 1, *,
              include_self: bool = False, same_polarity: bool = False,
              state: StcfState | None = None) -> np.ndarray:
    """Boolean keep-mask of :func:`stcf_filter` (one entry per event). ``state``: the
    timestamp map of the previous chunks of the same stream (updated in place); None
    starts from an empty map."""
    _check(tau_us, k, radius)
    if state is None:
        state = StcfState(events.width, events.height, same_polarity)
    else:
        state.check(events, same_polarity)
    if len(events) == 0:
        return np.zeros(0, bool)
    return _stcf_kernel(events.t, events.x, events.y, events.p, state.last,
                        np.int64(tau_us), int(k), int(radius), bool(include_self),
                        bool(same_polarity))


def stcf_filter(events: Events, tau_us: int = 10000, k: int = 2, radius: int = 1, *,
                include_self: bool = False, same_polarity: bool = False,
                state: StcfState | None = None) -> Events:
    """Events supported by at least ``k`` neighbours within ``tau_us`` (module docstring)."""
    return events.select(stcf_mask(events, tau_us, k, radius, include_self=include_self,
                                   same_polarity=same_polarity, state=state))


def _box_sum(a: np.ndarray, radius: int) -> np.ndarray:
    """Sum over the (2r+1)^2 window of the last two axes (zeros outside), via cumsums."""
    pad = [(0, 0)] * (a.ndim - 2) + [(radius + 1, radius), (radius + 1, radius)]
    c = np.pad(a, pad).cumsum(-2).cumsum(-1)
    w = 2 * radius + 1
    return c[..., w:, w:] - c[..., :-w, w:] - c[..., w:, :-w] + c[..., :-w, :-w]


def stcf_voxel(voxel: np.ndarray, k: int = 2, radius: int = 1, window_bins: int = 2, *,
               include_self: bool = False) -> np.ndarray:
    """Voxel-grid STCF: zero every voxel (B, H, W) whose pixel has fewer than ``k``
    neighbours with events in bins [b - window_bins + 1, b] (module docstring).
    Returns a new array; the input is not modified."""
    voxel = np.asarray(voxel)
    if voxel.ndim != 3:
        raise ValidationError("voxel", f"expected (bins, H, W), got shape {voxel.shape}")
    _check(1, k, radius)
    if window_bins < 1:
        raise ValidationError("window_bins", f"must be >= 1, got {window_bins}")
    occ = (voxel != 0).astype(np.int32)
    c = np.concatenate([np.zeros_like(occ[:1]), occ.cumsum(0)])
    B = occ.shape[0]
    lo = np.maximum(np.arange(B) - window_bins + 1, 0)
    recent = (c[np.arange(B) + 1] - c[lo]) > 0          # pixel fired in the window
    support = _box_sum(recent.astype(np.int32), radius)
    if not include_self:
        support = support - recent
    return np.where(support >= k, voxel, 0).astype(voxel.dtype, copy=False)
