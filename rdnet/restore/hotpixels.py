"""Hot pixels: pixels that fire far more often than their neighbours, whatever the scene.

A hot pixel (a leaky or stuck comparator) emits events at a high, steady rate that no
local filter can tell from structure for long: BAF and STCF let its events through as
soon as one neighbour fires, and a learned restorer sees a pixel full of events. What
gives it away is its count over a long stretch compared with its neighbours'. As
jAER's ``HotPixelFilter`` learns the busiest pixels during a learning period, rdnet
counts every pixel's events over the whole recording (one streamed pass) and flags a
pixel when

* its count exceeds ``factor`` x the median count of its neighbours on the sensor (8, or
  5 on an edge, 3 at a corner; at least 1), and
* its mean rate exceeds ``min_rate_hz``.

A moving edge lights up a pixel's neighbours as much as the pixel itself, so structure
is not flagged; a pixel 20x busier than the middle of its neighbourhood for a whole
recording is not explained by the scene. The flagged pixels' events are then dropped
before the chosen restorer runs (:func:`drop_pixels`). The pass needs the whole
recording before the first window, so it suits files, not a live stream.
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events


def pixel_counts(chunks: Iterable[Events], width: int, height: int) -> tuple[np.ndarray, int]:
    """``(counts (height, width) int64, duration_us)`` of a stream of event chunks."""
    counts, _, duration = polarity_counts(chunks, width, height)
    return counts, duration


def polarity_counts(chunks: Iterable[Events], width: int, height: int) -> tuple[np.ndarray, np.ndarray, int]:
    """``(counts, on_counts, duration_us)`` of a stream of event chunks: per pixel all
    events and the ON ones, each (height, width) int64."""
    counts = np.zeros(width * height, np.int64)
    on = np.zeros(width * height, np.int64)
    t_first = t_last = None
    for ev in chunks:
        if len(ev) == 0:
            continue
        flat = ev.y.astype(np.int64) * width + ev.x
        counts += np.bincount(flat, minlength=width * height)
        on += np.bincount(flat, weights=ev.p, minlength=width * height).astype(np.int64)
        t_first = int(ev.t[0]) if t_first is None else t_first
        t_last = int(ev.t[-1])
    duration = 0 if t_first is None else t_last - t_first
    return counts.reshape(height, width), on.reshape(height, width), duration


def polarity_model(counts: np.ndarray, on_counts: np.ndarray, mask: np.ndarray) -> dict:
    """What the flagged pixels ``mask`` tell about the simulator's hot-pixel polarity:
    ``on_fraction`` (ON share of their events) and, with two or more flagged pixels of two
    or more events, the ``degrade`` keys ``hot_pixel_on_fraction`` and
    ``hot_pixel_polarity_concentration`` fitted to them
    (:func:`rdnet.sim.effects.fit_hot_pixel_polarity`; ``"inf"`` when every pixel fires at one
    share), else None for both."""
    from rdnet.sim.effects import fit_hot_pixel_polarity
    n, on = np.asarray(counts)[mask], np.asarray(on_counts)[mask]
    out = {"on_fraction": float(on.sum() / n.sum()) if n.sum() else None,
           "hot_pixel_on_fraction": None, "hot_pixel_polarity_concentration": None}
    if int((n >= 2).sum()) >= 2:
        m, k = fit_hot_pixel_polarity(on, n)
        out.update(hot_pixel_on_fraction=m, hot_pixel_polarity_concentration=k if np.isfinite(k) else "inf")
    return out


def neighbour_median(counts: np.ndarray) -> np.ndarray:
    """Per pixel, the median of its neighbours' counts inside the sensor (8 inside, 5 on an
    edge, 3 at a corner); NaN for a pixel without neighbours (a 1 x 1 sensor)."""
    counts = np.asarray(counts)
    c = np.pad(counts.astype(np.float64), 1, constant_values=np.nan)
    h, w = counts.shape
    shifts = np.stack([c[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                       for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)])
    n = np.count_nonzero(~np.isnan(shifts), axis=0)
    # NaN (outside) sorts last: the median of the n inside values, without nanmedian's warnings
    srt = np.sort(shifts, axis=0)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[None], axis=0)[0]
    hi = np.take_along_axis(srt, np.maximum(n // 2, 0)[None], axis=0)[0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def hot_pixels(counts: np.ndarray, duration_us: int, factor: float, min_rate_hz: float) -> np.ndarray:
    """Boolean (height, width) map of hot pixels (module docstring); nothing is flagged
    when ``factor`` is 0 or the recording has no duration."""
    if factor < 0 or min_rate_hz < 0:
        raise ValidationError("hot_pixels", f"factor and min_rate_hz must be >= 0, got {factor}, {min_rate_hz}")
    counts = np.asarray(counts)
    if factor == 0 or duration_us <= 0:
        return np.zeros(counts.shape, bool)
    rate_hz = counts / (duration_us * 1e-6)
    med = np.nan_to_num(neighbour_median(counts), nan=np.inf)   # no neighbour: nothing to compare
    return (counts > factor * np.maximum(med, 1.0)) & (rate_hz > min_rate_hz)


def drop_pixels(events: Events, mask: np.ndarray) -> Events:
    """``events`` without those at the pixels where ``mask`` (height, width) is true."""
    if len(events) == 0 or not mask.any():
        return events
    keep = ~mask[events.y, events.x]
    return Events(events.array[keep], events.width, events.height, validate=False)
