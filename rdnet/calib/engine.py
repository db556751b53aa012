"""How the calibration simulates a parameter set: the project's pixel model
(:class:`rdnet.sim.sensor.Sensor`) for what happens *inside* the pixel (shot noise
included: its events reset the pixel), composed with the additive hot-pixel and timestamp
effects of :mod:`rdnet.sim.effects`, and summarised
directly into the statistics of :mod:`rdnet.calib.stats`.

The search evaluates hundreds of parameter sets on the same frames, and part of the
vocabulary does not change what the pixel circuit emits: hot pixels add events, jitter
and latency move them. :class:`Engine` therefore splits a config in two:

* the **kernel** part (thresholds, mismatch, ON/OFF ratio, bandwidth, refractory period,
  readout period, leak, shot noise, whose events reset the pixel): simulated by
  ``Sensor`` from log frames computed once per context, and cached per (kernel config,
  seed) (a small LRU);
* the **additive** part (hot pixels, jitter, latency): drawn on top of the cached kernel
  events with the simulator's own functions (:func:`effects.hot_pixel_events`,
  :func:`effects.hot_pixels`, :func:`rdnet.sim.sensor.apply_timing`), exactly as
  ``Sensor.step`` composes them for a single chunk.

The composition gives the same events as :func:`rdnet.sim.pair.simulate` with one chunk
for every deterministic config when ``random_reference`` is off (tested), and the same distribution for random ones (the
random numbers are drawn in another order: each component has its own stream derived
from the seed, which also makes the draws common to candidates that share a component).
"""
from __future__ import annotations

import dataclasses
from collections import OrderedDict

import numpy as np

from rdnet.calib.context import CalibContext
from rdnet.calib.stats import Summary, summarize_arrays
from rdnet.events.core import Events
from rdnet.sim import effects
from rdnet.sim.sensor import Sensor, apply_timing, sort_events
from rdnet.sim.settings import DegradeConfig, SensorConfig

#: degrade keys that act on the events after the pixel circuit (composed by the engine)
ADDITIVE_KEYS = ("hot_pixel_fraction", "hot_pixel_hz", "hot_pixel_on_fraction", "hot_pixel_polarity_concentration",
                 "jitter_us", "latency_us")
#: stream ids of the per-component random generators (np.random.default_rng([seed, id]))
#: (1 was the additive shot noise's until shot-noise events reset the pixel, 2026-11)
_KERNEL, _HOT, _TIMING, _REFERENCE = 0, 2, 3, 4
#: frame step of the warm-up on a held frame (the kernel's noise and leak are exact within a step)
WARMUP_STEP_US = 50_000


def randomize_reference(sensor: Sensor, degrade: DegradeConfig, u: np.ndarray,
                        where: np.ndarray | None = None) -> None:
    """Move the reference of every pixel of ``sensor`` (or of the pixels ``where``, (H, W)
    bool) to ``S + theta_off - u (theta_on + theta_off)``, ``u`` (H, W) in [0, 1), ``S`` the
    level the sensor holds (the first frame's, right after it set the state): the log
    intensity then sits uniformly between the OFF and the ON threshold, the stationary
    state of a pixel that has seen changes before the recording starts (the simulator's
    own start, ``ref = L0``, puts every pixel exactly between them). Without ``where`` a
    config with a leak keeps the sensor's own random leak phase."""
    if where is None and degrade.leak_hz > 0:
        return
    m = np.ones(sensor.ref.shape, bool) if where is None else np.asarray(where, bool)
    if m.shape != sensor.ref.shape:
        raise ValueError(f"pixel mask {m.shape} does not match the sensor {sensor.ref.shape}")
    sensor.ref[m] = sensor.s_prev[m] + sensor.thr_off[m] - u[m] * (sensor.thr_on[m] + sensor.thr_off[m])


def warms_up(degrade: DegradeConfig) -> bool:
    """Whether a simulation of ``degrade`` warms up before the recording: with leak (the
    phase of a static pixel, its drift since the last noise or leak event, decides when its
    first leak event comes) or shot noise (whose events reset the pixel, so a static pixel
    sits at its last reset, not at a random point). Without either a held frame changes
    nothing."""
    return degrade.leak_hz > 0 or degrade.shot_noise_hz > 0


