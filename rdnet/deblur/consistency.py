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
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from rdnet.calib.consistency import active_intervals, consistency
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
        t0, t1 = int(t[0]), int(t[-1])
        if len(events):
            t0, t1 = max(t0, int(events.t[0])), min(t1, int(events.t[-1]) + 1)
        log = np.log(frames.grey() + np.float32(log_eps)).astype(np.float32)
        return cls(width=frames.width, height=frames.height, frame_t=t, log_frames=log, t0=t0, t1=t1)

    @property
    def scored_intervals(self) -> int:
        return int(((self.frame_t[:-1] >= self.t0) & (self.frame_t[1:] <= self.t1)).sum())


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
        nominal = consistency(ev, frames, threshold_on, threshold_off, active=active)
        gain = nominal["slope"]
        fitted = nominal
        if np.isfinite(gain) and gain != 0:
            fitted = consistency(ev, frames, threshold_on * gain, threshold_off * gain, active=active)
        else:
            gain = float("nan")
        out[name] = {"r2_fitted": fitted["r2"], "threshold_on_fitted": threshold_on * gain,
                     "threshold_off_fitted": threshold_off * gain, "r2_nominal": nominal["r2"],
                     "correlation": nominal["correlation"], "slope": gain,
                     "active": nominal["active"], "events": len(ev)}
    return out
