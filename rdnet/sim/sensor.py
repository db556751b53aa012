"""Streaming DVS pixel simulator (ideal sensor plus the in-pixel degradations).

Model (Lichtsteiner et al., IEEE JSSC 2008; ESIM, Rebecq et al., CoRL 2018): each pixel
follows ``L = log(I + log_eps)`` and holds a reference ``ref``. Between two consecutive
frames at ``t0`` and ``t1`` the (possibly low-passed) log intensity is taken to vary
linearly, ``S(t) = S0 + (S1 - S0) (t - t0) / (t1 - t0)``; every time ``S`` crosses
``ref + theta_on`` (``ref - theta_off``) an ON (OFF) event is emitted at the exact crossing
time of that pixel,

    t_e = t0 + (ref' - S0) / (S1 - S0) (t1 - t0),   ref' = ref +- theta,

rounded to the microsecond, and ``ref`` moves by exactly one threshold. Several events per
step are allowed. A pixel whose log intensity ramps linearly by k thresholds therefore gets
exactly k events at the analytic times (a tolerance of :data:`CROSSING_TOL` log units
absorbs float rounding at the last crossing).

:class:`Sensor` holds the per-pixel state in preallocated arrays (reference, thresholds,
low-pass state, leak offset, time of the last event, readout period of the last event) and
consumes frames chunk by chunk (:meth:`Sensor.step`), so arbitrarily long inputs stream in
bounded memory. Per chunk:

1. numpy (SIMD) computes ``log(I + eps)`` and the low-pass decay ``exp(-2 pi f(I) dt)``
   into buffers reused from chunk to chunk;
2. one fused numba kernel, parallel over groups of rows (:func:`row_group`), advances
   every pixel (low-pass, leak, thresholds, refractory, readout period, and shot noise,
   whose events reset the pixel like any comparator firing) and writes its events to a
   buffer per group;
3. without hot pixels or timing effects the events are gathered with a stable sort per
   step (:func:`_gather_sorted`); otherwise the hot-pixel events of :mod:`rdnet.sim.effects`
   (one Poisson count per pixel per chunk) and the events held back from the previous
   chunk are merged in one fused pass (:func:`_assemble`) that draws each event's
   jitter/latency shift (one uniform per event through an alias table of the exact
   shift distribution) and counting-sorts everything by time.

Random numbers come only from the numpy Generator passed in, drawn in a fixed order
(shot noise: a counter-based stream per pixel, :func:`_noise_draw`, keyed by one draw of
the Generator), and the parallel loops work on a fixed partition of the data, so the same
seed gives bit-identical events whatever the number of threads (and, without hot pixels
and jitter, whatever the chunking). The kernels release the GIL, so
other Python threads run meanwhile (the calibration upsamples frames in one).
"""
from __future__ import annotations

import logging
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import get_num_threads, njit, parallel_chunksize, prange

from rdnet.errors import ValidationError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.sim import effects
from rdnet.sim.settings import DegradeConfig, SensorConfig

log = logging.getLogger(__name__)

#: Tolerance (log units) of the crossing test ``S - ref >= theta - tol``.
CROSSING_TOL = 1e-9
_NEVER = -(1 << 62)
_FMAX = 3.0e38
_NO_ALPHA = np.zeros((1, 1, 1), np.float32)
#: Iterations per work item of the parallel loops (dynamic scheduling: on a shared machine
#: a thread that gets less CPU takes fewer rows instead of holding up the others). The
#: work partition, hence the output, does not depend on it.
PARALLEL_CHUNK = 2
#: Work items per thread of the parallel gather of the ideal sensor's events over steps.
GATHER_ITEMS_PER_THREAD = 4
#: Pixels per group of rows of the pixel kernel (:func:`row_group`): about a page of a
#: float32 frame, so each step of a group reads contiguous memory.
GROUP_PIXELS = 1024
#: Pixel-steps per chunk from which the numpy terms run in two threads.
_THREADED_TERMS = 1 << 20
_POOL: ThreadPoolExecutor | None = None


def _terms_pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="rdnet-sensor")
    return _POOL

_ONE_F = np.ones(1)
_ZERO_I = np.zeros(1, np.int64)
_EMPTY_F = np.empty(0)


