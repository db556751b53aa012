"""Recording-level API of the circuit event generator (:mod:`rdnet.circuit.pixel`).

Use::

    params = CircuitParams(threshold_on=0.2, threshold_off=0.2, refractory_us=500.0)
    events = generate(images, t_us, params, np.random.default_rng(0))   # rdnet Events

``images``: (N, H, W) float linear intensity in [0, 1] (or uint8 0..255) at ``t_us``;
the intensity is linear in time between them. The generator streams over the frame
intervals (the pixel state is carried from one interval to the next) and draws every random
number from the ``Generator`` it is given.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields

import numpy as np

from rdnet.circuit.pixel import advance
from rdnet.config import positive
from rdnet.errors import ConfigError, ValidationError
from rdnet.events.core import Events

log = logging.getLogger(__name__)

#: placeholder for random numbers an effect that is off does not need
_NONE = np.zeros((0, 0))

#: Lower clip of a mismatched threshold (log units).
MIN_THRESHOLD = 0.01


@dataclass(frozen=True)
class CircuitParams:
    """Parameters of the circuit pixel (all effects off at 0).

    ``threshold_on``/``threshold_off``  comparator thresholds on the change of the log
        photoreceptor output since the last reset (log units).
    ``threshold_sigma``  per-pixel Gaussian mismatch of each threshold, std as a fraction
        of the nominal one (clipped at :data:`MIN_THRESHOLD`).
    ``i_dark``  dark current, in units of full-scale intensity: the photoreceptor follows
        ``log(I + i_dark)`` and its bandwidth is proportional to ``I + i_dark``.
    ``photoreceptor_hz``  photoreceptor cutoff at full intensity I = 1 (0: infinite).
    ``follower_hz``  source-follower cutoff, independent of intensity (0: perfect buffer).
    ``voltage_noise``  Brownian noise of the follower output at I = 1 (log units per
        sqrt(s)); grows as ``1 / sqrt(I + i_dark)`` in the dark (0: off).
    ``refractory_us``  reset hold after each event (the pixel re-references on waking).
    ``shot_noise_hz``  rate of noise events per pixel in the dark; ``shot_noise_half``:
        the intensity at which it halves (``r(I) = r0 / (1 + I / half)``).
    ``leak_hz``  mean over pixels of the leak rate (ON events of a static pixel);
        ``leak_spread_decades``: std of log10 of the per-pixel rate.
    ``hot_pixel_fraction``/``hot_pixel_hz``  pixels with a large leakage and their rate.
    ``latency_us``/``jitter_us``  constant delay and Gaussian std of the timestamps.
    ``max_step_us``  longest integration sub-step.
    """

    threshold_on: float = 0.2
    threshold_off: float = 0.2
    threshold_sigma: float = 0.0
    i_dark: float = 0.01
    photoreceptor_hz: float = 0.0
    follower_hz: float = 0.0
    voltage_noise: float = 0.0
    refractory_us: float = 0.0
    shot_noise_hz: float = 0.0
    shot_noise_half: float = 0.1
    leak_hz: float = 0.0
    leak_spread_decades: float = 0.1
    hot_pixel_fraction: float = 0.0
    hot_pixel_hz: float = 0.0
    latency_us: float = 0.0
    jitter_us: float = 0.0
    max_step_us: float = 250.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"circuit.{f.name}", f"expected a finite number, got {v!r}")
            strict = f.name in ("threshold_on", "threshold_off", "i_dark", "shot_noise_half", "max_step_us")
            positive(f"circuit.{f.name}", v, allow_zero=not strict)
        if self.hot_pixel_fraction > 1:
            raise ConfigError("circuit.hot_pixel_fraction", f"must be <= 1, got {self.hot_pixel_fraction}")

    @property
    def onoff_ratio(self) -> float:
        return self.threshold_on / self.threshold_off


#: CircuitParams fields that carry the same name and meaning as an rdnet ``degrade`` key
#: (so fitted values compare with the truth), and where the meaning differs:
#: ``refractory_us``  same meaning: the pixel is held in reset and re-references at wake-up.
#: ``shot_noise_hz``  both: the dark rate; rdnet's falls linearly to 0.25x at I = 1, this
#:     one as 1 / (1 + I / 0.1) (0.09x at I = 1); in both, noise events reset the pixel.
#: ``leak_hz``  same drift model in both (ON events of a static pixel at that mean rate).
#: ``hot_pixel_*``  rdnet: Poisson events, ON with a per-pixel probability (default: one
#:     random polarity per pixel; ``hot_pixel_on_fraction``, ``hot_pixel_polarity_concentration``);
#:     here: periodic ON events from a large leak (rdnet's ``hot_pixel_on_fraction`` 1).
#: ``latency_us``/``jitter_us``  same meaning (rdnet truncates the Gaussian at 4 std).
#: ``threshold_sigma``  same meaning.
DEGRADE_EQUIVALENT: tuple[str, ...] = ("threshold_sigma", "refractory_us", "shot_noise_hz", "leak_hz",
                                       "leak_spread_decades", "hot_pixel_fraction", "hot_pixel_hz",
                                       "latency_us", "jitter_us")


def from_degrade(sensor, degrade, **extra) -> CircuitParams:
    """The circuit with the values of an rdnet ``sensor``/``degrade`` pair where the
    meaning carries over: thresholds (``onoff_ratio`` applied keeping their geometric
    mean), ``log_eps`` -> ``i_dark``, ``cutoff_hz`` -> ``photoreceptor_hz`` (both the
    cutoff at I = 1, falling with intensity: rdnet's with the floor ``cutoff_floor``, 20/255
    of full scale by default, this one with its dark current ``i_dark``; so rdnet's
    ``cutoff_floor`` has no separate counterpart here), and :data:`DEGRADE_EQUIVALENT`. ``sample_period_us`` has
    no counterpart (rejected when on). ``extra``: CircuitParams fields to set."""
    if getattr(degrade, "sample_period_us", 0.0):
        raise ConfigError("degrade.sample_period_us", "the circuit generator has no readout period")
    r = math.sqrt(degrade.onoff_ratio)
    vals = {k: float(getattr(degrade, k)) for k in DEGRADE_EQUIVALENT}
    vals.update(threshold_on=sensor.threshold_on * r, threshold_off=sensor.threshold_off / r,
                i_dark=sensor.log_eps, photoreceptor_hz=degrade.cutoff_hz)
    vals.update(extra)
    return CircuitParams(**vals)


def pixel_parameters(n_pix: int, params: CircuitParams, rng: np.random.Generator
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel ``(theta_on, theta_off, leak rate per us)`` (a hot pixel: its leak rate is
    ``hot_pixel_hz``), drawn in a fixed order (ON mismatch, OFF mismatch, leak spread, hot
    pixels) whatever is switched on, so one seed gives the same pixels across configs."""
    n_on = rng.standard_normal(n_pix)
    n_off = rng.standard_normal(n_pix)
    n_leak = rng.standard_normal(n_pix)
    order = rng.permutation(n_pix)
    s = params.threshold_sigma
    thr_on = np.maximum(params.threshold_on * (1.0 + s * n_on), MIN_THRESHOLD)
    thr_off = np.maximum(params.threshold_off * (1.0 + s * n_off), MIN_THRESHOLD)
    d = params.leak_spread_decades
    spread = 10.0 ** (d * n_leak) / math.exp(0.5 * (d * math.log(10.0)) ** 2)   # mean 1
    leak = params.leak_hz * 1e-6 * spread
    n_hot = int(round(params.hot_pixel_fraction * n_pix))
    if n_hot and params.hot_pixel_hz > 0:
        leak[order[:n_hot]] = params.hot_pixel_hz * 1e-6
    return thr_on, thr_off, leak