def start(sensor: Sensor, degrade: DegradeConfig, frame: np.ndarray, t0: int, u: np.ndarray | None,
          warmup_us: int, *, moving: np.ndarray | None = None, log: bool = False) -> bool:
    """Set the state of a fresh ``sensor`` as it is when a recording starts at ``t0``: the
    pixels have been running before. Their reference starts at a random point between the
    thresholds (:func:`randomize_reference`, ``u``; None: at the input), then, when
    :func:`warms_up` (leak or shot noise), they run for ``warmup_us`` on ``frame`` (1, H, W)
    held still, so leak (the reference drifts) and shot noise (each event resets the pixel)
    bring every static pixel to its stationary state; those events are dropped. Without the
    warm-up a static pixel under leak starts anywhere below its ON threshold, while one that
    has been running sits at its age since the last noise or leak event (a truncated
    exponential under noise resets): in a recording shorter than 1 / leak the first leak
    events come from that start alone.

    ``moving`` (H, W) bool: pixels whose scene moves in the recording. The scene did not
    hold still for them before it (a noise reset during a held frame would put their
    reference at that frame's level), so after the warm-up their reference is drawn
    between the thresholds again from ``u`` (:func:`randomize_reference`, leak or not),
    around the level the warm-up left (leak drift included). Returns whether it warmed up
    (events before ``t0`` may then follow)."""
    warm = warmup_us > 0 and warms_up(degrade)
    t_start = t0 - int(warmup_us) if warm else t0
    sensor.step(frame, np.array([t_start], np.int64), log=log)
    if u is not None:
        randomize_reference(sensor, degrade, u)
    if warm:
        t = np.linspace(t_start, t0, max(2, -(-int(warmup_us) // WARMUP_STEP_US) + 1)).round().astype(np.int64)[1:]
        sensor.step(np.repeat(frame, t.size, axis=0), t, log=log)
        if moving is not None and u is not None:
            randomize_reference(sensor, degrade, u, where=moving)
    return warm


def simulate_random_start(images: np.ndarray, t_us: np.ndarray, sensor: SensorConfig, degrade: DegradeConfig,
                          rng: np.random.Generator | None, ref_rng: np.random.Generator,
                          warmup_us: int = 0) -> Events:
    """:func:`rdnet.sim.pair.simulate` of (N, H, W) linear frames (already upsampled) with
    every pixel's reference started at a random point between its thresholds
    (:func:`randomize_reference`, ``u`` drawn from ``ref_rng``) and, with ``warmup_us``,
    warmed up on the first frame held still (:func:`start`): a recording's events, whose
    pixels were in an unknown state when it started. Events before ``t_us[0]`` are dropped."""
    n, h, w = images.shape
    s = Sensor(w, h, sensor, degrade, rng)
    t0 = int(t_us[0])
    warm = start(s, degrade, images[:1], t0, ref_rng.random((h, w)), warmup_us)
    parts = [s.step(images[1:], t_us[1:]).array, s.flush().array]
    arr = sort_events(np.concatenate(parts))
    if warm:                     # jitter may hold warm-up events back past the first frame's step
        arr = arr[arr["t"] >= t0]
    return Events(arr, w, h, validate=False)


def _kernel_degrade(degrade: DegradeConfig) -> DegradeConfig:
    off = {k: 0.0 for k in ADDITIVE_KEYS}
    return dataclasses.replace(degrade, **off)


def kernel_key(sensor: SensorConfig, degrade: DegradeConfig) -> tuple:
    """What the pixel-circuit events of a config depend on (the cache key, seed aside)."""
    d = _kernel_degrade(degrade)
    return (round(sensor.threshold_on, 12), round(sensor.threshold_off, 12), round(sensor.log_eps, 12),
            tuple(round(float(getattr(d, f.name)), 12) for f in dataclasses.fields(d)))


class Engine:
    """Simulations of one context's upsampled frames (see the module docstring).

    ``cache_size``: kernel event sets kept (each holds one simulation's events).
    ``random_reference``: start every pixel's reference at a random point between its
    thresholds, drawn per seed (default ``ctx.cfg.random_reference``; see
    :meth:`kernel_events`). ``warmup_us``: how long the pixels run on the first frame held
    still before the recording (default ``ctx.cfg.warmup_us``; :func:`start`; the moving
    pixels' reference is drawn again after it)."""

    def __init__(self, ctx: CalibContext, cache_size: int = 24, random_reference: bool | None = None,
                 warmup_us: int | None = None):
        self.ctx = ctx
        self.random_reference = bool(ctx.cfg.random_reference if random_reference is None else random_reference)
        self.warmup_us = int(ctx.cfg.warmup_us if warmup_us is None else warmup_us)
        self._ref_u = {}
        #: pixels whose scene moves in the recording (not ``ctx.static``): their reference is
        #: drawn again after a warm-up (:func:`start`)
        self.moving = ~np.asarray(ctx.static, bool)
        self.lin = np.ascontiguousarray(ctx.sim_images, dtype=np.float32)
        self.t = np.ascontiguousarray(ctx.sim_t, dtype=np.int64)
        self._log = None
        self._cache: OrderedDict = OrderedDict()
        self.cache_size = int(cache_size)
        self.n_kernel = 0          # Sensor runs
        self.n_composed = 0        # simulations (kernel cached or not)

    # --- per-context precomputation -------------------------------------------------------
    def log_frames(self, log_eps: float) -> np.ndarray:
        """float32 log(I + eps) of the upsampled frames, as the sensor computes it."""
        if self._log is None or self._log[0] != log_eps:
            lf = np.add(self.lin, np.float32(log_eps))
            np.log(lf, out=lf)
            self._log = (log_eps, lf)
        return self._log[1]

    # --- simulation ---------------------------------------------------------------------------
    def reference_phase(self, seed: int) -> np.ndarray:
        """(H, W) uniform [0, 1) draws of ``seed``'s initial reference (own stream, common
        to every candidate simulated with that seed)."""
        u = self._ref_u.get(seed)
        if u is None:
            h, w = self.lin.shape[1:]
            u = self._ref_u[seed] = np.random.default_rng([seed, _REFERENCE]).random((h, w))
        return u

    def randomizes(self, degrade: DegradeConfig) -> bool:
        """Whether the events of ``degrade`` depend on the seed."""
        return self.random_reference or effects.needs_rng(degrade)

    def kernel_events(self, sensor: SensorConfig, degrade: DegradeConfig, seed: int) -> np.ndarray:
        """Time-sorted events of the pixel circuit alone (additive effects off). With
        ``random_reference`` every pixel's reference starts at a random point between its
        thresholds (:func:`randomize_reference`, u ~ U[0, 1) per pixel and seed; with leak the
        sensor's own leak phase instead); with leak or shot noise the pixels then warm up on
        the first frame and the moving ones are drawn between the thresholds again
        (:func:`start`)."""
        kd = _kernel_degrade(degrade)
        rnd = effects.needs_rng(kd) or self.random_reference
        key = (kernel_key(sensor, degrade), seed if rnd else None)
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        rng = np.random.default_rng([seed, _KERNEL]) if rnd else None
        h, w = self.lin.shape[1:]
        s = Sensor(w, h, sensor, kd, rng)
        # the first frame sets the state (linear, as simulate), then the warm-up on it
        start(s, kd, self.lin[:1], int(self.t[0]), self.reference_phase(seed) if self.random_reference else None,
              self.warmup_us, moving=self.moving)
        if kd.cutoff_hz > 0:                       # the low-pass needs the linear intensity too
            ev = s.step(self.lin[1:], self.t[1:], log_frames=self.log_frames(sensor.log_eps)[1:])
        else:
            ev = s.step(self.log_frames(sensor.log_eps)[1:], self.t[1:], log=True)
        arr = ev.array
        rest = s.flush().array
        if rest.size:
            arr = np.concatenate([arr, rest])
        self.n_kernel += 1
        self._cache[key] = arr
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return arr

    def compose(self, sensor: SensorConfig, degrade: DegradeConfig, seed: int) -> np.ndarray:
        """All events of ``(sensor, degrade)`` with ``seed`` (not time-sorted when additive
        effects are on)."""
        self.n_composed += 1
        arr = self.kernel_events(sensor, degrade, seed)
        d = degrade
        t0, t1 = int(self.t[0]), int(self.t[-1])
        h, w = self.lin.shape[1:]
        parts = [arr]
        if d.hot_pixel_fraction > 0 and d.hot_pixel_hz > 0:
            rng = np.random.default_rng([seed, _HOT])
            idx, on = effects.hot_pixels(h, w, d, rng)
            if idx.size:
                parts.append(effects.hot_pixel_events(idx, on, d.hot_pixel_hz, t0, t1, w, rng))
        timing = d.jitter_us > 0 or d.latency_us > 0
        if len(parts) == 1 and not timing:
            return arr
        out = np.concatenate(parts) if len(parts) > 1 else arr.copy()
        if timing:
            apply_timing(out, d, np.random.default_rng([seed, _TIMING]) if d.jitter_us > 0 else None, t0)
        return out

    def summary(self, sensor: SensorConfig, degrade: DegradeConfig, seed: int) -> Summary:
        arr = self.compose(sensor, degrade, seed)
        return summarize_arrays(arr["t"], arr["x"], arr["y"], arr["p"], self.ctx)

    def events(self, sensor: SensorConfig, degrade: DegradeConfig, seed: int) -> Events:
        """Time-sorted :class:`Events` (for the report's consistency check)."""
        arr = self.compose(sensor, degrade, seed)
        h, w = self.lin.shape[1:]
        return Events(sort_events(arr), w, h, validate=False)


__all__ = ["ADDITIVE_KEYS", "Engine", "kernel_key", "randomize_reference", "simulate_random_start", "start", "warms_up"]
