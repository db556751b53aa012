"""Event-frame consistency: how well the signed events between two frames explain the
change of log intensity between them.

For consecutive frames k, k+1 and each pixel, the ideal DVS model (Lichtsteiner et al.
2008; the event-based double integral of Pan et al., CVPR 2019, Eq. 3) predicts
``log I_{k+1} - log I_k ~= theta_on * N_on - theta_off * N_off`` with ``N_on``/``N_off``
the event counts in (t_k, t_{k+1}]. Over the *active* pixel-intervals (at least one event
or a log change above the smaller threshold) we report the coefficient of determination
``R^2 = 1 - sum (dL - pred)^2 / sum (dL - mean dL)^2`` (depends on the thresholds) and the
Pearson correlation of ``pred`` and ``dL`` (threshold-free when ON = OFF).
"""
from __future__ import annotations

import numpy as np

from rdnet.calib.context import CalibContext
from rdnet.events.core import Events


def interval_counts(events: Events, ctx: CalibContext) -> tuple[np.ndarray, np.ndarray]:
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


def consistency(events: Events, ctx: CalibContext, threshold_on: float, threshold_off: float) -> dict:
    """``{"r2", "correlation", "active", "slope"}`` over the frame intervals inside the
    compared window (``slope``: least-squares gain of dL on pred, 1 = thresholds right)."""
    n_on, n_off = interval_counts(events, ctx)
    lf = ctx.log_frames.reshape(len(ctx.frame_t), -1)
    dL = np.diff(lf, axis=0).astype(np.float64)
    inside = (ctx.frame_t[:-1] >= ctx.t0) & (ctx.frame_t[1:] <= ctx.t1)
    pred = threshold_on * n_on - threshold_off * n_off
    act = ((n_on + n_off) > 0) | (np.abs(dL) >= min(threshold_on, threshold_off))
    act &= inside[:, None]
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