def _as_linear(images: np.ndarray) -> np.ndarray:
    im = np.asarray(images)
    if im.ndim != 3:
        raise ValidationError("frames/images", f"the circuit generator takes (N, H, W) grey frames, got {im.shape}")
    if im.dtype == np.uint8:
        return im.astype(np.float64) / 255.0
    return im.astype(np.float64)


#: sub-step of the warm-up on a held frame: the input is constant, so only the shot noise's
#: one-event-per-sub-step limit depends on it (at 5 ms and 2 Hz, 0.5 % of the noise events)
WARMUP_STEP_US = 5_000.0


def generate(images: np.ndarray, t_us: np.ndarray, params: CircuitParams, rng: np.random.Generator,
             *, random_start: bool = True, warmup_us: float = 0.0) -> Events:
    """Events of the circuit pixel array for frames ``images`` at ``t_us``.

    ``random_start``: every pixel starts with its memorised level at a uniformly random
    point between its thresholds (an unknown state, as at the start of a real recording);
    False: at the input (a pixel just reset). Photoreceptor and follower start in steady
    state. ``warmup_us``: the array first runs that long on the first frame held still
    (sub-steps of :data:`WARMUP_STEP_US`; its events are dropped), so noise resets and leak
    drift leave every pixel where a sensor that has been running has it.
    Timestamps are integer microseconds from ``t_us[0]``'s clock."""
    im = _as_linear(images)
    t = np.asarray(t_us, np.int64)
    if len(t) < 2 or np.any(np.diff(t) <= 0):
        raise ValidationError("frames/t", "need >= 2 frames with increasing timestamps")
    if not warmup_us >= 0:
        raise ValidationError("warmup_us", f"must be >= 0, got {warmup_us}")
    n, H, W = im.shape
    P = H * W
    thr_on, thr_off, leak = pixel_parameters(P, params, rng)
    first = im[0].ravel()
    vp = np.log(first + params.i_dark)
    vs = vp.copy()
    vmem = vs - (-thr_off + rng.random(P) * (thr_on + thr_off)) if random_start else vs.copy()
    wake = np.full(P, -np.inf)
    w_p = 2 * math.pi * params.photoreceptor_hz * 1e-6
    w_s = 2 * math.pi * params.follower_hz * 1e-6
    sig = params.voltage_noise * 1e-3            # per sqrt(s) -> per sqrt(us)
    shot = params.shot_noise_hz * 1e-6
    refr = float(params.refractory_us)
    cap = 4 * P + 1024
    parts_t, parts_p, parts_x = [], [], []
    # (I0, I1, t0, t1, sub-steps, keep the events): the warm-up on the held first frame, then the frames
    n_warm = int(math.ceil(warmup_us / WARMUP_STEP_US))
    t_warm = np.linspace(float(t[0]) - warmup_us, float(t[0]), n_warm + 1)
    steps = [(first, first, t_warm[j], t_warm[j + 1], 1, False) for j in range(n_warm)]
    steps += [(im[i].ravel(), im[i + 1].ravel(), float(t[i]), float(t[i + 1]),
               max(1, int(math.ceil((t[i + 1] - t[i]) / params.max_step_us))), True) for i in range(n - 1)]
    for I0, I1, t0, t1, nsub, keep in steps:
        u_noise = rng.random((P, nsub)) if shot > 0 else _NONE
        u_pol = rng.random((P, nsub)) if shot > 0 else _NONE
        z = rng.standard_normal((P, nsub)) if sig > 0 else _NONE
        state = (vp.copy(), vs.copy(), vmem.copy(), wake.copy())
        while True:
            ot, op, ox = np.empty(cap), np.empty(cap, np.uint8), np.empty(cap, np.int64)
            k = advance(I0, I1, t0, t1, nsub, params.i_dark, w_p, w_s, sig, refr, shot, params.shot_noise_half,
                        thr_on, thr_off, leak, vp, vs, vmem, wake, u_noise, u_pol, z, ot, op, ox)
            if k >= 0:
                break
            vp, vs, vmem, wake = (a.copy() for a in state)      # buffer full: redo from the saved state
            cap *= 4
        if keep:
            parts_t.append(ot[:k])
            parts_p.append(op[:k])
            parts_x.append(ox[:k])
    te = np.concatenate(parts_t) if parts_t else np.empty(0)
    pe = np.concatenate(parts_p) if parts_p else np.empty(0, np.uint8)
    xe = np.concatenate(parts_x) if parts_x else np.empty(0, np.int64)
    te = te + params.latency_us
    if params.jitter_us > 0:
        te = te + params.jitter_us * rng.standard_normal(te.shape[0])
    ti = np.maximum(np.floor(te), float(t[0])).astype(np.int64)
    return Events.from_columns(ti, (xe % W).astype(np.uint16), (xe // W).astype(np.uint16), pe, W, H, sort=True)
