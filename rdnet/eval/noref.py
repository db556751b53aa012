"""No-reference scores of an event stream (real recordings have no ground truth).

* **ESR**, the event structural ratio of E-MLB (Ding, Chen, Yu, Huang, Zhang, Li,
  "E-MLB: Multilevel Benchmark for Event-Based Camera Denoising", IEEE TMM 2023), in the
  form of the authors' released code (cuke-emlb ``EventStructuralRatio``): the events of a
  packet (here a fixed time interval, E-MLB uses 33 ms) are accumulated into a count image
  n (polarity ignored), smoothed by a 3 x 3 median filter (zero outside), and with N the
  number of events of the packet and K = W H pixels::

      NTSS = sum_i n_i^2 / N^2                (concentration of the events on few pixels)
      L    = (K - sum_i 0.5^{n_i}) / K         (expected share of pixels hit when half the
                                                events are drawn: coverage)
      ESR  = 1000 sqrt(NTSS L)

  The paper's form ``NTSS = sum n_i (n_i - 1) / (N (N - 1))``,
  ``L_N = K - sum (1 - M / N)^{n_i}`` becomes this one for M = N / 2 and large N. Isolated
  noise events are removed by the median filter and spread N over many pixels, so they
  lower ESR; structure (edges firing repeatedly) raises it. :func:`esr_score` is the mean
  over the packets with at least 2 events (NaN when there are none);
  :class:`EsrAccumulator` computes it chunk by chunk on an absolute packet grid
  (multiples of the interval), so two streams of one recording share their packets.
* **Event-frame consistency** (recordings with frames): the measure of
  :mod:`rdnet.deblur.consistency` (built on :mod:`rdnet.calib.consistency`):
  ``compare_consistency`` for whole streams (``rdnet deblur``), the same numbers window by
  window with :class:`~rdnet.deblur.consistency.ConsistencyAccumulator` (``rdnet restore``).
* **Region fractions** (static-camera recordings): :func:`mask_fractions` -- the fraction of
  the raw events a restorer keeps inside each given pixel mask (e.g. the moving person,
  the background, known hot pixels). The masks come from the caller; :func:`activity_mask`
  derives a "where the scene moves" mask from the raw events themselves.
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events


def _each_once(idx: np.ndarray, scratch: np.ndarray) -> np.ndarray:
    """The distinct values of ``idx`` (flat indices, in no particular order) in O(len), no
    sort: each position writes its number into ``scratch`` (as long as the image) at its
    index; exactly one position per index then reads back its own number."""
    order = np.arange(idx.size, dtype=scratch.dtype)
    scratch[idx] = order
    return idx[scratch[idx] == order]


def _median3_sparse(padded: np.ndarray, nonzero: np.ndarray,
                    scratch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """3 x 3 median (zero outside) of an image given zero-bordered as ``padded`` (H + 2, W + 2),
    ``nonzero`` the distinct flat indices (into ``padded``) of its nonzero pixels. A median of
    9 values is nonzero only where >= 5 of them are, so only pixels within one pixel of a
    nonzero one are computed: returns (flat indices into ``padded``, their medians), every
    other pixel's median being 0. The median is the 5th smallest of the 9 values: exact, any
    dtype. ``scratch``: an int64 array of ``padded.size`` to reuse (else one is allocated)."""
    hp, wp = padded.shape
    offs = (np.arange(-1, 2)[:, None] * wp + np.arange(-1, 2)).ravel()      # 3 x 3, flat
    nonzero = np.asarray(nonzero, np.int64)
    if 9 * len(nonzero) < padded.size // 8:        # sparse (a packet): the neighbours, each once
        near = (nonzero[:, None] + offs).ravel()
        r, c = np.divmod(near, wp)
        near = near[(r >= 1) & (r <= hp - 2) & (c >= 1) & (c <= wp - 2)]     # inside the image
        cand = _each_once(near, np.empty(padded.size, np.int64) if scratch is None else scratch)
    else:                                          # dense (a whole recording): dilate a mask
        m = np.zeros(padded.size, bool)
        m[nonzero] = True
        m = m.reshape(hp, wp)
        near = np.zeros_like(m)
        for dy in range(3):                        # 9 shifted slices, not a per-pixel loop
            for dx in range(3):
                near[1:-1, 1:-1] |= m[dy:dy + hp - 2, dx:dx + wp - 2]
        cand = np.flatnonzero(near)
    vals = padded.ravel()[cand[:, None] + offs]
    return cand, np.partition(vals, 4, axis=1)[:, 4]


def _median3(img: np.ndarray) -> np.ndarray:
    """3 x 3 median filter of a 2-D image, zero outside (scipy ``median_filter(img, 3,
    mode="constant")``), through :func:`_median3_sparse`."""
    padded = np.pad(np.asarray(img), 1)
    out = np.zeros_like(padded)
    idx, med = _median3_sparse(padded, np.flatnonzero(padded))
    out.ravel()[idx] = med
    return out[1:-1, 1:-1]


def _esr_padded(padded: np.ndarray, nonzero: np.ndarray, n_events: int,
                scratch: np.ndarray | None = None) -> float:
    """ESR of a packet from its zero-bordered integer count image and the distinct flat
    indices of its nonzero pixels (see :func:`esr_packet`). Cost O(events), not O(pixels)."""
    if n_events < 2 or len(nonzero) == 0:
        return float("nan")
    K = (padded.shape[0] - 2) * (padded.shape[1] - 2)
    _, med = _median3_sparse(padded, nonzero, scratch)
    med = med[med > 0].astype(np.int64)
    ntss = float((med * med).sum()) / float(n_events) ** 2
    # miss = sum over all K pixels of 0.5^n: K - (nonzero medians) ones, plus a histogram of
    # the nonzero values summed exactly (math.fsum of h_v 2^-v: exact products, one rounding),
    # so equal to a dense float64 sum over the image whenever that one is exact (medians up to
    # ~30 on a megapixel sensor: the ESR of the committed real recordings is bit-identical)
    v, h = np.unique(med, return_counts=True)
    miss = math.fsum(np.r_[float(K - med.size), np.ldexp(h.astype(np.float64), -v)].tolist())
    cover = (K - miss) / K
    return 1000.0 * float(np.sqrt(ntss * cover))


def esr_packet(counts: np.ndarray, n_events: int) -> float:
    """ESR of one packet from its (H, W) integer count image and event number (module docstring)."""
    c = np.asarray(counts)
    ci = c.astype(np.int64)
    if not np.array_equal(ci, c):
        raise ValidationError("counts", "ESR needs integer event counts per pixel")
    padded = np.pad(ci, 1)
    return _esr_padded(padded, np.flatnonzero(padded), n_events)


class EsrAccumulator:
    """ESR over packets of ``interval_us`` on the absolute grid [k I, (k + 1) I), fed
    time-sorted chunks in order with :meth:`add`; :meth:`score` = mean over packets.
    The open packet's counts live in a zero-bordered image of which only the touched pixels
    are read and reset: the cost per packet follows its events, not the sensor size."""

    def __init__(self, width: int, height: int, interval_us: int = 33_000):
        self.width, self.height, self.interval = int(width), int(height), int(interval_us)
        self._k: int | None = None
        self._padded = np.zeros((self.height + 2, self.width + 2), np.int64)
        self._scratch = np.empty(self._padded.size, np.int64)
        self._touched: list[np.ndarray] = []
        self._n = 0
        self.values: list[float] = []

    def _open_value(self) -> float:
        nz = np.concatenate(self._touched) if self._touched else np.zeros(0, np.int64)
        nz = _each_once(nz, self._scratch) if len(self._touched) > 1 else nz
        self._touched = [nz]
        return _esr_padded(self._padded, nz, self._n, self._scratch)

    def _close(self) -> None:
        if self._n:
            v = self._open_value()
            if np.isfinite(v):
                self.values.append(v)
            self._padded.ravel()[self._touched[0]] = 0
        self._touched = []
        self._n = 0

    def add(self, events: Events) -> None:
        if len(events) == 0:
            return
        k = events.t // self.interval
        # flat index into the zero-bordered image
        pix = (events.y.astype(np.int64) + 1) * (self.width + 2) + events.x.astype(np.int64) + 1
        starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
        ends = np.r_[starts[1:], len(k)]
        flat = self._padded.ravel()
        for a, b in zip(starts, ends):               # one iteration per packet, not per event
            if self._k is not None and int(k[a]) != self._k:
                self._close()
            self._k = int(k[a])
            u, cnt = np.unique(pix[a:b], return_counts=True)
            flat[u] += cnt
            self._touched.append(u)
            self._n += int(b - a)

    def score(self) -> float:
        """Mean ESR over the packets so far (the open one included)."""
        vals = list(self.values)
        if self._n:
            v = self._open_value()
            if np.isfinite(v):
                vals.append(v)
        return float(np.mean(vals)) if vals else float("nan")


def esr_score(events: Events, interval_us: int = 33_000) -> float:
    """Mean ESR of ``events`` over packets of ``interval_us`` (module docstring)."""
    acc = EsrAccumulator(events.width, events.height, interval_us)
    acc.add(events)
    return acc.score()


def pixel_mask(width: int, height: int, coords: Sequence[Sequence[int]]) -> np.ndarray:
    """(H, W) bool mask of the given (x, y) pixels."""
    m = np.zeros((height, width), bool)
    c = np.asarray(coords, np.int64).reshape(-1, 2)
    if c.size:
        m[c[:, 1], c[:, 0]] = True
    return m


def mask_fractions(raw: Events, kept: Events, masks: Mapping[str, np.ndarray]) -> dict:
    """Per mask name: ``{"raw": raw events inside, "kept": restored events inside,
    "fraction": kept / raw}`` (fraction NaN when no raw event falls inside)."""
    out = {}
    for name, m in masks.items():
        m = np.asarray(m, bool)
        n_raw = int(m[raw.y, raw.x].sum())
        n_kept = int(m[kept.y, kept.x].sum())
        out[name] = {"raw": n_raw, "kept": n_kept, "fraction": n_kept / n_raw if n_raw else float("nan")}
    return out


#: the activity-mask settings ``restore_real`` scores with (and benchmarks that read its regions)
ACTIVITY_MASK = {"sigma_px": 4.0, "rel_threshold": 0.25, "quantile": 0.999}


def activity_mask(events: Events, sigma_px: float = ACTIVITY_MASK["sigma_px"],
                  rel_threshold: float = ACTIVITY_MASK["rel_threshold"],
                  quantile: float = ACTIVITY_MASK["quantile"]) -> np.ndarray:
    """(H, W) bool mask of where the scene moves, from the events themselves: the event
    count per pixel, 3 x 3 median-filtered (a lone hot pixel disappears: its neighbours
    are quiet), Gaussian-smoothed with ``sigma_px`` (an extended moving object stays
    dense), thresholded at ``rel_threshold`` times its ``quantile`` (a robust maximum)."""
    from scipy.ndimage import gaussian_filter
    counts = _median3(events.count_per_pixel().astype(np.float64))
    s = gaussian_filter(counts, sigma_px, mode="constant")
    top = float(np.quantile(s, quantile)) if s.size else 0.0
    return s >= rel_threshold * top if top > 0 else np.zeros_like(s, bool)