def row_group(width: int, height: int, group_pixels: int = GROUP_PIXELS) -> int:
    """Rows per group of :func:`_pixel_kernel`: as many as make ``group_pixels``
    pixels (at least 1, at most ``height``). The kernel advances a group step by step, so
    a step reads the group's rows of one frame, contiguous in memory, in one loop. One row
    per step (a 173-pixel row of the calibration's DAVIS346 pixel sample: 0.7 KB, and the
    next step's 90 KB further) took 4.2 ns per pixel and step, groups of 1038 pixels 2.9
    (ideal sensor, one thread; benchmarks/bench_sensor_groups.py). The events do not
    depend on it."""
    return max(1, min(int(height), -(-int(group_pixels) // max(int(width), 1))))


@njit(cache=True, inline="always")
def _finite(v):
    """(v as float64, 0), or (0.0, 1) when v is NaN or infinite (branch-free)."""
    s = float(v)
    ok = (s > -_FMAX) & (s < _FMAX)
    return (s if ok else 0.0), np.int64(not ok)


@njit(cache=True, inline="always")
def _advance(j, s1, s_prev, s0row, ref, thr_on, thr_off, crs):
    """Pixel j (of a group's flat views) moves to S = ``s1`` (the previous S kept in
    ``s0row[j]``); ``crs[j]``: whether it crosses a threshold (branch-free)."""
    s0row[j] = s_prev[j]
    s_prev[j] = s1
    r = ref[j]
    crs[j] = (s1 - r >= thr_on[j] - CROSSING_TOL) | (r - s1 >= thr_off[j] - CROSSING_TOL)


_U64 = np.uint64
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True, inline="always")
def _mix64(z):
    """splitmix64 finaliser (Steele, Lea, Flood, OOPSLA 2014): a bijection of uint64 whose
    outputs pass BigCrush for consecutive inputs."""
    z = (z ^ (z >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> _U64(27))) * _U64(0x94D049BB133111EB)
    return z ^ (z >> _U64(31))


@njit(cache=True, inline="always")
def _noise_draw(key, pix, ctr):
    """Draw number ``ctr`` of pixel ``pix`` of the shot-noise stream ``key`` (counter-based,
    so the draws do not depend on threads or chunking): (Exp(1) variate, polarity bit)."""
    z = _mix64(key + _GOLDEN * _mix64((_U64(pix) << _U64(32)) + _U64(ctr)))
    u = (float(z >> _U64(11)) + 1.0) * (1.0 / 9007199254740992.0)     # (0, 1]
    return -math.log(u), np.uint8(z & _U64(1))


@njit(cache=True)
def _init_hazard(hz, ctr, key):
    """First noise hazard target (Exp(1)) of every pixel; counters to 1."""
    H, W = hz.shape
    for y in range(H):
        for x in range(W):
            hz[y, x] = _noise_draw(key, y * W + x, np.int64(0))[0]
            ctr[y, x] = 1


@njit(cache=True, inline="always")
def _emit(out_t, out_x, out_p, base, n, cap, te, x, pol):
    """Write event n of a row buffer (while n < cap: the caller grows the buffers and
    reruns the chunk on overflow); returns n + 1."""
    if n < cap:
        out_t[base + n] = te
        out_x[base + n] = x
        out_p[base + n] = pol
    return n + 1


@njit(cache=True, inline="always")
def _admit(te, lt, lb, refractory, use_period, period):
    """Whether an event (threshold crossing or noise) at ``te`` is emitted by a pixel whose
    last event was at ``lt`` in readout period ``lb``: not within ``refractory`` of it, nor
    in the same readout period. Returns (emitted, the pixel's readout period after it)."""
    if te - lt < refractory:
        return False, lb
    if use_period:
        b = np.int64(math.floor(te / period))
        if b == lb:
            return False, lb
        return True, b
    return True, lb


@njit(cache=True, inline="always")
def _wake_level(s0, s1, tp, t1, wake):
    """S at the wake-up time ``wake`` of a pixel held in reset during the step tp -> t1
    (S linear from s0 to s1; s1 when it wakes at or after t1): its new reference."""
    if wake >= t1:
        return s1
    return s0 + (s1 - s0) * ((wake - tp) / float(t1 - tp))


@njit(cache=True, inline="always")
def _lowpass(lp, decay, j, s1, lraw):
    """One low-pass step of pixel j (of a group's flat views; ``decay`` this step's)
    towards ``s1``, the input linear from the previous step's ``lraw[j]`` to ``s1`` within
    the step (exact first-order response); returns the new state."""
    a = float(decay[j])
    l0 = lraw[j]
    lraw[j] = s1
    if a <= 0.0:
        g = 0.0
    elif a >= 0.9999999:
        g = -0.5 * (1.0 - a)
    else:
        g = a + (1.0 - a) / math.log(a)
    lpv = a * lp[j] + (1.0 - a) * s1 + (s1 - l0) * g
    lp[j] = lpv
    return lpv


@njit(cache=True, inline="always")
def _leaked(acc, drift, j, s1, dt):
    """``s1`` plus pixel j's leak offset, which grows by ``drift[j] dt`` over the step."""
    a = acc[j] + drift[j] * dt
    acc[j] = a
    return s1 + a


@njit(cache=True, inline="always")
def _flat(a, p0, n):
    """Pixels p0 .. p0 + n - 1 of ``a`` ((H, W) or a (H, W) frame), C-contiguous, flat: a view."""
    return a.reshape(a.size)[p0:p0 + n]


@njit(parallel=True, cache=True, nogil=True)
def _pixel_kernel(logf, decay, lin, use_lp, use_leak, use_shot, shot_a, shot_b, t_us, t_prev,
                  s_prev, lp, lraw, acc, ref, last_t, last_bin, hz, nctr, key,
                  thr_on, thr_off, drift, refractory, period,
                  out_t, out_x, out_p, seg, counts, bad, cap, group):
    """Advance every pixel over the K steps of ``logf`` (K, H, W) log intensity.

    Per pixel and step k (dt = t_k - t_{k-1} in us):
      low-pass (if ``use_lp``): the exact first-order response over the step to an input
      linear from L_{k-1} to L_k (``lraw`` keeps L_{k-1}): with a = decay_k = exp(-2 pi f(I) dt),
      lp = a lp + (1 - a) L_k + (L_k - L_{k-1}) (a + (1 - a) / ln a), so the lag does not
      depend on the step (holding L_k over the step made events about dt / 2 early;
      benchmarks/bandwidth_step_size.py);
      leak: acc += drift dt; S_k = lp + acc (= L_k when both are off);
      each crossing of ``ref +- theta`` by the segment S_{k-1} -> S_k: ref moves by one
      threshold, event time t_{k-1} + (ref - S_{k-1}) / (S_k - S_{k-1}) dt, emitted unless
      in the readout period of the last event (then lost, ref moved); after an event at
      t_e the pixel is held in reset until t_e + ``refractory``: ref follows S (linear
      within a step) and the first crossing after the wake is measured from S there;
      shot noise (if ``use_shot``): rate ``shot_a + shot_b min(I_k, 1)`` (per us; ``lin`` =
      I, clipped at 0 by the caller), constant within a step; ``hz`` is the hazard left to
      the pixel's next noise event (an Exp(1) target, :func:`_noise_draw` number ``nctr``
      of stream ``key``). A noise event is a comparator firing: it has a random polarity,
      is lost in the refractory/readout period of the last event like any other, and when
      emitted it resets the pixel (``ref = S`` at its time; then the refractory hold).
      Noise events and threshold crossings of a pixel are taken in time order.
    Loops: groups of ``group`` consecutive rows in parallel (group Y: rows Y * group ..,
    the last group shorter; :func:`row_group`), then steps, then the group's pixels, flat
    (a branch-free pass that vectorises, then the pixels that cross), so a step reads the
    group's rows of a frame, contiguous in memory. Group Y's buffer (from
    ``Y * cap``) is step-ordered, row-ordered per step and pixel-ordered per row;
    ``seg[k, y]`` counts the events of row y in step k (:func:`_row_starts` locates them)
    and ``counts[Y]`` the group's total (events are written while it is < cap). ``bad[Y]``
    flags NaN/inf input. The events and their order do not depend on ``group``.
    """
    K, H, W = logf.shape
    n_groups = (H + group - 1) // group
    use_period = period > 0.0
    use_reset = refractory > 0.0
    for gy in prange(n_groups):
        y0 = gy * group
        gw = (min(H, y0 + group) - y0) * W     # pixels of the group: j = (y - y0) W + x
        p0 = y0 * W
        base = gy * cap
        n = 0
        isbad = False
        tp = t_prev
        # the group's pixels as flat views (indices from 0: no negative-index handling)
        g_s = _flat(s_prev, p0, gw)
        g_lp = _flat(lp, p0, gw)
        g_lraw = _flat(lraw, p0, gw)
        g_acc = _flat(acc, p0, gw)
        g_ref = _flat(ref, p0, gw)
        g_lt = _flat(last_t, p0, gw)
        g_lb = _flat(last_bin, p0, gw)
        g_hz = _flat(hz, p0, gw)
        g_ctr = _flat(nctr, p0, gw)
        g_on = _flat(thr_on, p0, gw)
        g_off = _flat(thr_off, p0, gw)
        g_drift = _flat(drift, p0, gw)
        s0row = np.empty(gw)
        idx = np.empty(gw, np.int64)
        nw = (gw + 7) // 8
        crs8 = np.zeros(nw * 8, np.uint8)       # crossing flags, padded to whole words
        crs = crs8[:gw]
        words = crs8.view(np.uint64)
        for k in range(K):
            t1 = t_us[k]
            dt = float(t1 - tp)
            for y in range(y0, y0 + gw // W):
                seg[k, y] = 0
            g_log = _flat(logf[k], p0, gw)
            g_dec = _flat(decay[k], p0, gw) if use_lp else _flat(decay[0], 0, 1)
            g_lin = _flat(lin[k], p0, gw) if use_shot else _flat(lin[0], 0, 1)
            # pass 1: new S of every pixel and whether it crosses, in a loop without
            # branches per configuration (a loop-invariant branch inside keeps it scalar)
            nbad = 0
            if use_leak and use_lp:
                for j in range(gw):
                    s1, b = _finite(g_log[j])
                    nbad += b
                    s1 = _leaked(g_acc, g_drift, j, _lowpass(g_lp, g_dec, j, s1, g_lraw), dt)
                    _advance(j, s1, g_s, s0row, g_ref, g_on, g_off, crs)
            elif use_leak:              # a loop of its own: the use_lp test inside kept it scalar
                for j in range(gw):
                    s1, b = _finite(g_log[j])
                    nbad += b
                    _advance(j, _leaked(g_acc, g_drift, j, s1, dt), g_s, s0row, g_ref, g_on, g_off, crs)
            elif use_lp:
                for j in range(gw):
                    s1, b = _finite(g_log[j])
                    nbad += b
                    _advance(j, _lowpass(g_lp, g_dec, j, s1, g_lraw), g_s, s0row, g_ref, g_on, g_off, crs)
            else:
                for j in range(gw):
                    s1, b = _finite(g_log[j])
                    nbad += b
                    _advance(j, s1, g_s, s0row, g_ref, g_on, g_off, crs)
            isbad |= nbad > 0
            if use_reset:
                # pixels held in reset during this step (an event less than ``refractory``
                # ago): the reference follows S until the pixel wakes (all step: ref = S_k;
                # waking inside the step: ref = S at the wake time, then it may cross)
                for j in range(gw):
                    wake = g_lt[j] + refractory
                    if wake > tp:
                        s1 = g_s[j]
                        r = _wake_level(s0row[j], s1, tp, t1, wake)
                        g_ref[j] = r
                        if wake >= t1:
                            crs[j] = 0
                        else:
                            crs[j] = (s1 - r >= g_on[j] - CROSSING_TOL) | (r - s1 >= g_off[j] - CROSSING_TOL)
            if use_shot:
                # the hazard left to the next noise event falls by the step's integral of
                # the rate; the pixels it reaches (flag 2) are handled in pass 2
                for j in range(gw):
                    h = g_hz[j] - (shot_a + shot_b * min(float(g_lin[j]), 1.0)) * dt
                    g_hz[j] = h
                    crs[j] |= np.uint8(2) * np.uint8(h <= 0.0)
            # the pixels that cross or fire a noise event (few: 8 flags are tested at once)
            m = 0
            for w8 in range(nw):
                if words[w8] != 0:
                    for j in range(w8 * 8, min(w8 * 8 + 8, gw)):
                        if crs[j]:
                            idx[m] = j
                            m += 1
            # pass 2: the events of those pixels, in pixel order, each pixel's in time order
            for q in range(m):
                j = idx[q]
                yr = j // W
                x = j - yr * W
                n_pixel = n
                s1 = g_s[j]
                s0 = s0row[j]
                r = g_ref[j]
                ton = g_on[j]
                toff = g_off[j]
                ds = s1 - s0
                lt = g_lt[j]
                lb = g_lb[j]
                fn = 2.0                    # step fraction of the next noise event (> 1: none)
                hdt = 0.0
                if crs[j] & 2:
                    hdt = (shot_a + shot_b * min(float(g_lin[j]), 1.0)) * dt
                    fn = (g_hz[j] + hdt) / hdt
                while True:
                    # the next threshold crossing from r and its step fraction fc
                    if s1 - r >= ton - CROSSING_TOL:
                        pol = 1
                        stp = ton
                    elif r - s1 >= toff - CROSSING_TOL:
                        pol = 0
                        stp = -toff
                    else:
                        pol = -1
                        stp = 0.0
                    fc = 2.0
                    if pol >= 0:
                        fc = (r + stp - s0) / ds if ds != 0.0 else 1.0
                        if fc < 0.0:
                            fc = 0.0
                        elif fc > 1.0:
                            fc = 1.0
                    if fn < fc:
                        # a noise event: fires unless in the refractory/readout period
                        te = np.int64(math.floor(tp + fn * dt + 0.5))
                        fire, lb = _admit(te, lt, lb, refractory, use_period, period)
                        e, pb = _noise_draw(key, p0 + j, g_ctr[j])
                        g_ctr[j] += 1
                        if fire:
                            lt = te
                            n = _emit(out_t, out_x, out_p, base, n, cap, te, x, pb)
                            r = s0 + ds * fn        # the reset: the reference takes S
                            if use_reset:
                                r = _wake_level(s0, s1, tp, t1, te + refractory)
                        rest = (1.0 - fn) * hdt
                        if e <= rest:
                            fn += e / hdt
                        else:
                            g_hz[j] = e - rest
                            fn = 2.0
                        continue
                    if pol < 0:
                        break
                    r += stp
                    te = np.int64(math.floor(tp + fc * dt + 0.5))
                    ok, lb = _admit(te, lt, lb, refractory, use_period, period)
                    if not ok:
                        continue
                    lt = te
                    n = _emit(out_t, out_x, out_p, base, n, cap, te, x, pol)
                    if use_reset:           # held in reset: ref follows S until te + refractory
                        r = _wake_level(s0, s1, tp, t1, te + refractory)
                g_ref[j] = r
                g_lt[j] = lt
                g_lb[j] = lb
                seg[k, y0 + yr] += n - n_pixel
            tp = t1
        counts[gy] = n
        bad[gy] = isbad


@njit(cache=True)
def _row_starts(seg, cap, group):
    """First buffer slot of the events of (step k, row y) as :func:`_pixel_kernel` writes
    them: group Y (rows Y * ``group`` ..) from ``Y * cap`` on, step by step, row by row
    within a step."""
    K, H = seg.shape
    start = np.empty((K, H), np.int64)
    for gy in range((H + group - 1) // group):
        s = gy * cap
        for k in range(K):
            for y in range(gy * group, min(H, (gy + 1) * group)):
                start[k, y] = s
                s += seg[k, y]
    return start


@njit(parallel=True, cache=True, nogil=True)
def _gather_sorted(out_t, out_x, out_p, seg, cap, group, t_us, t_prev, out):
    """Write the kernel's step-ordered buffers (:func:`_row_starts`) into ``out``
    (EVENT_DTYPE) sorted by time.

    Events of step k lie in [t_{k-1}, t_k]; steps are handled in parallel, each with a
    stable counting sort on its time offsets (argsort when the step is long compared
    with its event count). Ties keep (row, pixel) order."""
    K, H = seg.shape
    start = _row_starts(seg, cap, group)
    stepoff = np.zeros(K + 1, np.int64)
    for k in range(K):
        tot = 0
        for y in range(H):
            tot += seg[k, y]
        stepoff[k + 1] = stepoff[k] + tot
    for k in prange(K):
        m = stepoff[k + 1] - stepoff[k]
        if m == 0:
            continue
        lo = t_prev if k == 0 else t_us[k - 1]
        span = t_us[k] - lo + 1
        o = stepoff[k]
        if span <= 32 * m + 1024:      # else the histogram costs more than a merge sort
            cnt = np.zeros(span + 1, np.int64)
            for y in range(H):
                s = start[k, y]
                for j in range(s, s + seg[k, y]):
                    cnt[out_t[j] - lo + 1] += 1
            for i in range(span):
                cnt[i + 1] += cnt[i]
            for y in range(H):
                s = start[k, y]
                for j in range(s, s + seg[k, y]):
                    q = o + cnt[out_t[j] - lo]
                    cnt[out_t[j] - lo] += 1
                    out[q].t = out_t[j]
                    out[q].x = out_x[j]
                    out[q].y = y
                    out[q].p = out_p[j]
        else:
            tt = np.empty(m, np.int64)
            src = np.empty(m, np.int64)
            ys = np.empty(m, np.int64)
            i = 0
            for y in range(H):
                s = start[k, y]
                for j in range(s, s + seg[k, y]):
                    tt[i] = out_t[j]
                    src[i] = j
                    ys[i] = y
                    i += 1
            order = np.argsort(tt, kind="mergesort")
            for i in range(m):
                j = src[order[i]]
                out[o + i].t = out_t[j]
                out[o + i].x = out_x[j]
                out[o + i].y = ys[order[i]]
                out[o + i].p = out_p[j]


_SORT_BLOCKS = 8


@njit(cache=True)
def _exclusive_offsets(hist):
    """In place: the (blocks, span) counts of a counting sort become each (block, time
    bin)'s first output index, bins in time order and blocks in order within a bin."""
    total = 0
    for v in range(hist.shape[1]):
        for b in range(hist.shape[0]):
            c = hist[b, v]
            hist[b, v] = total
            total += c


@njit(parallel=True, cache=True, nogil=True)
def _counting_sort(src, tmin, span, out):
    """Stable counting sort of the structured events ``src`` by time into ``out``.

    Parallel over a fixed number of contiguous input blocks (per-block histograms, then
    per-block offsets); a stable sort has a unique result, so the output does not depend
    on the number of threads."""
    n = src.shape[0]
    nb = _SORT_BLOCKS
    step = (n + nb - 1) // nb
    hist = np.zeros((nb, span), np.int64)
    for b in prange(nb):
        for i in range(b * step, min(n, (b + 1) * step)):
            hist[b, src[i].t - tmin] += 1
    _exclusive_offsets(hist)   # bins in time order, blocks in input order within a bin
    for b in prange(nb):
        for i in range(b * step, min(n, (b + 1) * step)):
            v = src[i].t - tmin
            j = hist[b, v]
            hist[b, v] = j + 1
            out[j] = src[i]


@njit(inline="always")
def shift_of(i, mode, const, lo, hi, prob, alias, r, sigma, latency):
    """Shift (integer us) of event ``i`` of a chunk; see :class:`rdnet.sim.effects.ShiftSampler`.
    (Defined here, next to the jitted functions that inline it: numba's cache does not see
    changes in other modules.)"""
    if mode == 0:
        return np.int64(const)
    if mode == 1:
        n = prob.shape[0]
        x = r[i] * n
        j = min(np.int64(x), n - 1)
        # c = (x - j >= prob[j]) as arithmetic (x - j and prob[j] lie in [0, 1]): a compare
        # here compiles to an unpredictable branch, 4x slower
        c = np.int64(math.floor((x - j) - prob[j])) + 1
        return np.int64(lo + j + (alias[j] - j) * c)
    # floor(d + s clip(z, -4, 4) + 0.5) = the unclipped shift clipped to [lo, hi]
    v = np.int64(math.floor(latency + sigma * r[i] + 0.5))
    return min(max(v, np.int64(lo)), np.int64(hi))


@njit(cache=True)
def _shift_in_place(arr, mode, const, lo, hi, prob, alias, r, sigma, latency, t_min):
    for i in range(arr.shape[0]):
        t = arr[i].t + shift_of(i, mode, const, lo, hi, prob, alias, r, sigma, latency)
        arr[i].t = t if t > t_min else t_min


def shift_events(arr: np.ndarray, sampler: effects.ShiftSampler, r: np.ndarray, t_min: int) -> None:
    """``t <- max(t + shift_i, t_min)`` in place on the EVENT_DTYPE array ``arr``, event i
    using random number ``r[i]`` (:func:`rdnet.sim.effects.draw_shift_randoms`)."""
    sm = sampler
    _shift_in_place(arr, sm.mode, sm.const_us, sm.lo_us, sm.hi_us, sm.prob, sm.alias, r, sm.sigma_us,
                    sm.latency_us, np.int64(t_min))


def apply_timing(arr: np.ndarray, degrade: DegradeConfig, rng: np.random.Generator | None,
                 t_min: int) -> None:
    """Jitter and latency, in place on the EVENT_DTYPE array ``arr``:
    ``t <- max(t + round(latency + jitter z), t_min)``, z ~ N(0, 1) truncated at
    :data:`rdnet.sim.effects.JITTER_TRUNCATE` (one draw per event in array order, through
    :func:`rdnet.sim.effects.shift_sampler`). Leaves ``arr`` unsorted. (:class:`Sensor`
    fuses the same shift into its per-chunk sort.)"""
    if (degrade.jitter_us <= 0 and degrade.latency_us <= 0) or arr.size == 0:
        return
    sm = effects.shift_sampler(degrade)
    shift_events(arr, sm, effects.draw_shift_randoms(sm, arr.size, rng), t_min)


@njit(parallel=True, cache=True, nogil=True)
def _assemble(out_t, out_x, out_p, seg, cap, group, held, noise, mode, const, lo_shift, hi_shift, prob, alias, r,
              sigma, latency, t_min, lo, span, counting, hist_buf, out):
    """All events of a chunk into ``out`` (EVENT_DTYPE), sorted by time when ``counting``.

    Sources, in this order: ``held`` (events of earlier chunks, already final in time),
    the kernel's buffers (``seg[k, y]`` events of row y in step k, consecutive from
    :func:`_row_starts`) and the ``noise`` events. Every kernel and noise event i (in source
    order) is shifted by :func:`shift_of` (random number ``r[i]``) and
    clipped below at ``t_min``; then a stable counting sort on ``t - lo`` (``span`` bins)
    writes ``out``. Parallel over a fixed partition of the sources (held,
    :data:`_SORT_BLOCKS` blocks of rows, noise); inside a block of rows the order is
    (step, row, pixel), so reads and writes move through time together. Ties keep source
    order, so the result does not depend on the number of threads. Without ``counting``
    the events are written in source order (the caller sorts). ``hist_buf``: int64 scratch
    of at least (:data:`_SORT_BLOCKS` + 2) ``span`` entries, reused across chunks."""
    K, H = seg.shape
    nb = _SORT_BLOCKS
    rows = (H + nb - 1) // nb
    NB = nb + 2
    nh = held.shape[0]
    start = _row_starts(seg, cap, group)    # first buffer slot of (step k, row y)
    first = np.zeros(NB + 1, np.int64)      # first slot of each block in source order
    first[1] = nh
    for b in range(nb):
        c = 0
        for k in range(K):
            for y in range(b * rows, min(H, (b + 1) * rows)):
                c += seg[k, y]
        first[b + 2] = first[b + 1] + c
    first[NB] = first[NB - 1] + noise.shape[0]
    hist = hist_buf[:NB * span].reshape((NB, span))
    for b in prange(NB):
        hist[b, :] = 0
        if b == 0:
            if counting:
                for i in range(nh):
                    hist[0, held[i].t - lo] += 1
        elif b <= nb:
            i = first[b] - nh
            for k in range(K):
                for y in range((b - 1) * rows, min(H, b * rows)):
                    for j in range(start[k, y], start[k, y] + seg[k, y]):
                        t = out_t[j] + shift_of(i, mode, const, lo_shift, hi_shift, prob, alias, r, sigma, latency)
                        if t < t_min:
                            t = t_min
                        out_t[j] = t
                        if counting:
                            hist[b, t - lo] += 1
                        i += 1
        else:
            i = first[b] - nh
            for j in range(noise.shape[0]):
                t = noise[j].t + shift_of(i, mode, const, lo_shift, hi_shift, prob, alias, r, sigma, latency)
                if t < t_min:
                    t = t_min
                noise[j].t = t
                if counting:
                    hist[b, t - lo] += 1
                i += 1
    if counting:
        _exclusive_offsets(hist)   # bins in time order, sources in order within a bin
    else:
        for b in range(NB):
            hist[b, 0] = first[b]
    for b in prange(NB):
        if b == 0:
            for i in range(nh):
                v = held[i].t - lo if counting else 0
                q = hist[0, v]
                hist[0, v] = q + 1
                out[q] = held[i]
        elif b <= nb:
            for k in range(K):
                for y in range((b - 1) * rows, min(H, b * rows)):
                    for j in range(start[k, y], start[k, y] + seg[k, y]):
                        t = out_t[j]
                        v = t - lo if counting else 0
                        q = hist[b, v]
                        hist[b, v] = q + 1
                        out[q].t = t
                        out[q].x = out_x[j]
                        out[q].y = y
                        out[q].p = out_p[j]
        else:
            for j in range(noise.shape[0]):
                v = noise[j].t - lo if counting else 0
                q = hist[b, v]
                hist[b, v] = q + 1
                out[q] = noise[j]


def sort_events(arr: np.ndarray) -> np.ndarray:
    """``arr`` (EVENT_DTYPE) stably sorted by time, as a new array (counting sort when the
    time span is small compared with the count, else argsort)."""
    n = arr.shape[0]
    if n == 0:
        return arr.copy()
    t = arr["t"]
    tmin, tmax = int(t.min()), int(t.max())
    span = tmax - tmin + 1
    if span <= 2 * n + (1 << 16):
        out = np.empty(n, EVENT_DTYPE)
        _counting_sort(arr, tmin, span, out)
        return out
    return arr[np.argsort(t, kind="stable")]


class Sensor:
    """Per-pixel state of one simulated event camera (ideal when ``degrade`` is None or
    all effects are off); consume frames with :meth:`step`, then :meth:`flush`.

    ``rng`` (numpy Generator) is required when a random effect is on; it draws the
    per-sequence pixel parameters here and the noise/jitter of every chunk. The same seed
    and the same chunking give bit-identical events. ``group_pixels``: the pixel kernel's
    memory layout (:func:`row_group`); the events do not depend on it.
    """

    def __init__(self, width: int, height: int, sensor: SensorConfig = SensorConfig(),
                 degrade: DegradeConfig | None = None, rng: np.random.Generator | None = None, *,
                 group_pixels: int = GROUP_PIXELS):
        self.width, self.height = int(width), int(height)
        if self.width <= 0 or self.height <= 0:
            raise ValidationError("width/height", f"sensor size must be positive, got {width}x{height}")
        self.sensor = sensor
        self.degrade = degrade = DegradeConfig() if degrade is None else degrade
        if effects.needs_rng(degrade) and not isinstance(rng, np.random.Generator):
            raise ValidationError("rng", "a numpy.random.Generator is required for the random degradations "
                                  f"{', '.join(degrade.active())}")
        self.rng = rng
        H, W = self.height, self.width
        # C-contiguous: the pixel kernel reads the per-pixel maps through flat views
        self.thr_on, self.thr_off = map(np.ascontiguousarray, effects.pixel_thresholds(H, W, sensor, degrade, rng))
        rates = effects.leak_rates(H, W, degrade, rng)
        self.leak_rate_hz = rates
        self.drift = np.ascontiguousarray(rates * self.thr_on * 1e-6)      # log units per microsecond
        self._phase = effects.leak_phase(H, W, degrade, rng)
        self.hot_idx, self.hot_on = effects.hot_pixels(H, W, degrade, rng)
        self._lp_coef = effects.lowpass_coef(degrade)
        self._lp_floor = np.float32(degrade.cutoff_floor)
        self._shot_a, self._shot_b = effects.shot_rate_coefs(degrade)
        self._shift_lo, self._shift_hi = effects.timing_shift_bounds(degrade)
        self._timing = degrade.jitter_us > 0 or degrade.latency_us > 0
        self._shifts = effects.shift_sampler(degrade) if self._timing else None
        self._use_leak = bool(np.any(self.drift != 0))
        # state
        self.s_prev = np.zeros((H, W))
        self.lp = np.zeros((H, W))
        self.lraw = np.zeros((H, W))
        self.acc = np.zeros((H, W))
        self.ref = np.zeros((H, W))
        self.last_t = np.full((H, W), _NEVER, np.int64)
        self.last_bin = np.full((H, W), _NEVER, np.int64)
        # shot noise: a counter-based stream (key drawn once from rng), the hazard left to
        # each pixel's next noise event and the pixel's draw counter
        self._noise_key = np.uint64(0)
        self.shot_hazard = np.zeros((H, W))
        self._noise_ctr = np.zeros((H, W), np.uint64)
        if self._shot_a > 0:
            self._noise_key = np.uint64(rng.integers(0, 1 << 63, dtype=np.int64))
            _init_hazard(self.shot_hazard, self._noise_ctr, self._noise_key)
        self._state = (self.s_prev, self.lp, self.lraw, self.acc, self.ref, self.last_t, self.last_bin,
                       self.shot_hazard, self._noise_ctr)
        self._backup = tuple(np.empty_like(a) for a in self._state)
        self._group = row_group(W, H, group_pixels)
        n_groups = -(-H // self._group)
        self._counts = np.zeros(n_groups, np.int64)      # events per group of rows
        self._bad = np.zeros(n_groups, np.bool_)
        self._cap = 0
        self._bufs: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._fbufs: dict[tuple[str, np.dtype], np.ndarray] = {}
        self._hist = np.empty(0, np.int64)
        self.t_prev: int | None = None
        self.t_start: int | None = None
        self._held = np.empty(0, EVENT_DTYPE)
        self.n_events = 0

    # --- buffers ------------------------------------------------------------------------
    def _ensure_cap(self, cap: int) -> None:
        """Event buffers of ``cap`` events per group of rows (:func:`row_group`)."""
        if cap > self._cap:
            n = cap * self._counts.size
            self._bufs = (np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint8))
            self._cap = cap

    def _chunk_buffer(self, name: str, k: int, dtype) -> np.ndarray:
        """A reusable (k, H, W) array (no allocation per chunk once the largest chunk is seen)."""
        key = (name, np.dtype(dtype))
        buf = self._fbufs.get(key)
        if buf is None or buf.shape[0] < k:
            buf = np.empty((k, self.height, self.width), dtype)
            self._fbufs[key] = buf
        return buf[:k]

    # --- input checks -------------------------------------------------------------------
    def _prepare(self, frames, t_us, is_log: bool) -> tuple[np.ndarray, np.ndarray]:
        fr = np.asarray(frames)
        if fr.ndim == 2:
            fr = fr[None]
        if fr.ndim != 3 or fr.shape[1:] != (self.height, self.width):
            raise ValidationError("frames", f"expected (K, {self.height}, {self.width}), got shape {fr.shape}")
        if fr.dtype == np.uint8 and not is_log:
            fr = fr.astype(np.float32) * np.float32(1.0 / 255.0)
        elif fr.dtype not in (np.float32, np.float64):
            if not np.issubdtype(fr.dtype, np.number) or np.issubdtype(fr.dtype, np.complexfloating):
                raise ValidationError("frames", f"expected float32 intensity, got dtype {fr.dtype}")
            fr = fr.astype(np.float64 if is_log else np.float32)
        fr = np.ascontiguousarray(fr)
        t = np.asarray(t_us)
        if t.ndim == 0:
            t = t[None]
        if not np.issubdtype(t.dtype, np.integer):
            if np.issubdtype(t.dtype, np.floating) and np.all(np.isfinite(t)) and np.all(t == np.round(t)):
                t = t.astype(np.int64)
            else:
                raise ValidationError("t_us", f"timestamps must be integer microseconds, got {t.dtype}")
        t = np.ascontiguousarray(t, dtype=np.int64)
        if t.shape != (fr.shape[0],):
            raise ValidationError("t_us", f"expected {fr.shape[0]} timestamps, got shape {t.shape}")
        prev = [] if self.t_prev is None else [self.t_prev]
        tt = np.concatenate([np.asarray(prev, np.int64), t])
        if tt.size > 1 and np.any(np.diff(tt) <= 0):
            i = int(np.flatnonzero(np.diff(tt) <= 0)[0])
            raise ValidationError("t_us", f"timestamps must increase strictly ({int(tt[i])} -> {int(tt[i + 1])} us)")
        return fr, t

    def _init_state(self, frame: np.ndarray, t0: int, is_log: bool) -> None:
        v = frame.astype(np.float64)
        if is_log:
            if not np.isfinite(v).all():
                raise ValidationError("frames", "log frame contains NaN or infinite values")
            L = v
        else:
            if not np.isfinite(v).all():
                raise ValidationError("frames", "frame contains NaN or infinite values")
            if v.min() < 0:
                raise ValidationError("frames", f"negative intensity {float(v.min())}")
            L = np.log(v + self.sensor.log_eps)
        self.s_prev[...] = L
        self.lp[...] = L
        self.lraw[...] = L
        self.acc[...] = 0.0
        self.ref[...] = L - self._phase * self.thr_on
        self.t_prev = self.t_start = int(t0)

    # --- simulation ---------------------------------------------------------------------
    def _chunk_terms(self, fr: np.ndarray, t: np.ndarray, is_log: bool, log_frames: np.ndarray | None = None):
        """Log intensity ``L`` (float32 for float32 linear input; ``log_frames`` when
        given), ``e = exp(-2 pi f(I) dt)`` of the low-pass (the kernel uses alpha = 1 - e),
        and the linear intensity ``I`` (clipped at 0) the kernel needs for the shot-noise
        hazard. Vectorized numpy (SIMD log/exp) into reused buffers, in two threads for
        large chunks (numpy releases the GIL; each thread fills its own steps, so the
        result is the same)."""
        K = t.size
        dt = np.diff(np.concatenate([[self.t_prev], t])).astype(np.float64)
        use_lp = self._lp_coef > 0
        need_lin = use_lp or self._shot_a > 0
        eps = self.sensor.log_eps
        if is_log:
            logf = fr
            lin = self._chunk_buffer("lin", K, np.float32) if need_lin else None
        else:
            logf = self._chunk_buffer("log", K, fr.dtype) if log_frames is None else log_frames
            lin = fr
        decay = self._chunk_buffer("decay", K, np.float32) if use_lp else _NO_ALPHA
        c = (-self._lp_coef * dt).astype(np.float32)[:, None, None]

        def fill(a: int, b: int) -> float:
            """Steps a..b-1; returns the smallest linear input (NaN if any) of the slice."""
            mn = 0.0
            if is_log:
                if need_lin:
                    li = lin[a:b]
                    np.exp(fr[a:b], out=li, casting="same_kind")
                    np.subtract(li, np.float32(eps), out=li)
                    np.maximum(li, np.float32(0.0), out=li)
            else:
                mn = fr[a:b].min()
                if not mn >= 0:
                    return float(mn)                # raised by the caller
                if log_frames is None:
                    lg = logf[a:b]
                    np.add(fr[a:b], fr.dtype.type(eps), out=lg)
                    np.log(lg, out=lg)
            if use_lp:
                # e = exp(-c dt_k (I + floor))
                de = decay[a:b]
                np.add(lin[a:b], self._lp_floor, out=de, casting="same_kind")
                np.multiply(de, c[a:b], out=de)
                np.exp(de, out=de)
            return float(mn)

        if K >= 2 and fr[0].size * K >= _THREADED_TERMS and get_num_threads() > 1:
            h = K // 2
            mins = list(_terms_pool().map(lambda ab: fill(*ab), [(0, h), (h, K)]))
        else:
            mins = [fill(0, K)]
        if not is_log:
            mn = min(mins) if not any(m != m for m in mins) else float("nan")
            if not mn >= 0:
                raise ValidationError("frames", "frames contain NaN or negative intensity"
                                      + ("" if mn != mn else f" ({float(mn)})"))
        if self._shot_a <= 0:
            lin = _NO_ALPHA                         # the kernel reads it for shot noise only
        elif lin.dtype != np.float32:
            lin = lin.astype(np.float32)
        return logf, decay, lin

    def step(self, frames: np.ndarray, t_us: np.ndarray, *, log: bool = False,
             log_frames: np.ndarray | None = None) -> Events:
        """Consume frames (K, H, W) at times ``t_us`` (K,) int64 us, after all frames seen
        so far; ``frames`` are linear intensity (float32 in [0, 1] or uint8), or log
        intensity when ``log=True``. The very first frame only sets the state. Returns the
        events that are final (time-sorted; with jitter, the events within the jitter
        range of the chunk end are held back until the next call or :meth:`flush`).

        ``log_frames``: with linear float frames, their ``log(I + log_eps)`` (same shape
        and dtype) when the caller has it already, e.g. for many simulations of the same
        frames; it is used instead of computing it (it must be exactly that: the low-pass
        needs both)."""
        fr, t = self._prepare(frames, t_us, log)
        if log_frames is not None:
            if log or log_frames.shape != fr.shape or log_frames.dtype != fr.dtype:
                got = f"{log_frames.shape} {log_frames.dtype}" + (" with log=True" if log else "")
                raise ValidationError("log_frames", f"expected {fr.shape} {fr.dtype} with linear frames, got {got}")
            log_frames = np.ascontiguousarray(log_frames)
        if t.size == 0:
            return Events.empty(self.width, self.height)
        if self.t_prev is None:
            self._init_state(fr[0], t[0], log)
            fr, t = fr[1:], t[1:]
            log_frames = None if log_frames is None else log_frames[1:]
            if t.size == 0:
                return Events.empty(self.width, self.height)
        with parallel_chunksize(PARALLEL_CHUNK):
            return self._step(fr, t, log, log_frames)

    def _step(self, fr: np.ndarray, t: np.ndarray, log: bool, log_frames: np.ndarray | None = None) -> Events:
        t0, t1 = int(self.t_prev), int(t[-1])
        logf, decay, lin = self._chunk_terms(fr, t, log, log_frames)
        for src, dst in zip(self._state, self._backup):
            np.copyto(dst, src)
        # first guess: up to 1/2 event per pixel and step of this chunk (only ever grown: a
        # long chunk after a short one, such as the recording after the calibration's warm-up
        # on a held frame, starts from its own guess instead of overflowing and running the
        # kernel twice); grown further on overflow
        self._ensure_cap(max(256, self.width * self._group * t.size // 2))
        seg = np.empty((t.size, self.height), np.int64)      # the kernel sets every entry
        while True:
            out_t, out_x, out_p = self._bufs
            _pixel_kernel(logf, decay, lin, self._lp_coef > 0, self._use_leak, self._shot_a > 0,
                          self._shot_a, self._shot_b, t, t0,
                          self.s_prev, self.lp, self.lraw, self.acc, self.ref, self.last_t, self.last_bin,
                          self.shot_hazard, self._noise_ctr, self._noise_key, self.thr_on, self.thr_off, self.drift,
                          float(self.degrade.refractory_us), float(self.degrade.sample_period_us),
                          out_t, out_x, out_p, seg, self._counts, self._bad, self._cap, self._group)
            bad = self._bad.any()
            need = int(self._counts.max())
            if bad or need > self._cap:
                for src, dst in zip(self._backup, self._state):
                    np.copyto(dst, src)
                if bad:
                    raise ValidationError("frames", "frames contain NaN or infinite values")
                self._ensure_cap(int(need * 1.25) + 16)
                continue
            break
        self.t_prev = t1
        n_kernel = int(self._counts.sum())
        d, rng = self.degrade, self.rng
        noise = []
        if self.hot_idx.size:
            noise.append(effects.hot_pixel_events(self.hot_idx, self.hot_on, d.hot_pixel_hz, t0, t1, self.width, rng))
        if not noise and not self._timing:
            arr = np.empty(n_kernel, EVENT_DTYPE)
            if arr.size:
                # a step holds few events, so a work item of PARALLEL_CHUNK steps costs less
                # than its scheduling: about GATHER_ITEMS_PER_THREAD items per thread
                chunk = max(PARALLEL_CHUNK, -(-t.size // (GATHER_ITEMS_PER_THREAD * get_num_threads())))
                with parallel_chunksize(chunk):
                    _gather_sorted(out_t, out_x, out_p, seg, self._cap, self._group, t, t0, arr)
            self.n_events += arr.shape[0]
            return Events(arr, self.width, self.height, validate=False)
        arr = self._assemble(seg, noise, n_kernel, t0, t1)
        if self._timing:
            # events of later chunks have t >= t1 + shift_lo: everything before is final
            cut = int(np.searchsorted(arr["t"], t1 + self._shift_lo, "left"))
            self._held = arr[cut:].copy()
            arr = arr[:cut]
        self.n_events += arr.shape[0]
        return Events(arr, self.width, self.height, validate=False)

    def _assemble(self, seg: np.ndarray, noise: list[np.ndarray], n_kernel: int, t0: int, t1: int) -> np.ndarray:
        """Held, kernel and noise events of the chunk, time-shifted (jitter, latency) and
        sorted in one fused pass (:func:`_assemble`)."""
        noise_arr = np.concatenate(noise) if len(noise) > 1 else (noise[0] if noise else np.empty(0, EVENT_DTYPE))
        held = self._held
        n_new = n_kernel + noise_arr.shape[0]
        sm = self._shifts
        if sm is None:
            mode, const, lo_s, hi_s, prob, alias, sig, lat = 0, 0, 0, 0, _ONE_F, _ZERO_I, 0.0, 0.0
            r = _EMPTY_F
            lo, hi = t0, t1
        else:
            mode, const, lo_s, hi_s, prob, alias, sig, lat = (sm.mode, sm.const_us, sm.lo_us, sm.hi_us, sm.prob,
                                                             sm.alias, sm.sigma_us, sm.latency_us)
            r = effects.draw_shift_randoms(sm, n_new, self.rng)
            lo, hi = max(t0 + self._shift_lo, self.t_start), t1 + self._shift_hi
        n_all = held.shape[0] + n_new
        span = hi - lo + 1
        counting = span <= 4 * n_all + 65536
        out = np.empty(n_all, EVENT_DTYPE)
        out_t, out_x, out_p = self._bufs
        need = (_SORT_BLOCKS + 2) * (span if counting else 1)
        if self._hist.size < need:
            self._hist = np.empty(need, np.int64)
        _assemble(out_t, out_x, out_p, seg, self._cap, self._group, held, noise_arr, mode, const, lo_s, hi_s,
                  prob, alias, r, sig, lat, np.int64(self.t_start), np.int64(lo), np.int64(span if counting else 1),
                  counting, self._hist, out)
        if not counting:
            out = out[np.argsort(out["t"], kind="stable")]
        return out

    def flush(self) -> Events:
        """Events held back for the jitter re-sort (call once at the end)."""
        arr, self._held = self._held, np.empty(0, EVENT_DTYPE)
        self.n_events += arr.shape[0]
        return Events(arr, self.width, self.height, validate=False)
