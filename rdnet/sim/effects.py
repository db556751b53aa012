"""Real-sensor degradations of the DVS model (keys of :class:`DegradeConfig`).

The per-pixel effects that act *inside* the pixel (threshold mismatch, ON/OFF ratio,
photoreceptor bandwidth, refractory period, limited readout, leak) are evaluated in the
fused per-pixel kernel of :mod:`rdnet.sim.sensor`; this module holds their parameters,
equations and the vectorized per-chunk effects (shot noise, hot pixels, timestamp jitter
and latency). Every effect is off at 0 (``onoff_ratio`` at 1).

Pixel model (Lichtsteiner, Posch, Delbruck, "A 128x128 120 dB 15 us latency asynchronous
temporal contrast vision sensor", IEEE JSSC 2008): the photoreceptor output follows the log
intensity ``L = log(I + log_eps)``; the pixel memorises a reference level ``ref`` at its
last event and emits an ON (OFF) event when ``L - ref >= theta_on`` (``<= -theta_off``);
then ``ref`` moves by one threshold (ESIM, Rebecq, Gehrig, Scaramuzza, CoRL 2018).

Effects and the sources they follow:

* ``threshold_sigma`` (v2e, Hu, Liu, Delbruck, CVPRW 2021, Sec. 3.1; ESIM Sec. 3):
  ``theta_c(x, y) = theta_c * (1 + sigma * n_c(x, y))``, ``n_c ~ N(0, 1)`` independent for
  c in {ON, OFF} and per pixel, drawn once per sequence; clipped below at
  :data:`MIN_THRESHOLD` (v2e clips at 0.01) so thresholds stay > 0.
* ``onoff_ratio`` r: ``theta_on = theta_on0 * sqrt(r)``, ``theta_off = theta_off0 / sqrt(r)``;
  the geometric mean ``sqrt(theta_on theta_off)`` of the nominal thresholds is kept and
  ``theta_on / theta_off = r * theta_on0 / theta_off0``.
* ``cutoff_hz`` f0 (v2e Sec. 3.2, ``emulator_utils.low_pass_filter``): first-order low-pass
  of the log intensity whose cutoff is proportional to intensity,
  ``f(I) = f0 (I + floor) / (1 + floor)`` with ``floor`` = ``cutoff_floor``, the
  photoreceptor's dark current relative to full scale (default :data:`CUTOFF_FLOOR`, v2e's
  ``(I255 + 20) / 275``), so dark pixels are slower; discretised exactly for a step dt:
  ``lp <- lp + alpha (L - lp)``, ``alpha = 1 - exp(-2 pi f(I) dt)``.
* ``refractory_us`` R (v2e Sec. 3.4; DVS-Voltmeter, Lin et al., ECCV 2022): after an event
  at t_e the pixel is held in reset until t_e + R (Lichtsteiner 2008: the reset switch of
  the differencing amplifier stays closed), so it emits nothing and its reference follows
  the input: at the wake-up ``ref = S(t_e + R)`` exactly, and the next event needs a full
  threshold of change from there. No burst follows the dead time, and the change during
  it is lost entirely. On a ramp of slope k the intervals are R + theta / k. (Until
  2026-11 the reference moved by whole thresholds during the dead time, keeping the
  residual below one threshold: intervals were multiples of theta / k of at least R.)
* ``sample_period_us`` P (limited readout bandwidth, RDNet paper Fig. 2b): the readout
  services each pixel at most once per period ``[m P, (m + 1) P)``; further crossings of
  the pixel in the same period are lost and ``ref`` moves by one threshold per lost
  crossing (the pixel is not reset), so fast changes lose events, and two events can
  sit either side of a period edge. Timestamps keep the crossing time.
* ``shot_noise_hz`` R (v2e Sec. 3.5, ``generate_shot_noise``): Poisson noise events,
  balanced ON/OFF, rate per pixel ``R (1 + (b - 1) min(I, 1))`` with
  ``b = shot_noise_bright_factor`` (v2e ``SHOT_NOISE_INTEN_FACTOR`` = 0.25): R in the dark,
  ``b R`` at full intensity (constant within a frame step). A noise event is a comparator
  firing (Lichtsteiner 2008; DVS-Voltmeter, Lin et al., ECCV 2022): it is simulated in the
  pixel kernel of :mod:`rdnet.sim.sensor`, is lost in the refractory or readout period of
  the pixel's last event like any other, and when emitted it **resets** the pixel: the
  reference takes the current log intensity (then the refractory hold). So shot noise
  restarts the leak's accumulation (leak events become rarer under noise: a static pixel
  with leak rate l and noise rate R leaks only when no noise event came for 1 / l) and
  clears the residual of a moving pixel. (Until 2026-11 noise events were added to the
  output and did not touch the reference.)
* ``leak_hz`` (v2e Sec. 3.5, leak events; Nozaki & Delbruck, IEEE TED 2017): junction
  leakage makes the reference drift down, ``d ref / dt = -leak_rate(x, y) theta_on(x, y)``,
  so a static pixel emits ON events at ``leak_rate``; per-pixel rates are log-normal,
  ``leak_rate = leak_hz 10^(s n) / E[10^(s n)]`` with ``s = leak_spread_decades`` (mean over
  pixels = ``leak_hz``), and the initial reference is lowered by ``u theta_on``,
  ``u ~ U(0, 1)``, so the leak phases are random (v2e).
* ``hot_pixel_fraction``/``hot_pixel_hz``: ``round(fraction H W)`` pixels, chosen once per
  sequence, emit Poisson events at ``hot_pixel_hz`` regardless of the scene. Polarity
  (``hot_pixel_on_fraction`` m, ``hot_pixel_polarity_concentration`` k): hot pixel i fires ON
  with probability ``q_i ~ Beta(k m, k (1 - m))``; k = 0 (default) is the limit where each
  hot pixel has one fixed polarity, ON with probability m (default 1/2). Real hot pixels
  mostly fire both polarities, leaning ON (DVXplorer: 29 of 34, m 0.66, k 2.9; docs/calibration.md
  "Hot-pixel polarity").
* ``jitter_us`` s and ``latency_us`` d (v2e Sec. 3.4 timestamp jitter; DVS-Voltmeter):
  ``t' = t + round(d + s z)``, ``z ~ N(0, 1)`` truncated to [-4, 4] (clipped: the mass
  beyond +-4 sits at +-4), ``round(v) = floor(v + 0.5)``, events re-sorted; times are
  clipped at the sequence start. The shift ``m`` is an integer with the exact law
  ``P(m <= k) = Phi((k + 0.5 - d) / s)`` for ``(k + 0.5 - d) / s`` in (-4, 4] (0 below, 1
  above), so it is drawn from that table with one uniform per event (alias method,
  Walker, ACM TOMS 1977; construction of Vose, IEEE TSE 1991) rather than through a
  normal draw; tables above :data:`MAX_SHIFT_TABLE` entries fall back to one normal per
  event.

Layering: this module imports nothing from :mod:`rdnet.sim.sensor` (the sensor imports it).
The jitted loops that apply a :class:`ShiftSampler` live in the sensor, next to the kernels
that inline them (:func:`rdnet.sim.sensor.apply_timing` for a standalone array).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from rdnet.events.core import EVENT_DTYPE
from rdnet.sim.settings import DegradeConfig, SensorConfig

#: Lower clip of mismatched thresholds in log units (v2e).
MIN_THRESHOLD = 0.01
#: Default intensity floor of the photoreceptor bandwidth, relative to full scale (v2e:
#: 20/255; ``degrade.cutoff_floor``).
CUTOFF_FLOOR = DegradeConfig.cutoff_floor
#: Truncation of the Gaussian timestamp jitter, in standard deviations.
JITTER_TRUNCATE = 4.0
#: Most entries of the jitter alias table (8 jitter_us + 2); wider jitter draws normals.
MAX_SHIFT_TABLE = 1 << 20


# --- per-sequence pixel parameters -----------------------------------------------------

def pixel_thresholds(height: int, width: int, sensor: SensorConfig, degrade: DegradeConfig,
                     rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray]:
    """(theta_on, theta_off), each (H, W) float64: nominal thresholds with the ON/OFF
    ratio and the per-pixel Gaussian mismatch applied (see the module docstring)."""
    root = math.sqrt(degrade.onoff_ratio)
    on = np.full((height, width), sensor.threshold_on * root)
    off = np.full((height, width), sensor.threshold_off / root)
    if degrade.threshold_sigma > 0:
        s = degrade.threshold_sigma
        on *= 1.0 + s * rng.standard_normal((height, width))
        off *= 1.0 + s * rng.standard_normal((height, width))
        np.maximum(on, MIN_THRESHOLD, out=on)
        np.maximum(off, MIN_THRESHOLD, out=off)
    return on, off


def leak_rates(height: int, width: int, degrade: DegradeConfig,
               rng: np.random.Generator | None) -> np.ndarray:
    """(H, W) float64 per-pixel leak rate in Hz, log-normal with mean ``leak_hz``."""
    if degrade.leak_hz <= 0:
        return np.zeros((height, width))
    s = degrade.leak_spread_decades * math.log(10.0)
    # E[exp(s n)] = exp(s^2 / 2): normalise so the mean rate over pixels is leak_hz
    return degrade.leak_hz * np.exp(s * rng.standard_normal((height, width)) - 0.5 * s * s)


def leak_phase(height: int, width: int, degrade: DegradeConfig,
               rng: np.random.Generator | None) -> np.ndarray:
    """(H, W) initial lowering of the reference in units of theta_on (U(0,1) when leak is on)."""
    if degrade.leak_hz <= 0:
        return np.zeros((height, width))
    return rng.random((height, width))


def hot_pixels(height: int, width: int, degrade: DegradeConfig,
               rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray]:
    """(flat pixel indices int64 sorted, ON probability float64 per pixel) of the hot
    pixels: with ``hot_pixel_polarity_concentration`` k = 0 each fires one polarity (1.0 or
    0.0, ON with probability ``hot_pixel_on_fraction`` m), with k > 0 pixel i fires ON with
    probability q_i ~ Beta(k m, k (1 - m)) (mean m; the ON/OFF mix of real hot pixels)."""
    n = int(round(degrade.hot_pixel_fraction * height * width))
    if n == 0 or degrade.hot_pixel_hz <= 0:
        return np.empty(0, np.int64), np.empty(0, np.float64)
    idx = np.sort(rng.choice(height * width, size=n, replace=False)).astype(np.int64)
    m, k = degrade.hot_pixel_on_fraction, degrade.hot_pixel_polarity_concentration
    if k > 0 and 0.0 < m < 1.0:
        return idx, rng.beta(k * m, k * (1.0 - m), n)
    return idx, (rng.random(n) < m).astype(np.float64)


def fit_hot_pixel_polarity(on_counts: np.ndarray, counts: np.ndarray) -> tuple[float, float]:
    """``(hot_pixel_on_fraction, hot_pixel_polarity_concentration)`` of hot pixels with
    ``on_counts`` ON events out of ``counts`` (one entry per hot pixel; at least two with 2+
    events), by the method of moments of the Beta-binomial model of :mod:`rdnet.sim.effects`:
    m = the mean per-pixel ON share; k = m (1 - m) / v - 1 with v the variance of the shares
    less their binomial part (sum of q (1 - q) / (n - 1), unbiased). ``k`` is 0 when v reaches
    m (1 - m) (one polarity per pixel) and ``inf`` when v <= 0 (all pixels alike)."""
    on = np.asarray(on_counts, np.float64)
    n = np.asarray(counts, np.float64)
    keep = n >= 2
    if keep.sum() < 2:
        raise ValueError("fit_hot_pixel_polarity needs two hot pixels with two or more events each")
    q = on[keep] / n[keep]
    m = float(q.mean())
    v = float(q.var(ddof=1) - np.mean(q * (1.0 - q) / (n[keep] - 1.0)))
    if m <= 0.0 or m >= 1.0 or v <= 0.0:
        return m, float("inf")
    return m, float(max(m * (1.0 - m) / v - 1.0, 0.0))


# --- in-kernel coefficients ------------------------------------------------------------

def cutoff_at(cutoff_hz: float, floor: float, intensity):
    """The photoreceptor cutoff (Hz) at linear ``intensity``: ``cutoff_hz (I + floor) / (1 +
    floor)`` (``cutoff_hz`` is the cutoff at I = 1, ``floor`` = ``degrade.cutoff_floor``)."""
    return cutoff_hz * (intensity + floor) / (1.0 + floor)


def lowpass_coef(degrade: DegradeConfig) -> float:
    """``c`` such that ``alpha = 1 - exp(-c dt_us (I + floor))`` (0 = filter off; ``floor``:
    ``degrade.cutoff_floor``)."""
    if degrade.cutoff_hz <= 0:
        return 0.0
    return 2.0 * math.pi * degrade.cutoff_hz * 1e-6 / (1.0 + degrade.cutoff_floor)


def shot_rate_coefs(degrade: DegradeConfig) -> tuple[float, float]:
    """``(a, b)`` with the shot-noise rate ``a + b min(I, 1)`` in events per microsecond."""
    r = degrade.shot_noise_hz * 1e-6
    return r, r * (degrade.shot_noise_bright_factor - 1.0)


# --- vectorized per-chunk effects ------------------------------------------------------

def hot_pixel_events(pixels: np.ndarray, on_prob: np.ndarray, rate_hz: float, t0: int, t1: int,
                     width: int, rng: np.random.Generator) -> np.ndarray:
    """The hot pixels' events of [t0, t1): hot pixel i (flat index ``pixels[i]``) gets
    ``Poisson(rate_hz (t1 - t0))`` events at uniform times, each ON with probability
    ``on_prob[i]`` (:func:`hot_pixels`; no draw where it is 0 or 1). Returns an EVENT_DTYPE
    array grouped by pixel (not sorted)."""
    counts = rng.poisson(np.full(pixels.size, rate_hz * (int(t1) - int(t0)) * 1e-6))
    n = int(counts.sum())
    idx = np.repeat(pixels, counts)
    span = max(int(t1) - int(t0), 1)
    out = np.empty(n, EVENT_DTYPE)
    out["t"] = int(t0) + np.floor(rng.random(n) * span).astype(np.int64)
    on = np.asarray(on_prob, np.float64)
    if np.all((on == 0.0) | (on == 1.0)):              # one polarity per pixel: no draw
        out["p"] = np.repeat(on.astype(np.uint8), counts)
    else:
        out["p"] = (rng.random(n) < np.repeat(on, counts)).astype(np.uint8)
    y, x = np.divmod(idx, width)
    out["x"], out["y"] = x, y
    return out


def timing_shift_bounds(degrade: DegradeConfig) -> tuple[int, int]:
    """(smallest, largest) integer shift that :func:`rdnet.sim.sensor.apply_timing` can add."""
    s = JITTER_TRUNCATE * degrade.jitter_us
    return int(math.floor(degrade.latency_us - s)), int(math.ceil(degrade.latency_us + s))


@dataclass(frozen=True)
class ShiftSampler:
    """How the timestamp shift of an event is drawn (see :func:`shift_sampler`).

    ``mode`` 0: constant ``const_us`` (latency only, no randomness); 1: alias table, shift
    ``lo_us + j`` with ``j`` from ``prob``/``alias`` and one uniform per event; 2: one
    standard normal per event, ``floor(latency + sigma clip(z, -4, 4) + 0.5)``.
    ``lo_us``/``hi_us`` bound every shift."""

    mode: int
    const_us: int
    lo_us: int
    hi_us: int
    prob: np.ndarray
    alias: np.ndarray
    sigma_us: float
    latency_us: float


def shift_pmf(degrade: DegradeConfig) -> tuple[int, np.ndarray]:
    """``(lo, p)``: ``P(shift = lo + j) = p[j]`` for the jitter/latency shift
    ``floor(d + s clip(z, -4, 4) + 0.5)``, ``z ~ N(0, 1)``: with
    ``q_k = (k + 0.5 - d) / s``, ``P(shift <= k) = 0`` for ``q_k <= -4``, ``Phi(q_k)`` for
    ``-4 < q_k <= 4`` and ``1`` for ``q_k > 4``."""
    lo, hi = timing_shift_bounds(degrade)
    d, s = float(degrade.latency_us), float(degrade.jitter_us)
    k = np.arange(lo, hi + 1, dtype=np.float64)
    q = (k + 0.5 - d) / s
    cdf = _phi(q)
    cdf[q <= -JITTER_TRUNCATE] = 0.0
    cdf[q > JITTER_TRUNCATE] = 1.0
    cdf[-1] = 1.0                      # q at hi is > 4 by construction of the bounds
    return lo, np.diff(np.concatenate([[0.0], cdf]))


@njit(cache=True)
def _phi(q):
    """Standard normal CDF, ``Phi(q) = erfc(-q / sqrt(2)) / 2`` (accurate in the lower tail)."""
    out = np.empty(q.shape[0])
    for i in range(q.shape[0]):
        out[i] = 0.5 * math.erfc(-q[i] / math.sqrt(2.0))
    return out


@njit(cache=True)
def alias_table(p):
    """Walker's alias table of the probabilities ``p`` (Vose's stable construction):
    with ``x = u n`` (u uniform in [0, 1)), ``j = floor(x)``, the draw is ``j`` if
    ``x - j < prob[j]`` else ``alias[j]``; it has law ``p`` exactly up to rounding."""
    n = p.shape[0]
    tot = p.sum()
    scaled = p * (n / tot)
    prob = np.ones(n)
    alias = np.arange(n)
    small = np.empty(n, np.int64)
    large = np.empty(n, np.int64)
    ns = nl = 0
    for i in range(n):
        if scaled[i] < 1.0:
            small[ns] = i
            ns += 1
        else:
            large[nl] = i
            nl += 1
    while ns > 0 and nl > 0:
        ns -= 1
        s = small[ns]
        g = large[nl - 1]
        prob[s] = scaled[s]
        alias[s] = g
        scaled[g] = (scaled[g] + scaled[s]) - 1.0
        if scaled[g] < 1.0:
            nl -= 1
            small[ns] = g
            ns += 1
    # leftovers are 1 up to rounding
    return prob, alias


def shift_sampler(degrade: DegradeConfig) -> ShiftSampler:
    """The sampler of the per-event timestamp shift (jitter and latency)."""
    lo, hi = timing_shift_bounds(degrade)
    empty_f, empty_i = np.ones(1), np.zeros(1, np.int64)
    d, s = float(degrade.latency_us), float(degrade.jitter_us)
    if s <= 0:
        c = int(math.floor(d + 0.5))
        return ShiftSampler(0, c, c, c, empty_f, empty_i, 0.0, d)
    if hi - lo + 1 <= MAX_SHIFT_TABLE:
        tab_lo, p = shift_pmf(degrade)
        prob, alias = alias_table(p)
        return ShiftSampler(1, 0, tab_lo, hi, prob, alias, s, d)
    # mode 2 clips the unclipped shift to the shifts of z = -4 and z = +4
    return ShiftSampler(2, 0, int(math.floor(d - JITTER_TRUNCATE * s + 0.5)),
                        int(math.floor(d + JITTER_TRUNCATE * s + 0.5)), empty_f, empty_i, s, d)


def draw_shift_randoms(sampler: ShiftSampler, n: int, rng: np.random.Generator | None) -> np.ndarray:
    """The random numbers of ``n`` shifts (in event order): uniforms (mode 1), normals
    (mode 2) or none (mode 0)."""
    if sampler.mode == 1:
        return rng.random(n)
    if sampler.mode == 2:
        return rng.standard_normal(n)
    return np.empty(0)


def needs_rng(degrade: DegradeConfig) -> bool:
    """Whether any active effect draws random numbers."""
    return any(getattr(degrade, k) > 0 for k in
               ("threshold_sigma", "shot_noise_hz", "leak_hz", "hot_pixel_fraction", "jitter_us"))
