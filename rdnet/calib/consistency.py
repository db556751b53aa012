"""Event-frame consistency: how well the signed events between two frames explain the
change of log intensity between them.

For consecutive frames k, k+1 and each pixel, the ideal DVS model (Lichtsteiner et al.
2008; the event-based double integral of Pan et al., CVPR 2019, Eq. 3) predicts
``log I_{k+1} - log I_k ~= theta_on * N_on - theta_off * N_off`` with ``N_on``/``N_off``
the event counts in (t_k, t_{k+1}]. Over the *active* pixel-intervals (at least one event
or a log change above the smaller threshold) we report the coefficient of determination
``R^2 = 1 - sum (dL - pred)^2 / sum (dL - mean dL)^2`` (depends on the thresholds) and the
Pearson correlation of ``pred`` and ``dL`` (threshold-free when ON = OFF).

The frames come from any object with the attributes of :class:`FrameSeries` (a
:class:`~rdnet.calib.context.CalibContext`, or the frames of ``rdnet deblur``). To compare
several event streams over the same pixel-intervals, pass one ``active`` mask to every
call (e.g. the union of their :func:`active_intervals`).
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

from rdnet.events.core import Events


class FrameSeries(Protocol):
    """What the measure reads of the frames: ``frame_t`` (N,) int64 us, ``log_frames``
    (N, H, W) log intensity, ``width`` and ``n_pixels`` of that grid, and the compared
    window [``t0``, ``t1``) (intervals outside it are left out)."""

    frame_t: np.ndarray
    log_frames: np.ndarray
    width: int
    t0: int
    t1: int

    @property
    def n_pixels(self) -> int: ...


def interval_counts(events: Events, ctx: FrameSeries) -> tuple[np.ndarray, np.ndarray]:
    """(N-1, P) ON and OFF counts of ``events`` between consecutive frames."""
    ft = ctx.frame_t
    a = events.array
    k = np.searchsorted(ft, a["t"], side="left") - 1      # (t_k, t_{k+1}] -> k
    ok = (k >= 0) & (k < len(ft) - 1)
    k = k[ok]
    pix = a["y"][ok].astype(np.int64) * ctx.width + a["x"][ok]
    on = a["p"][ok].astype(bool)
    n = (len(ft) - 1) * ctx.n_pixels
    key = k * ctx.n_pixels + pix
    n_on = np.bincount(key[on], minlength=n).reshape(len(ft) - 1, -1)
    n_off = np.bincount(key[~on], minlength=n).reshape(len(ft) - 1, -1)
    return n_on, n_off


def log_changes(ctx: FrameSeries) -> np.ndarray:
    """(N-1, P) float64 change of log intensity between consecutive frames."""
    lf = ctx.log_frames.reshape(len(ctx.frame_t), -1)
    return np.diff(lf, axis=0).astype(np.float64)


def _active(n_on, n_off, dL, ctx: FrameSeries, threshold_on: float, threshold_off: float) -> np.ndarray:
    inside = (ctx.frame_t[:-1] >= ctx.t0) & (ctx.frame_t[1:] <= ctx.t1)
    act = ((n_on + n_off) > 0) | (np.abs(dL) >= min(threshold_on, threshold_off))
    return act & inside[:, None]


def active_intervals(events: Events, ctx: FrameSeries, threshold_on: float, threshold_off: float) -> np.ndarray:
    """(N-1, P) bool: the pixel-intervals inside the compared window with at least one
    event or a log change of at least the smaller threshold."""
    n_on, n_off = interval_counts(events, ctx)
    return _active(n_on, n_off, log_changes(ctx), ctx, threshold_on, threshold_off)


def consistency(events: Events, ctx: FrameSeries, threshold_on: float, threshold_off: float,
                *, active: np.ndarray | None = None) -> dict:
    """``{"r2", "correlation", "active", "slope"}`` over the frame intervals inside the
    compared window (``slope``: least-squares gain of dL on pred, 1 = thresholds right).
    ``active``: the (N-1, P) pixel-intervals to score (default: :func:`active_intervals`)."""
    n_on, n_off = interval_counts(events, ctx)
    dL = log_changes(ctx)
    pred = threshold_on * n_on - threshold_off * n_off
    act = _active(n_on, n_off, dL, ctx, threshold_on, threshold_off) if active is None else active
    y, x = dL[act], pred[act]
    out = {"active": int(act.sum()), "r2": float("nan"), "correlation": float("nan"), "slope": float("nan")}
    if y.size < 3:
        return out
    ss = float(((y - y.mean()) ** 2).sum())
    if ss > 0:
        out["r2"] = float(1.0 - ((y - x) ** 2).sum() / ss)
    if x.std() > 0 and y.std() > 0:
        out["correlation"] = float(np.corrcoef(x, y)[0, 1])
    xx = float((x * x).sum())
    if xx > 0:
        out["slope"] = float((x * y).sum() / xx)
    return out
