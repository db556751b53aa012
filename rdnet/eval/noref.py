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
  :mod:`rdnet.deblur.consistency` (built on :mod:`rdnet.calib.consistency`), reused by
  :func:`frame_consistency`.
* **Region fractions** (static-camera recordings): :func:`mask_fractions` -- the fraction of
  the raw events a restorer keeps inside each given pixel mask (e.g. the moving person,
  the background, known hot pixels). The masks come from the caller; :func:`activity_mask`
  derives a "where the scene moves" mask from the raw events themselves.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from rdnet.events.core import Events


def _median3(img: np.ndarray) -> np.ndarray:
    from scipy.ndimage import median_filter
    return median_filter(img, size=3, mode="constant", cval=0)


def esr_packet(counts: np.ndarray, n_events: int) -> float:
    """ESR of one packet from its (H, W) count image and event number (module docstring)."""
    if n_events < 2:
        return float("nan")
    c = np.asarray(counts, np.float64)
    K = c.size
    rows, cols = np.flatnonzero(c.any(1)), np.flatnonzero(c.any(0))
    if rows.size == 0:
        return float("nan")
    # the median is 0 farther than one pixel from any event: filter only that box
    r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, c.shape[0])
    c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, c.shape[1])
    pad = np.pad(c[r0:r1, c0:c1], 1)
    n = _median3(pad)[1:-1, 1:-1]
    ntss = float((n * n).sum()) / float(n_events) ** 2
    miss = float(np.power(0.5, n).sum()) + (K - n.size)        # 0.5^0 = 1 outside the box
    cover = (K - miss) / K
    return 1000.0 * float(np.sqrt(ntss * cover))


class EsrAccumulator:
    """ESR over packets of ``interval_us`` on the absolute grid [k I, (k + 1) I), fed
    time-sorted chunks in order with :meth:`add`; :meth:`score` = mean over packets."""

    def __init__(self, width: int, height: int, interval_us: int = 33_000):
        self.width, self.height, self.interval = int(width), int(height), int(interval_us)
        self._k: int | None = None
        self._counts = np.zeros(self.width * self.height, np.int64)
        self._n = 0
        self.values: list[float] = []

    def _close(self) -> None:
        if self._n:
            v = esr_packet(self._counts.reshape(self.height, self.width), self._n)
            if np.isfinite(v):
                self.values.append(v)
        self._counts[:] = 0
        self._n = 0

    def add(self, events: Events) -> None:
        if len(events) == 0:
            return
        k = events.t // self.interval
        pix = events.y.astype(np.int64) * self.width + events.x
        starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
        ends = np.r_[starts[1:], len(k)]
        for a, b in zip(starts, ends):               # one iteration per packet, not per event
            if self._k is not None and int(k[a]) != self._k:
                self._close()
            self._k = int(k[a])
            self._counts += np.bincount(pix[a:b], minlength=self._counts.size)
            self._n += int(b - a)

    def score(self) -> float:
        """Mean ESR over the packets so far (the open one included)."""
        vals = list(self.values)
        if self._n:
            v = esr_packet(self._counts.reshape(self.height, self.width), self._n)
            if np.isfinite(v):
                vals.append(v)
        return float(np.mean(vals)) if vals else float("nan")


def esr_score(events: Events, interval_us: int = 33_000) -> float:
    """Mean ESR of ``events`` over packets of ``interval_us`` (module docstring)."""
    acc = EsrAccumulator(events.width, events.height, interval_us)
    acc.add(events)
    return acc.score()


def frame_consistency(frames, streams: Mapping[str, Events], sensor, window_events: Events) -> dict:
    """Event-frame consistency of each stream (:func:`rdnet.deblur.consistency.compare_consistency`,
    scored on the same pixel-intervals) with the nominal thresholds and ``log_eps`` of the
    ``sensor`` settings; the window is where ``frames`` and ``window_events`` overlap."""
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    if frames is None or len(frames) < 2:
        return {}
    lf = LogFrames.of(frames, window_events, sensor.log_eps)
    return compare_consistency(lf, streams, sensor.threshold_on, sensor.threshold_off)


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


def activity_mask(events: Events, sigma_px: float = 4.0, rel_threshold: float = 0.25,
                  quantile: float = 0.999) -> np.ndarray:
    """(H, W) bool mask of where the scene moves, from the events themselves: the event
    count per pixel, 3 x 3 median-filtered (a lone hot pixel disappears: its neighbours
    are quiet), Gaussian-smoothed with ``sigma_px`` (an extended moving object stays
    dense), thresholded at ``rel_threshold`` times its ``quantile`` (a robust maximum)."""
    from scipy.ndimage import gaussian_filter
    counts = _median3(events.count_per_pixel().astype(np.float64))
    s = gaussian_filter(counts, sigma_px, mode="constant")
    top = float(np.quantile(s, quantile)) if s.size else 0.0
    return s >= rel_threshold * top if top > 0 else np.zeros_like(s, bool)
