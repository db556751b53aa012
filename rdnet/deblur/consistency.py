"""Event-frame consistency of raw and restored events: the no-ground-truth score of
``rdnet deblur``.

Between consecutive frames k and k+1 an ideal sensor's signed events explain the change
of log intensity: ``log I_{k+1} - log I_k ~= theta_on N_on - theta_off N_off`` per pixel
(the measure of :mod:`rdnet.calib.consistency`, reused here). Both event streams are
scored on the *same* pixel-intervals: those inside the compared window where either
stream has an event or the log intensity changes by at least the smaller nominal
threshold (``sensor`` section), so that removing or adding events cannot shrink or grow
the set being judged.

Headline score (``r2_fitted``): the R^2 of that model with the threshold scale fitted to
each stream by least squares (real sensors and restored events need not have the nominal
thresholds; the fitted value is reported as ``threshold_on_fitted``). 1 = the events explain
every change, 0 = no better than a constant; higher is better. Also reported: R^2 at the
nominal thresholds, the Pearson correlation, the number of scored pixel-intervals and of
events.

:func:`compare_consistency` scores whole streams (dense (N-1, P) arrays per stream);
:class:`ConsistencyAccumulator` gives the same numbers for streams fed window by window in
time order, holding count images only for the frame intervals still open (``rdnet
restore``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from rdnet.calib.consistency import (MOMENTS, active_intervals, changed, consistency, inside_window,
                                     interval_events, merge_moments, moment_scores, moments)
from rdnet.events.core import Events
from rdnet.events.recording import Frames

BETTER = "higher"
METRIC = ("r2_fitted: fraction of the variance of the change of log intensity between consecutive "
          "frames that threshold x signed event count explains, over the pixel-intervals where a "
          "stream has events or the intensity changed; threshold scale fitted per stream; "
          "1 = perfect, 0 = no better than a constant")


@dataclass(frozen=True)
class LogFrames:
    """Log intensity of a recording's frames, in the form the consistency measure reads
    (:class:`rdnet.calib.consistency.FrameSeries`): all pixels, window [t0, t1)."""

    width: int
    height: int
    frame_t: np.ndarray
    log_frames: np.ndarray
    t0: int
    t1: int

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

    @classmethod
    def of(cls, frames: Frames, events: Events, log_eps: float) -> "LogFrames":
        """Grey log frames; the window is where frames and ``events`` overlap."""
        t = frames.t_us.astype(np.int64)
        span = (int(events.t[0]), int(events.t[-1])) if len(events) else None
        t0, t1 = compared_window(t, span)
        return cls(width=frames.width, height=frames.height, frame_t=t,
                   log_frames=log_intensity(frames.grey(), log_eps), t0=t0, t1=t1)

    @property
    def scored_intervals(self) -> int:
        return int(inside_window(self.frame_t, self.t0, self.t1).sum())


def compared_window(frame_t: np.ndarray, span: tuple[int, int] | None) -> tuple[int, int]:
    """[t0, t1): where the frames (first to last time) and the events whose first and last
    times are ``span`` overlap (the frames' span when there are no events)."""
    t0, t1 = int(frame_t[0]), int(frame_t[-1])
    if span is not None:
        t0, t1 = max(t0, span[0]), min(t1, span[1] + 1)
    return t0, t1


def log_intensity(grey: np.ndarray, log_eps: float) -> np.ndarray:
    """float32 ``log(grey + log_eps)`` of linear grey frames (elementwise: a frame at a time
    gives the same values as all at once)."""
    return np.log(grey + np.float32(log_eps)).astype(np.float32)


def _stream_scores(nominal: dict, r2_at_gain: Callable[[float], float], threshold_on: float,
                   threshold_off: float, n_events: int) -> dict:
    """One stream's entry of :func:`compare_consistency` from its scores at the nominal
    thresholds (:func:`rdnet.calib.consistency.consistency` form) and the R^2 at the nominal
    thresholds x a gain; without a finite non-zero gain the fitted R^2 is the nominal one."""
    gain = nominal["slope"]
    if np.isfinite(gain) and gain != 0:
        r2_fitted = r2_at_gain(gain)
    else:
        gain, r2_fitted = float("nan"), nominal["r2"]
    return {"r2_fitted": r2_fitted, "threshold_on_fitted": threshold_on * gain,
            "threshold_off_fitted": threshold_off * gain, "r2_nominal": nominal["r2"],
            "correlation": nominal["correlation"], "slope": gain,
            "active": nominal["active"], "events": n_events}


def compare_consistency(frames: LogFrames, streams: Mapping[str, Events], threshold_on: float,
                        threshold_off: float) -> dict[str, dict]:
    """Per stream name: ``r2_fitted``, ``threshold_on_fitted``/``threshold_off_fitted``
    (nominal x the least-squares gain), ``r2_nominal``, ``correlation``, ``slope`` (the
    gain), ``active`` (pixel-intervals scored, the same for every stream) and ``events``.
    NaN where undefined (fewer than 3 intervals, no variation)."""
    active = None
    for ev in streams.values():
        a = active_intervals(ev, frames, threshold_on, threshold_off)
        active = a if active is None else active | a
    out = {}
    for name, ev in streams.items():
        def r2_at(gain, ev=ev):
            return consistency(ev, frames, threshold_on * gain, threshold_off * gain, active=active)["r2"]
        nominal = consistency(ev, frames, threshold_on, threshold_off, active=active)
        out[name] = _stream_scores(nominal, r2_at, threshold_on, threshold_off, len(ev))
    return out


class ConsistencyAccumulator:
    """:func:`compare_consistency` of the event streams ``names`` (the first one sets the
    compared window, as ``window_events`` of :meth:`LogFrames.of`), fed chunk by chunk with
    :meth:`add`; :meth:`scores` = the same dict, equal up to float summation order.

    Each stream's events come time-sorted in order; ``add(name, events, until)`` says that
    every event of that stream before ``until`` has now been given. The ON/OFF count images
    (streams x 2 x P) are kept only for the frame intervals still open (an event adds 1 to
    its pixel: the cost of a chunk follows its events, not the sensor size); interval k,
    (t_k, t_{k+1}], closes once every stream's ``until`` is past t_{k+1} and is then reduced
    to the :func:`~rdnet.calib.consistency.moments` of (dL, theta_on N_on - theta_off N_off)
    per stream over its active pixels (an event of any stream, or |dL| >= the smaller
    threshold). :meth:`scores` merges the intervals inside the compared window. Memory:
    the open intervals' counts plus 10 numbers per interval and stream; the log frames are
    computed one at a time from ``grey`` (default ``frames.grey()``)."""

    def __init__(self, frames: Frames, names: Sequence[str], threshold_on: float, threshold_off: float,
                 log_eps: float, *, grey: np.ndarray | None = None):
        self.frame_t = frames.t_us.astype(np.int64)
        self.width, self.height = frames.width, frames.height
        self.names = tuple(names)
        self.threshold_on, self.threshold_off, self.log_eps = float(threshold_on), float(threshold_off), log_eps
        self._grey = frames.grey() if grey is None else grey
        n_int = max(len(self.frame_t) - 1, 0)
        self._moments = np.zeros((n_int, len(self.names), len(MOMENTS)))   # closed intervals
        self._lo = 0                                    # first open interval ...
        # ... and the counts of the open ones an event reached, by interval: (stream, ON/OFF, pixel) flat
        self._rows: dict[int, np.ndarray] = {}
        self._until: dict[str, int | None] = dict.fromkeys(self.names)
        self._events = dict.fromkeys(self.names, 0)
        self._span: tuple[int, int] | None = None       # first and last time of the window stream
        self._log: dict[int, np.ndarray] = {}

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

    @property
    def open_intervals(self) -> int:
        """Frame intervals whose count images are held now (streams x 2 x P int64 each)."""
        return len(self._rows)

    def add(self, name: str, events: Events, until: int | None = None) -> None:
        """Feed stream ``name`` its next ``events``; ``until``: all its events before this
        time have been given (default: the last event's time)."""
        s = self.names.index(name)
        if len(events):
            t_lo, t_hi = int(events.t.min()), int(events.t.max())
            if self._until[name] is not None and t_lo < self._until[name]:
                raise ValueError(f"stream {name!r}: an event at {t_lo} us, before {self._until[name]} us "
                                 f"that an earlier add said was complete")
            self._events[name] += len(events)
            if s == 0:
                self._span = (t_lo if self._span is None else self._span[0], t_hi)
            k, pix, on = interval_events(events, self, self._lo, len(self._moments) - self._lo)
            if k.size:                                  # k: intervals counted from the first open one
                flat = (2 * s + ~on) * self.n_pixels + pix  # ON: 2s, OFF: 2s + 1
                size = len(self.names) * 2 * self.n_pixels
                for i in np.unique(k):                  # a row per interval, made when an event reaches it
                    row = self._rows.get(self._lo + int(i))
                    if row is None:
                        row = self._rows[self._lo + int(i)] = np.zeros(size, np.int64)
                    np.add.at(row, flat[k == i], 1)
            until = t_hi if until is None else until
        if until is not None:
            before = self._until[name]
            self._until[name] = int(until) if before is None else max(before, int(until))
        if any(u is None for u in self._until.values()):
            return
        done = int(np.searchsorted(self.frame_t[1:], min(self._until.values()), side="left"))
        for k in range(self._lo, done):                 # closed: t_{k+1} < every stream's until
            self._moments[k] = self._reduce(k, self._open_counts(k))
        for k in [k for k in self._rows if k < done]:
            del self._rows[k]
        self._lo = max(done, self._lo)

    def _open_counts(self, k: int) -> np.ndarray | None:
        """(streams, 2, P) counts of the open interval k; None when no event reached it yet."""
        row = self._rows.get(k)
        return None if row is None else row.reshape(len(self.names), 2, -1)

    def _log_frame(self, k: int) -> np.ndarray:
        """Flat log intensity of frame k (:meth:`_reduce` keeps the later frame of an interval
        for the next one)."""
        return self._log[k] if k in self._log else log_intensity(self._grey[k], self.log_eps).reshape(-1)

    def _reduce(self, k: int, counts: np.ndarray | None) -> np.ndarray:
        """(streams, 10) moments of interval k from its (streams, 2, P) ON/OFF counts
        (None: no event); empty where the window stream began after t_k (outside for sure)."""
        out = np.tile(moments([], []), (len(self.names), 1))
        if self._span is not None and self.frame_t[k] < self._span[0]:
            return out
        before, after = self._log_frame(k), self._log_frame(k + 1)
        self._log = {k + 1: after}
        dL = (after - before).astype(np.float64)
        if counts is None:
            counts = np.zeros((len(self.names), 2, self.n_pixels), np.int64)
        act = changed(counts.sum(axis=(0, 1)), dL, self.threshold_on, self.threshold_off)
        y, c = dL[act], counts[:, :, act]
        for s in range(len(self.names)):
            out[s] = moments(y, self.threshold_on * c[s, 0] - self.threshold_off * c[s, 1])
        return out

    def scores(self) -> dict[str, dict]:
        """:func:`compare_consistency` of the streams given so far ({} with fewer than 2
        frames); the intervals still open are reduced as they stand (nothing is closed)."""
        if len(self._moments) == 0:
            return {}
        t0, t1 = compared_window(self.frame_t, self._span)
        inside = inside_window(self.frame_t, t0, t1)
        m = self._moments.copy()
        for k in np.flatnonzero(inside[self._lo:]) + self._lo:      # open or not reached yet
            m[k] = self._reduce(k, self._open_counts(k))
        total = [merge_moments(m[inside, s]) for s in range(len(self.names))]
        out = {}
        for s, name in enumerate(self.names):
            out[name] = _stream_scores(moment_scores(total[s]), lambda g, s=s: moment_scores(total[s], g)["r2"],
                                       self.threshold_on, self.threshold_off, self._events[name])
        return out
