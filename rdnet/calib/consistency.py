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

The same scores from sufficient statistics (for streams scored interval by interval,
:class:`rdnet.deblur.consistency.ConsistencyAccumulator`): :func:`moments` of the (dL, pred)
pairs of a set of pixel-intervals, :func:`merge_moments` over disjoint sets,
:func:`moment_scores`; equal to :func:`consistency` up to float summation order.
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


def interval_events(events: Events, ctx: FrameSeries, first: int = 0,
                    count: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(interval - ``first``, flat pixel, ON) of the ``events`` in the frame intervals
    ``first`` .. ``first + count - 1`` (default: all N-1 from the first); interval k is
    (t_k, t_{k+1}], events outside the chosen intervals are left out."""
    ft = ctx.frame_t
    count = len(ft) - 1 - first if count is None else count
    a = events.array
    k = np.searchsorted(ft, a["t"], side="left") - 1 - first      # (t_k, t_{k+1}] -> k
    ok = (k >= 0) & (k < count)
    pix = a["y"][ok].astype(np.int64) * ctx.width + a["x"][ok]
    return k[ok], pix, a["p"][ok].astype(bool)


def interval_counts(events: Events, ctx: FrameSeries) -> tuple[np.ndarray, np.ndarray]:
    """(N-1, P) ON and OFF counts of ``events`` between consecutive frames."""
    count = len(ctx.frame_t) - 1
    k, pix, on = interval_events(events, ctx)
    n = count * ctx.n_pixels
    key = k * ctx.n_pixels + pix
    n_on = np.bincount(key[on], minlength=n).reshape(count, -1)
    n_off = np.bincount(key[~on], minlength=n).reshape(count, -1)
    return n_on, n_off


def log_changes(ctx: FrameSeries) -> np.ndarray:
    """(N-1, P) float64 change of log intensity between consecutive frames."""
    lf = ctx.log_frames.reshape(len(ctx.frame_t), -1)
    return np.diff(lf, axis=0).astype(np.float64)


def inside_window(frame_t: np.ndarray, t0: int, t1: int) -> np.ndarray:
    """(N-1,) bool: the frame intervals inside the compared window [t0, t1)."""
    return (frame_t[:-1] >= t0) & (frame_t[1:] <= t1)


def changed(n_events: np.ndarray, dL: np.ndarray, threshold_on: float, threshold_off: float) -> np.ndarray:
    """bool, elementwise: a pixel-interval with at least one event (``n_events``, ON + OFF)
    or a log change ``dL`` of at least the smaller threshold."""
    return (n_events > 0) | (np.abs(dL) >= min(threshold_on, threshold_off))


def _active(n_on, n_off, dL, ctx: FrameSeries, threshold_on: float, threshold_off: float) -> np.ndarray:
    act = changed(n_on + n_off, dL, threshold_on, threshold_off)
    return act & inside_window(ctx.frame_t, ctx.t0, ctx.t1)[:, None]


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


#: the sufficient statistics :func:`moments` returns, in order (y = dL, x = pred)
MOMENTS = ("n", "sum_y", "sum_yy", "sum_x", "sum_xx", "sum_xy", "min_x", "max_x", "min_y", "max_y")


def moments(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(10,) float64 sufficient statistics (:data:`MOMENTS`) of the pairs (``y`` = dL,
    ``x`` = pred) of a set of pixel-intervals: their number, the sums of y, y^2, x, x^2,
    xy, and the extremes of x and y (+-inf when empty; they decide "no variation" exactly)."""
    y, x = np.asarray(y, np.float64), np.asarray(x, np.float64)
    if y.size == 0:
        return np.array([0.0] * 6 + [np.inf, -np.inf, np.inf, -np.inf])
    return np.array([y.size, y.sum(), (y * y).sum(), x.sum(), (x * x).sum(), (x * y).sum(),
                     x.min(), x.max(), y.min(), y.max()])


def merge_moments(m: np.ndarray) -> np.ndarray:
    """The :func:`moments` of the union of disjoint sets from theirs, (..., 10) -> (10,)."""
    m = np.asarray(m, np.float64).reshape(-1, len(MOMENTS))
    return np.r_[m[:, :6].sum(axis=0), m[:, 6].min(initial=np.inf), m[:, 7].max(initial=-np.inf),
                 m[:, 8].min(initial=np.inf), m[:, 9].max(initial=-np.inf)]


def moment_scores(m: np.ndarray, gain: float = 1.0) -> dict:
    """:func:`consistency`'s ``{"r2", "correlation", "active", "slope"}`` from the
    :func:`moments` of the scored pixel-intervals, with pred scaled by ``gain`` (= the
    measure at thresholds x gain): ``r2 = 1 - sum (y - g x)^2 / sum (y - mean y)^2`` with
    ``sum (y - g x)^2 = Syy - 2 g Sxy + g^2 Sxx``; Pearson correlation from the centred sums;
    ``slope = sum g x y / sum (g x)^2``. The same NaN rules: fewer than 3 pairs, y (for r2)
    or x or y (correlation) constant, sum x^2 = 0 (slope)."""
    n, sy, syy, sx, sxx, sxy, xmin, xmax, ymin, ymax = (float(v) for v in m)
    sx, sxx, sxy = gain * sx, gain * gain * sxx, gain * sxy
    out = {"active": int(n), "r2": float("nan"), "correlation": float("nan"), "slope": float("nan")}
    if n < 3:
        return out
    ss = syy - sy * sy / n
    if ymax > ymin and ss > 0:
        out["r2"] = 1.0 - (syy - 2.0 * sxy + sxx) / ss
        vx = sxx - sx * sx / n
        if xmax > xmin and gain != 0 and vx > 0:
            out["correlation"] = float(np.clip((sxy - sx * sy / n) / np.sqrt(vx * ss), -1.0, 1.0))
    if sxx > 0:
        out["slope"] = sxy / sxx
    return out


def _shift_sums(events: Events, ctx: FrameSeries, shifts: np.ndarray, flat: np.ndarray, kid: np.ndarray,
                y: np.ndarray, n_int: int) -> np.ndarray:
    """(S, K, 5) per shift and frame interval: the sums x, x^2, x y, y, y^2 over the
    pixel-intervals ``flat`` (flat index k * P + pixel, interval ``kid``, log change ``y``),
    x = ON - OFF count of the events shifted earlier by each of ``shifts`` (increasing).

    The first shift is counted in full; every later one by a sweep: an event moves from
    interval b to b - 1 at the first shift s with ``t - s <= t_b`` (the frame boundary it
    crosses), so only the pixel-intervals that events enter or leave at a step change, and
    the sums of x and x^2 are updated there (x is a whole count: exact). The sum of x y is
    summed again per shift, in the same order as a fresh count, so every sum equals the
    fresh count's bit for bit. A scan then costs about one full count plus the crossings and
    one weighted sum per shift, instead of one full count per shift."""
    a = events.array
    t = a["t"].astype(np.float64)
    pix = a["y"].astype(np.int64) * ctx.width + a["x"]
    sign = np.where(a["p"].astype(bool), 1.0, -1.0)
    P = ctx.n_pixels
    ft = np.asarray(ctx.frame_t)
    slot = np.full(n_int * P, -1, np.int64)                     # pixel-interval -> index in flat
    slot[flat] = np.arange(flat.size)

    def slots_of(k: np.ndarray, p: np.ndarray) -> np.ndarray:
        """index in flat of interval k at pixel p (-1: outside the intervals or the set)."""
        ok = (k >= 0) & (k < n_int)
        return np.where(ok, slot[np.where(ok, k, 0) * P + p], -1)

    out = np.empty((len(shifts), n_int, 5))
    out[:, :, 3:] = np.stack([np.bincount(kid, weights=w, minlength=n_int) for w in (y, y * y)], 1)
    idx = slots_of(np.searchsorted(ft, t - float(shifts[0]), side="left") - 1, pix)   # (t_k, t_{k+1}] -> k
    keep = idx >= 0
    x = np.bincount(idx[keep], weights=sign[keep], minlength=flat.size)
    sums = np.stack([np.bincount(kid, weights=w, minlength=n_int) for w in (x, x * x, x * y)], 1)
    out[0, :, :3] = sums
    if len(shifts) == 1:
        return out
    # the crossings: event e leaves interval b for b - 1 at the first grid shift s_i >= t_e - t_b,
    # for the boundaries b with shifts[0] < t_e - t_b <= shifts[-1]
    lo = np.searchsorted(ft, t - float(shifts[-1]), side="left")
    hi = np.searchsorted(ft, t - float(shifts[0]), side="left")
    n_cross = hi - lo
    ev = np.repeat(np.arange(t.size), n_cross)
    b = np.repeat(lo - np.cumsum(n_cross) + n_cross, n_cross) + np.arange(ev.size)
    step = np.searchsorted(shifts, t[ev] - ft[b], side="left")
    # the grid index whose own test ``t - s <= t_b`` first holds (float rounding of t - s)
    step = np.clip(step, 1, len(shifts) - 1)
    step -= (step > 1) & (t[ev] - shifts[np.maximum(step - 1, 0)] <= ft[b])
    step += (step < len(shifts) - 1) & ~(t[ev] - shifts[step] <= ft[b])
    leave, enter = slots_of(b, pix[ev]), slots_of(b - 1, pix[ev])
    # one row per (step, slot, signed count): the leaving event counts -sign, the entering +sign
    st = np.concatenate([step[leave >= 0], step[enter >= 0]])
    sl = np.concatenate([leave[leave >= 0], enter[enter >= 0]])
    dv = np.concatenate([-sign[ev][leave >= 0], sign[ev][enter >= 0]])
    order = np.argsort(st, kind="stable")
    st, sl, dv = st[order], sl[order], dv[order]
    bounds = np.searchsorted(st, np.arange(len(shifts) + 1), side="left")
    for i in range(1, len(shifts)):
        j0, j1 = bounds[i], bounds[i + 1]
        if j1 > j0:
            touched, inv = np.unique(sl[j0:j1], return_inverse=True)
            d = np.bincount(inv, weights=dv[j0:j1], minlength=touched.size)
            old = x[touched]
            new = old + d
            x[touched] = new
            k = kid[touched]
            sums[:, 0] += np.bincount(k, weights=d, minlength=n_int)
            sums[:, 1] += np.bincount(k, weights=new * new - old * old, minlength=n_int)
            sums[:, 2] = np.bincount(kid, weights=x * y, minlength=n_int)
        out[i, :, :3] = sums
    return out


def _corr_of_sums(s: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Pearson correlation from summed (..., 5) x, x^2, xy, y, y^2 and counts ``n``."""
    sx, sxx, sxy, sy, syy = np.moveaxis(s, -1, 0)
    with np.errstate(invalid="ignore", divide="ignore"):     # no pixel-interval (n = 0): NaN
        vx, vy = sxx - sx * sx / n, syy - sy * sy / n
        return np.where((vx > 0) & (vy > 0), (sxy - sx * sy / n) / np.sqrt(vx * vy), np.nan)


def _peak(shifts: np.ndarray, curve: np.ndarray) -> float:
    """The shift of the curve's maximum, refined by the parabola through it and its two
    neighbours (the grid point itself at either end of the grid; NaN for an all-NaN curve)."""
    if not np.isfinite(curve).any():
        return float("nan")
    i = int(np.nanargmax(curve))
    if i == 0 or i == len(curve) - 1 or not np.isfinite(curve[i - 1:i + 2]).all():
        return float(shifts[i])
    a, b, c = curve[i - 1], curve[i], curve[i + 1]
    den = a - 2 * b + c
    off = 0.5 * (a - c) / den if den < 0 else 0.0
    return float(shifts[i] + np.clip(off, -0.5, 0.5) * (shifts[i + 1] - shifts[i]))


def latency_scan(events: Events, ctx: FrameSeries, *, max_shift_us: float, step_us: float,
                 min_change: float, rng: np.random.Generator, resamples: int = 200) -> dict:
    """A sensor latency read off the recording alone, with no simulator and no frame
    interpolation: the constant time shift that, undone, makes the events between two
    frames explain the change of log intensity between them best.

    For every shift L on the grid ``-max_shift_us .. max_shift_us`` (step ``step_us``) the
    events are moved earlier by L and counted per frame interval; the score is the Pearson
    correlation, over the pixel-intervals inside the compared window whose log change is at
    least ``min_change`` (a frame-only set, the same for every shift), of the net count
    ON - OFF with the log change (threshold-free when the ON and OFF thresholds are equal).
    The estimate is the shift of the highest score (parabola through the best grid point and
    its neighbours); its spread comes from ``resamples`` bootstrap draws of the frame
    intervals (with replacement, from ``rng``). Returns ``{"shifts_us", "correlation",
    "latency_us", "ci95_us", "bootstrap_std_us", "intervals", "pixel_intervals",
    "at_edge"}`` (``at_edge``: the peak sits at the end of the grid, so the latency may lie
    beyond it)."""
    if step_us <= 0 or max_shift_us < step_us:
        raise ValueError("latency_scan: need 0 < step_us <= max_shift_us")
    n_int = len(ctx.frame_t) - 1
    dL = log_changes(ctx)
    mask = (np.abs(dL) >= float(min_change)) & inside_window(ctx.frame_t, ctx.t0, ctx.t1)[:, None]
    flat = np.flatnonzero(mask)
    kid = flat // ctx.n_pixels
    y = dL.ravel()[flat]
    n_steps = int(np.floor(max_shift_us / step_us + 1e-9))
    shifts = step_us * np.arange(-n_steps, n_steps + 1, dtype=np.float64)
    sums = _shift_sums(events, ctx, shifts, flat, kid, y, n_int)                 # (S, K, 5)
    per_int = np.bincount(kid, minlength=n_int).astype(np.float64)
    curve = _corr_of_sums(sums.sum(1), per_int.sum())
    est = _peak(shifts, curve)
    used = np.flatnonzero(per_int > 0)
    boot = np.full(resamples, np.nan)
    if used.size >= 2 and resamples > 0:
        draws = rng.multinomial(used.size, np.full(used.size, 1.0 / used.size), size=resamples).astype(np.float64)
        s_b = np.einsum("bk,skm->bsm", draws, sums[:, used])                       # (B, S, 5)
        n_b = draws @ per_int[used]                                               # (B,)
        curves = _corr_of_sums(s_b, n_b[:, None])
        boot = np.array([_peak(shifts, c) for c in curves])
    ok = np.isfinite(boot)
    ci = [float(v) for v in np.quantile(boot[ok], [0.025, 0.975])] if ok.sum() >= 2 else [float("nan")] * 2
    return {"shifts_us": shifts.tolist(), "correlation": [float(v) for v in curve], "latency_us": est,
            "ci95_us": ci, "bootstrap_std_us": float(np.std(boot[ok], ddof=1)) if ok.sum() >= 2 else float("nan"),
            "resamples": int(resamples), "intervals": int(used.size), "pixel_intervals": int(flat.size),
            "min_change": float(min_change),
            "at_edge": bool(np.isfinite(est) and abs(est) >= shifts[-1] - 1e-9)}
