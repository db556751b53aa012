"""Event statistics and the sim-to-real discrepancy.

An event stream is summarised per time segment (:func:`summarize`) into raw counts:
per-pixel counts (all / ON), counts per log-intensity bin (all / ON), the per-pixel
inter-event-interval histogram (log bins) and the event rate over time. Summing the
segments of a set (fit or held-out, :func:`aggregate`) gives the *statistics*; the
*discrepancy* between a simulated and the real stream is the weighted sum of the
normalised distances of :data:`STATISTICS` (:func:`distances`, :func:`discrepancy`).

The statistics were chosen so that each degradation of the vocabulary moves at least
one statistic the others leave alone (design notes in ``docs`` of :data:`STATISTICS`):

=======================  =====================================================  ==================
statistic                distance (normalisation)                               moved mainly by
=======================  =====================================================  ==================
rate_map                 L1 of coarse rate maps (mean rate per cell without     thresholds
                         its busiest pixel) / L1 of the real map
rate_vs_intensity        mean |log ratio| of rate per log-intensity bin         bandwidth (dark)
on_vs_intensity          mean |ON fraction diff| per bin / 0.1                  asymmetry, leak
on_fraction              |ON fraction diff| in moving pixels / 0.1              asymmetry
iei                      total variation of the log-binned inter-event           refractory, readout,
                         interval histograms / 0.1                               hot pixels, jitter
static_rate              |log ratio| of the static-pixel event rate (busiest    shot noise, leak
                         2 % of the static pixels left out)
static_on_fraction       |ON fraction diff| in static pixels beyond its         leak
                         binomial standard error (:func:`fraction_gap`) / 0.2
pixel_quantiles          mean |log ratio| of the mean per-pixel rate in         threshold mismatch
                         quantile bands (0-10-25-50-75-90-100 %) of moving px
pixel_tail               same for the top bands (90-95-98-99-99.5-99.8-100 %)  hot pixels
                         of the per-pixel net rate |ON - OFF| / T (a
                         scene moves a pixel's log intensity a bounded net
                         amount; a hot pixel of fixed polarity does not)
pixel_isolated           same for the top bands of the per-pixel isolated       hot pixels (their
                         rate max(0, n - max of its 8 neighbours' n) / T (a     own statistic
                         scene's edges and textures fire in neighbouring        only)
                         pixels too; a hot pixel fires alone, whatever its
                         polarity); weight 0
rate_time                L1 of rate over time / L1 of the real rate             jitter, bandwidth
lag                      |cross-correlation lag of sim vs real rate| / 1 ms     latency
lag_smoothed             |lag of the highest Pearson correlation of the rates   latency (its own
                         smoothed over 5 bins| / 1 ms; weight 0                 statistic only)
pixel_persistence        |covariance over moving pixels of log((n + 1) /        threshold mismatch
                         (m + 1)) between the two halves of the set's           (its own
                         segments, sim - real| / (0.01 + |real's|) (n a         statistic only)
                         pixel's events, m the declared config's mean over 4
                         reference seeds; the 2 % most extreme pixels left
                         out); weight 0
=======================  =====================================================  ==================

``pixel_persistence`` is what a per-pixel gain does that a scene does not: a pixel with a low
threshold fires more than the declared config expects in every part of the recording, so its
excess in one half of a segment set predicts its excess in the other. Scene content and count
noise are divided out by the reference (the declared config simulated with seeds
:data:`PERSIST_REF_SEEDS`, once per context, by :class:`rdnet.calib.fit.Objective`); a global
threshold change moves every pixel alike and is centred away. Any config that reproduces the
recording reproduces its persistence against the same reference, so it is compared like the
other statistics. It has weight 0: it moves no fit and is threshold mismatch's own statistic
for the signature gate and for naming by signature (:mod:`rdnet.calib.fit`). As a term of the
fit (weight 1, 2026-11-28) it lost more cases than it gained, because interpolation error, a
dark-pixel bandwidth limit, hot pixels and DAVIS346's latency persist too
(``benchmarks/results/calib_persistence.md``); as the signature it moves only where the
fitted mismatch explains it (docs/calibration.md, "Threshold mismatch's own statistic"). The
distance is relative to the recording's own persistence, so a recording whose persistence is
large for another reason (DAVIS346: 1.38 against 0.07 simulated) does not hit the cap.

``pixel_isolated`` counts hot pixels whatever their polarity. ``pixel_tail`` ranks pixels by
their net rate, which a pixel firing both polarities keeps only in part: simulated hot pixels
of one polarity each match a recording's tail of mixed-polarity ones with too few pixels (the
proof's ``hot_pixels_mixed_polarity`` cases: the fraction 26-43 % low). A pixel's excess over
the busiest of its neighbours does not depend on the polarity, and a scene's events come in
spatially connected structures (edges, texture), so it is near 0 everywhere but at isolated
pixels (hot pixels; a little shot noise). It has weight 0 and is hot pixels' own statistic:
their search adds its fit term (``Effect.fit_own``), and it is their signature. The
neighbours are those of the sampled grid (``calibrate.pixel_stride`` apart).

``lag_smoothed`` has weight 0: it moves no fit, and is latency's own statistic for the
signature gate only. The plain ``lag`` sums the products of the bins inside the fit (or
held-out) mask at each lag; the masks interleave, each lag step loses pairs at the runs'
ends and a broad peak is pulled towards 0 (``benchmarks/calib_lag_segments.py``).
Normalising each lag by its own pairs (Pearson) and smoothing the frame-period ripple away
does not have that pull, but as the fit's term it did worse in the proof; as the
signature it named one more latency and lost none (docs/calibration.md, "Why latency is
vetoed").

Log ratios use a floor (a fraction of the real mean rate) so empty bins do not blow up.
The metric is in the spirit of the event-statistics comparisons of v2e (Hu et al., CVPR-W
2021, Sec. 4) and ESIM/DVS-noise studies (Graca & Delbruck, 2021, shot and leak noise
rates; Guo et al. 2022, noise IEI distributions).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from rdnet.calib.context import CalibContext
from rdnet.events.core import Events

#: statistic name -> default weight in the discrepancy.
STATISTICS: dict[str, float] = {
    "rate_map": 1.0,
    "rate_vs_intensity": 1.0,
    "on_vs_intensity": 1.0,
    "on_fraction": 1.0,
    "iei": 1.0,
    "static_rate": 1.0,
    "static_on_fraction": 1.0,
    "pixel_quantiles": 1.0,
    "pixel_tail": 1.0,
    "rate_time": 1.0,
    "lag": 1.0,
    "lag_smoothed": 0.0,
    "pixel_persistence": 0.0,     # threshold mismatch's own statistic only (module docstring)
    "pixel_isolated": 0.0,        # hot pixels' own statistic only (module docstring)
}
#: floor of the persistence distance's denominator (a threshold_sigma of 0.1 gives a
#: persistence of about 0.01)
PERSIST_SCALE = 0.01
#: share of the most extreme pixels left out of the persistence (hot pixels)
PERSIST_TRIM = 0.02
#: seeds of the reference simulations
PERSIST_REF_SEEDS = (100, 101, 102, 103)

#: log10(us) edges of the inter-event-interval histogram: 1 us .. ~3 s, 4 bins per decade
IEI_EDGES = np.arange(0.0, 6.75, 0.25)
#: quantile bands of the per-pixel rate distributions (mean rate of the pixels in each band)
MOVING_BANDS = (0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0)
TAIL_BANDS = (0.9, 0.95, 0.98, 0.99, 0.995, 0.998, 1.0)
LAG_SCALE_US = 1000.0
#: bins the rates are smoothed over by :func:`pearson_lag_us` (one frame period of the
#: proof's 100 fps scenes at the 2 ms bins of ``calibrate.time_bin_us``)
LAG_SMOOTH_BINS = 5
#: fraction of the busiest static pixels left out of the static-noise statistics
STATIC_TRIM = 0.02



@dataclass(frozen=True)
class Summary:
    """Raw per-segment counts of one event stream (S = number of segments)."""

    pix: np.ndarray        # (S, P) events per pixel
    pix_on: np.ndarray     # (S, P) ON events per pixel
    ibin: np.ndarray       # (S, B) events per log-intensity bin
    ibin_on: np.ndarray    # (S, B)
    iei: np.ndarray        # (S, len(IEI_EDGES)+1) interval histogram (second event's segment)
    rate_t: np.ndarray     # (K,) events per time bin


def summarize(events: Events, ctx: CalibContext) -> Summary:
    """Per-segment raw counts of ``events`` (already on the context's pixel grid)."""
    a = events.array
    return summarize_arrays(a["t"], a["x"], a["y"], a["p"], ctx)


def summarize_arrays(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray,
                     ctx: CalibContext) -> Summary:
    """:func:`summarize` of event columns in any order (one O(n + pixels) numba pass:
    the per-pixel intervals are taken after grouping the events by pixel and sorting
    each pixel's times, so the events need not be time-sorted)."""
    S, P, B = len(ctx.segments), ctx.n_pixels, len(ctx.intensity_edges) - 1
    K = len(ctx.time_edges) - 1
    nI = len(IEI_EDGES) + 1
    ft = ctx.frame_t
    mids = (ft[:-1] + ft[1:]) // 2
    pix, pix_on, ibin, ibin_on, iei, rate_t = _summarize_kernel(
        np.ascontiguousarray(t, np.int64), np.ascontiguousarray(x), np.ascontiguousarray(y),
        np.ascontiguousarray(p), int(ctx.width), int(ctx.t0), int(ctx.t1),
        np.ascontiguousarray(ctx.segments[:, 1]), mids, ctx.frame_bin_by_pixel, np.int64(ctx.cfg.time_bin_us),
        iei_thresholds(),
        S, P, B, K, nI)
    return Summary(pix.reshape(S, P), pix_on.reshape(S, P), ibin.reshape(S, B), ibin_on.reshape(S, B),
                   iei.reshape(S, nI), rate_t)


@njit(cache=True, inline="always")
def _right(edges, v) -> int:
    """np.searchsorted(edges, v, side='right') for one value."""
    lo, hi = 0, edges.shape[0]
    while lo < hi:
        m = (lo + hi) >> 1
        if edges[m] <= v:
            lo = m + 1
        else:
            hi = m
    return lo


@njit(cache=True, nogil=True)
def _summarize_kernel(t, x, y, p, width, t0, t1, seg_end, mids, frame_bin, tb, iei_thr,
                      S, P, B, K, nI):
    # pass 1 (input order): events per pixel; pass 2: each pixel's times and polarities in
    # pixel order; pass 3 (pixel by pixel, so the per-pixel counts are written in order):
    # sort each pixel's times, then every count. iei_thr: iei_thresholds()
    pix = np.zeros(S * P, np.int64)
    pix_on = np.zeros(S * P, np.int64)
    ibin = np.zeros(S * B, np.int64)
    ibin_on = np.zeros(S * B, np.int64)
    iei = np.zeros(S * nI, np.int64)
    rate_t = np.zeros(K, np.int64)
    n = t.shape[0]
    start = np.zeros(P + 1, np.int32)
    for i in range(n):
        ti = t[i]
        if ti >= t0 and ti < t1:
            start[np.int64(y[i]) * width + np.int64(x[i]) + 1] += 1
    for q in range(P):
        start[q + 1] += start[q]
    fill = start[:P].copy()
    nm = mids.shape[0]
    m = start[P]
    tt = np.empty(m, np.int64)
    pp = np.empty(m, np.uint8)
    for i in range(n):
        ti = t[i]
        if ti >= t0 and ti < t1:
            q = np.int64(y[i]) * width + np.int64(x[i])
            j = fill[q]
            tt[j] = ti
            pp[j] = p[i]
            fill[q] = j + 1
    for q in range(P):
        a, e = start[q], start[q + 1]
        if e == a:
            continue
        for j in range(a + 1, e):        # insertion sort: each pixel's times are nearly sorted
            v = tt[j]
            w = pp[j]
            k = j - 1
            while k >= a and tt[k] > v:
                tt[k + 1] = tt[k]
                pp[k + 1] = pp[k]
                k -= 1
            tt[k + 1] = v
            pp[k + 1] = w
        # a pixel's times are sorted: its segment and nearest frame only move forward
        rs = _right(seg_end, tt[a])
        rf = _right(mids, tt[a])
        for j in range(a, e):
            ti = tt[j]
            while rs < S and seg_end[rs] <= ti:
                rs += 1
            while rf < nm and mids[rf] <= ti:
                rf += 1
            s = min(rs, S - 1)
            on = pp[j] != 0
            pix[s * P + q] += 1
            b = np.int64(frame_bin[q, rf])
            ibin[s * B + b] += 1
            if on:
                pix_on[s * P + q] += 1
                ibin_on[s * B + b] += 1
            kb = min((ti - t0) // tb, K - 1)       # the bins are tb wide, the last takes the rest
            rate_t[kb] += 1
            if j > a:
                dt = ti - tt[j - 1]
                if dt < 1:
                    dt = 1
                iei[s * nI + _right(iei_thr, dt)] += 1
    return pix, pix_on, ibin, ibin_on, iei, rate_t


@njit(cache=True)
def _iei_bin(dt) -> int:
    """Interval histogram bin of an integer interval ``dt`` >= 1 us, by its definition:
    ``np.searchsorted(IEI_EDGES, log10(dt), side='right')``."""
    return _right(IEI_EDGES, np.log10(np.float64(dt)))


@njit(cache=True)
def _iei_thresholds_kernel(edges):
    """See :func:`iei_thresholds` (here, so that log10 is the kernels' own)."""
    out = np.empty(edges.shape[0], np.int64)
    for j in range(edges.shape[0]):
        d = max(np.int64(1), np.int64(math.floor(10.0 ** edges[j])) - 2)
        while np.log10(np.float64(d)) < edges[j]:
            d += 1
        while d > 1 and np.log10(np.float64(d - 1)) >= edges[j]:
            d -= 1
        out[j] = d
    return out


@functools.lru_cache(maxsize=1)
def iei_thresholds() -> np.ndarray:
    """(len(IEI_EDGES),) int64: the least integer interval (us) whose log10 reaches each
    edge, computed with the summary kernel's own log10, so that
    ``searchsorted(thresholds, dt, 'right')`` is the bin of :func:`_iei_bin` for every
    integer ``dt`` >= 1 (log10 grows with dt) without a logarithm per interval (tested
    exhaustively up to beyond the last edge)."""
    return _iei_thresholds_kernel(IEI_EDGES)


def band_means(x: np.ndarray, bands, presorted: bool = False) -> np.ndarray:
    """Mean of the sorted values of ``x`` within each quantile band [b_i, b_i+1) (a
    smooth, seed-stable summary of a distribution; point quantiles of counts jump).
    ``presorted``: ``x`` is sorted already."""
    if x.size == 0:
        return np.zeros(len(bands) - 1)
    xs = x.ravel() if presorted else np.sort(x.ravel())
    idx = np.rint(np.asarray(bands) * xs.size).astype(np.int64)
    idx[1:] = np.maximum(idx[1:], idx[:-1] + 1)
    idx = np.minimum(idx, xs.size)
    c = np.concatenate([[0.0], np.cumsum(xs)])
    lo, hi = idx[:-1], idx[1:]
    lo = np.minimum(lo, xs.size - 1)
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)


def isolated_counts(n: np.ndarray) -> np.ndarray:
    """(H, W) counts (or rates) -> each pixel's excess over the largest of its (up to) 8
    neighbours, 0 where a neighbour has as many (the ``pixel_isolated`` statistic, module
    docstring; the hot-pixel mask of :mod:`rdnet.calib.fit`)."""
    h, w = n.shape
    p = np.zeros((h + 2, w + 2), n.dtype)      # counts are >= 0: a border has no larger neighbour
    p[1:-1, 1:-1] = n
    m = np.zeros_like(n)
    for dy in range(3):
        for dx in range(3):
            if dy != 1 or dx != 1:
                np.maximum(m, p[dy:dy + h, dx:dx + w], out=m)
    return np.maximum(n - m, 0)


def sorted_counts(n: np.ndarray) -> np.ndarray:
    """``np.sort`` of non-negative integer counts (1-D), by counting when they are small
    compared with their number (per-pixel event counts: mostly 0 and a few)."""
    if n.size and 0 <= n.min() and n.max() < 4 * n.size:
        h = np.bincount(n)
        return np.repeat(np.arange(h.size, dtype=n.dtype), h)
    return np.sort(n)


@dataclass(frozen=True)
class _Layout:
    """What :func:`aggregate` needs of a context besides the counts (computed once per
    context: the search evaluates hundreds of simulations on it)."""

    cell: np.ndarray        # (P,) rate-map cell of each pixel
    cell_n: np.ndarray      # pixels per cell
    grid: tuple             # (gh, gw) cells
    moving: np.ndarray      # (P,) bool
    static_idx: np.ndarray  # indices of the static pixels
    widths: np.ndarray      # (K,) seconds of the rate-over-time bins
    masks: dict             # segment tuple -> (K,) bool: the time bins of those segments


def _layout(ctx: CalibContext) -> _Layout:
    lay = ctx._cache.get("stats_layout")
    if lay is None:
        H, W, g = ctx.height, ctx.width, ctx.cfg.grid_px
        gh, gw = -(-H // g), -(-W // g)
        cell = ((np.arange(H)[:, None] // g) * gw + (np.arange(W)[None, :] // g)).ravel()
        static = ctx.static.ravel()
        st_idx = np.flatnonzero(static)
        lay = ctx._cache["stats_layout"] = _Layout(
            cell=cell, cell_n=np.bincount(cell, minlength=gh * gw), grid=(gh, gw), moving=~static,
            static_idx=st_idx,
            widths=np.diff(ctx.time_edges).astype(np.float64) * 1e-6, masks={})
    return lay


def aggregate(s: Summary, ctx: CalibContext, segs) -> dict[str, np.ndarray]:
    """Statistics of the segment set ``segs`` (rates in events per pixel per second)."""
    segs = list(segs)
    lay = _layout(ctx)
    T = ctx.segment_seconds(segs)
    pix = s.pix[segs].sum(0)
    pix_on = s.pix_on[segs].sum(0)
    moving = lay.moving
    rate_pix = pix / max(T, 1e-9)
    H, W = ctx.height, ctx.width
    gh, gw = lay.grid
    # each cell without its busiest pixel: hot pixels sit at random places, so where they
    # are is not comparable between a simulation and the recording (their number and
    # rate are, in pixel_tail)
    cell_max = np.zeros(gh * gw)
    np.maximum.at(cell_max, lay.cell, rate_pix)
    rate_map = ((np.bincount(lay.cell, weights=rate_pix, minlength=gh * gw) - cell_max)
                / np.maximum(lay.cell_n - 1, 1))
    occ = ctx.occupancy[segs].sum(0)
    ib = s.ibin[segs].sum(0).astype(np.float64)
    ib_on = s.ibin_on[segs].sum(0).astype(np.float64)
    n_mov = float(pix[moving].sum())
    # the noise-floor statistics leave out the busiest STATIC_TRIM of the static pixels, so
    # that they measure shot noise and leak, not where a few hot pixels happen to sit
    st_idx = lay.static_idx
    keep = st_idx[np.argsort(pix[st_idx], kind="stable")[: st_idx.size - int(np.ceil(STATIC_TRIM * st_idx.size))]]
    n_st = float(pix[keep].sum())
    n_st_on = float(pix_on[keep].sum())
    iei = s.iei[segs].sum(0).astype(np.float64)
    tmask = lay.masks.get(tuple(segs))
    if tmask is None:
        tmask = lay.masks[tuple(segs)] = np.isin(ctx.time_seg, segs)
        tmask.flags.writeable = False
    net_n = np.abs(2 * pix_on - pix)
    # the bands of rates k / T from the sorted counts k (dividing keeps the order)
    tail = band_means(sorted_counts(net_n) / max(T, 1e-9), TAIL_BANDS, presorted=True)
    quantiles = band_means(sorted_counts(pix[moving]) / max(T, 1e-9), MOVING_BANDS, presorted=True)
    isolated = band_means(sorted_counts(isolated_counts(pix.reshape(H, W)).ravel()) / max(T, 1e-9), TAIL_BANDS,
                          presorted=True)
    ref = ctx._cache.get("persistence_reference")
    persist = np.float64(np.nan) if ref is None or len(segs) < 2 else np.float64(
        _persistence(s.pix, ref, segs[0::2], segs[1::2], moving))
    return {
        "pixel_persistence": persist,
        "seconds": np.float64(T),
        "count": np.float64(pix.sum()),
        "rate": np.float64(pix.sum() / max(T, 1e-9) / ctx.n_pixels),
        "pixel_rate": rate_pix.reshape(H, W),
        "pixel_on_rate": pix_on.reshape(H, W) / max(T, 1e-9),
        "rate_map": rate_map.reshape(gh, gw),
        "occupancy": occ,
        "rate_vs_intensity": ib / np.maximum(occ, 1e-12),
        "intensity_count": ib,
        "on_vs_intensity": (ib_on + 1.0) / (ib + 2.0),
        "on_fraction": np.float64((pix_on[moving].sum() + 1.0) / (n_mov + 2.0)),
        "moving_count": np.float64(n_mov),
        "iei": iei / max(iei.sum(), 1.0),
        "iei_count": iei,
        "static_rate": np.float64(n_st / max(T, 1e-9) / max(keep.size, 1)),
        "static_count": np.float64(n_st),
        "static_on_fraction": np.float64((n_st_on + 1.0) / (n_st + 2.0)),
        "pixel_quantiles": quantiles,
        "pixel_tail": tail,
        "pixel_isolated": isolated,
        "rate_time": np.where(tmask, s.rate_t / lay.widths, 0.0),
        "time_mask": tmask,
    }


def _persistence(pix: np.ndarray, ref: np.ndarray, a_segs, b_segs, moving: np.ndarray) -> float:
    """Covariance over the moving pixels (reference count >= 3 in both halves, the
    PERSIST_TRIM most extreme left out) of log((n + 1) / (m + 1)) in the segments
    ``a_segs`` and in ``b_segs``: n a stream's counts, m the reference's (S, P)."""
    na, nb = pix[list(a_segs)].sum(0), pix[list(b_segs)].sum(0)
    ma, mb = ref[list(a_segs)].sum(0), ref[list(b_segs)].sum(0)
    ok = moving & (ma >= 3) & (mb >= 3)
    if ok.sum() < 20:
        return float("nan")
    a = np.log((na[ok] + 1.0) / (ma[ok] + 1.0))
    b = np.log((nb[ok] + 1.0) / (mb[ok] + 1.0))
    a, b = a - a.mean(), b - b.mean()
    e = np.abs(a) + np.abs(b)
    keep = e <= np.quantile(e, 1.0 - PERSIST_TRIM)
    a, b = a[keep], b[keep]
    return float(np.mean((a - a.mean()) * (b - b.mean())))


def _logratio(a, b, floor) -> np.ndarray:
    return np.abs(np.log((np.asarray(a, float) + floor) / (np.asarray(b, float) + floor)))


def xcorr_lag_us(sim: np.ndarray, real: np.ndarray, mask: np.ndarray, bin_us: float,
                 max_lag_us: float) -> float:
    """Lag (us) by which ``sim`` must be delayed to best match ``real``: the argmax of
    their normalised cross-correlation over the masked bins, refined by a parabola
    through the peak and its neighbours. Positive = real events come later."""
    a = np.where(mask, sim - sim[mask].mean() if mask.any() else 0.0, 0.0)
    b = np.where(mask, real - real[mask].mean() if mask.any() else 0.0, 0.0)
    if not a.any() or not b.any():      # also every series of one bin (nothing left after the mean)
        return 0.0
    L = int(min(len(a) - 1, max(1, round(max_lag_us / bin_us))))
    return peak_lag_us(_lagged_dots(a, b, L), np.arange(-L, L + 1), bin_us)


def _lagged_dots(a: np.ndarray, b: np.ndarray, L: int) -> np.ndarray:
    """``sum_i a[i] * b[i + k]`` for k = -L .. L: one matrix-vector product of the 2L + 1
    windows of ``b`` padded with L zeros at each end (only the lags asked for, where a full
    correlation would take all 2n - 1)."""
    n = len(a)
    padded = np.concatenate([np.zeros(L), np.asarray(b, np.float64), np.zeros(L)])
    return np.lib.stride_tricks.sliding_window_view(padded, n) @ np.asarray(a, np.float64)


def pearson_lag_curve(sim: np.ndarray, real: np.ndarray, mask: np.ndarray, bin_us: float,
                      max_lag_us: float, smooth_bins: int = LAG_SMOOTH_BINS
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Integer bin lags k = -L .. L (L = ``max_lag_us / bin_us``) and the Pearson correlation
    at each of ``sim`` delayed by k bins against ``real``: both rates first smoothed over
    ``smooth_bins`` bins inside ``mask`` (a box filter normalised by the masked bins it
    covers: the ripple at the frame period does not set the lag), each lag's coefficient
    over the bin pairs that are both inside ``mask`` (a lag that loses pairs at the mask's
    run ends is not penalised for it); -inf where a lag has no pairs or no variance. Empty
    arrays when the mask is empty or either rate constant inside it."""
    m = np.asarray(mask, bool)
    empty = np.zeros(0, np.int64), np.zeros(0)
    if not m.any():
        return empty
    w = max(min(int(smooth_bins), m.size), 1)       # np.convolve "same" is max(len) long
    k = np.ones(w) / w
    mf = m.astype(float)
    cover = np.maximum(np.convolve(mf, k, "same"), 1e-9)

    def smooth(x):
        return np.where(m, np.convolve(np.where(m, x, 0.0), k, "same") / cover, 0.0)
    s, r = smooth(np.asarray(sim, float)), smooth(np.asarray(real, float))
    a = np.where(m, s - s[m].mean(), 0.0)
    b = np.where(m, r - r[m].mean(), 0.0)
    if not a.any() or not b.any():
        return empty
    L = int(max(1, min(len(a) - 1, round(max_lag_us / bin_us))))
    den = np.sqrt(np.clip(_lagged_dots(a * a, mf, L), 0.0, None) * np.clip(_lagged_dots(mf, b * b, L), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(den > 0, _lagged_dots(a, b, L) / den, -np.inf)
    return np.arange(-L, L + 1), c


def pearson_lag_us(sim: np.ndarray, real: np.ndarray, mask: np.ndarray, bin_us: float,
                   max_lag_us: float, smooth_bins: int = LAG_SMOOTH_BINS) -> float:
    """Lag (us) by which ``sim`` must be delayed to best match ``real``: the peak of
    :func:`pearson_lag_curve`, refined as in :func:`xcorr_lag_us`; 0 where the curve is
    empty. Positive = real events come later."""
    lags, c = pearson_lag_curve(sim, real, mask, bin_us, max_lag_us, smooth_bins)
    return peak_lag_us(c, lags, bin_us) if lags.size else 0.0


def peak_lag_us(c: np.ndarray, lags: np.ndarray, bin_us: float) -> float:
    """The lag (us) of the peak of a cross-correlation ``c`` over integer bin ``lags``,
    refined by a parabola through the peak and its neighbours (when both are finite)."""
    i = int(np.argmax(c))
    frac = 0.0
    if 0 < i < len(c) - 1 and np.isfinite(c[i - 1]) and np.isfinite(c[i + 1]):
        den = c[i - 1] - 2 * c[i] + c[i + 1]
        if den < 0:
            frac = 0.5 * (c[i - 1] - c[i + 1]) / den
    return float((lags[i] + frac) * bin_us)


def fraction_gap(p_sim, p_real, n_sim, n_real):
    """|p_sim - p_real| of two fractions (ON fractions) beyond the standard error of their
    difference (binomial, from the event counts ``n_sim`` and ``n_real`` they were
    measured on; 0 when the difference lies within it): a difference that sampling alone
    makes is no evidence for either config."""
    p_sim, p_real = np.asarray(p_sim, np.float64), np.asarray(p_real, np.float64)
    p = 0.5 * (p_sim + p_real)
    se = np.sqrt(p * (1.0 - p) * (1.0 / (np.asarray(n_sim, np.float64) + 2.0)
                                  + 1.0 / (np.asarray(n_real, np.float64) + 2.0)))
    return np.maximum(np.abs(p_sim - p_real) - se, 0.0)


def distances(sim: dict, real: dict, ctx: CalibContext) -> dict[str, float]:
    """Normalised distance of every statistic in :data:`STATISTICS` (0 = identical)."""
    floor = 0.05 * max(float(real["rate"]), 1e-6)
    d: dict[str, float] = {}
    d["rate_map"] = float(np.abs(sim["rate_map"] - real["rate_map"]).sum()
                          / max(np.abs(real["rate_map"]).sum(), 1e-12))
    w = real["occupancy"] / max(real["occupancy"].sum(), 1e-12)
    d["rate_vs_intensity"] = float((w * _logratio(sim["rate_vs_intensity"], real["rate_vs_intensity"], floor)).sum())
    wc = real["intensity_count"] / max(real["intensity_count"].sum(), 1.0)
    d["on_vs_intensity"] = float((wc * np.abs(sim["on_vs_intensity"] - real["on_vs_intensity"])).sum() / 0.1)
    d["on_fraction"] = float(abs(sim["on_fraction"] - real["on_fraction"]) / 0.1
                             * min(1.0, real["moving_count"] / 100.0))
    d["iei"] = float(0.5 * np.abs(sim["iei"] - real["iei"]).sum() / 0.1)
    sfloor = 0.01 * floor + 1e-3
    d["static_rate"] = float(_logratio(sim["static_rate"], real["static_rate"], sfloor))
    # the static pixels' few events (about 800 per segment set in a proof scene) leave a
    # standard error of about 0.025 on the difference, half of what an `s1` leak moves it:
    # only the part beyond it counts (docs/calibration.md, "The static pixels' ON fraction")
    d["static_on_fraction"] = float(fraction_gap(sim["static_on_fraction"], real["static_on_fraction"],
                                                 sim["static_count"], real["static_count"]) / 0.2
                                    * min(1.0, real["static_count"] / 100.0))
    d["pixel_quantiles"] = float(_logratio(sim["pixel_quantiles"], real["pixel_quantiles"], floor).mean())
    d["pixel_tail"] = float(_logratio(sim["pixel_tail"], real["pixel_tail"], floor).mean())
    d["pixel_isolated"] = float(_logratio(sim["pixel_isolated"], real["pixel_isolated"], floor).mean())
    d["rate_time"] = float(np.abs(sim["rate_time"] - real["rate_time"]).sum()
                           / max(np.abs(real["rate_time"]).sum(), 1e-12))
    lag = xcorr_lag_us(sim["rate_time"], real["rate_time"], real["time_mask"],
                       float(ctx.cfg.time_bin_us), float(ctx.cfg.max_lag_us))
    d["lag"] = float(min(abs(lag) / LAG_SCALE_US, 5.0))
    lag = pearson_lag_us(sim["rate_time"], real["rate_time"], real["time_mask"],
                         float(ctx.cfg.time_bin_us), float(ctx.cfg.max_lag_us))
    d["lag_smoothed"] = float(min(abs(lag) / LAG_SCALE_US, 5.0))
    ps, pr = float(sim.get("pixel_persistence", np.nan)), float(real.get("pixel_persistence", np.nan))
    d["pixel_persistence"] = (float(min(abs(ps - pr) / (PERSIST_SCALE + abs(pr)), 5.0))
                              if np.isfinite(ps) and np.isfinite(pr) else 0.0)
    return d


def discrepancy(sim: dict, real: dict, ctx: CalibContext,
                weights: dict[str, float] | None = None) -> tuple[float, dict[str, float]]:
    """Weighted sum of :func:`distances` and the per-statistic terms."""
    weights = STATISTICS if weights is None else weights
    d = distances(sim, real, ctx)
    return float(sum(weights.get(k, 0.0) * v for k, v in d.items())), d
