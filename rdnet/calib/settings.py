"""``calibrate`` section of params.yaml: how ``rdnet calibrate`` compares simulation and
recording (segments, seeds, statistic resolution, significance rule)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

from rdnet.config import MAX_THREADS, ONE_HOUR_US, check_bounds, positive
from rdnet.errors import ConfigError
from rdnet.events.core import MAX_SENSOR_SIDE
from rdnet.sim.settings import SENSOR_UPPER_BOUNDS


#: upper bounds of the ``calibrate`` keys (``search_seeds`` is at most ``seeds``), far above any
#: useful setting
UPPER_BOUNDS = {
    # durations in int64 microseconds (huge values overflowed)
    "time_bin_us": ONE_HOUR_US, "max_lag_us": ONE_HOUR_US, "warmup_us": ONE_HOUR_US,
    # threads and seeds: threads and memory grow with them
    "threads": MAX_THREADS, "seeds": 100,
    # time segments, each simulated and scored on its own: a minute in 1000 segments leaves
    # 60 ms, a few frames, to each
    "segments": 1000,
    # pixels: a stride or a rate-map cell wider than the largest sensor side is one pixel or
    # one cell (a stride of 1e9 gave a traceback)
    "pixel_stride": MAX_SENSOR_SIDE, "grid_px": MAX_SENSOR_SIDE,
    # log-intensity quantile bins (1e9 was killed for memory): beyond a few hundred they hold
    # a handful of pixels each
    "intensity_bins": 1000,
    # a log-intensity range, bounded as a contrast threshold is (``sensor.threshold_on``)
    "static_contrast": SENSOR_UPPER_BOUNDS["threshold_on"],
    # seed standard deviations: beyond 1000 no effect is ever named (as good as off)
    "significance": 1000.0, "signature_significance": 1000.0,
    # shares of the fit discrepancy after the basic refit: no effect removes more than all of it
    "min_relative_gain": 1.0, "screen_gain": 1.0,
    # effects: far more than the vocabulary holds (rdnet.calib.effects.EFFECTS, 10)
    "max_effects": 100, "max_fitted": 100, "screen_refine": 100,
    # each screen point is a simulation of the search sample (1e9 was killed for memory)
    "search_points": 100,
    # each golden-section step shrinks the bracket by 0.618: 75 steps reach float64's
    # resolution (1e9 ran until killed)
    "refine_steps": 100,
    # pixel-frame budgets: at ~1e7 pixel-frames a second, 1e12 is more than a day
    "max_sim_steps": 1e12, "search_max_sim_steps": 1e12,
    # as ``interpolate.max_upsample`` (rdnet.sim.interpolate.UPPER_BOUNDS: frames in memory)
    "max_upsample": 1024}


@dataclass(frozen=True)
class CalibrateConfig:
    """Settings of the sim-to-real calibration (:mod:`rdnet.calib`).

    ``segments``: the recording is cut into this many equal time segments; even ones are
    used to fit, odd ones are held out to score. ``seeds``: simulation seeds of the final
    scoring (common random numbers: every candidate is simulated with the same seeds; their
    spread is the noise scale of the significance test). ``search_seeds``: the first this
    many of them are used while fitting. ``pixel_stride``: simulate every k-th row/column
    only (DVS pixels are independent, so this is an unbiased pixel sample that divides the
    cost by k^2). ``time_bin_us``: bin of the rate-over-time statistic. ``grid_px``: cell of
    the coarse rate map (simulated pixels). ``intensity_bins``: log-intensity quantile bins.
    ``static_contrast``: a pixel whose log-intensity range over the frames stays below this
    is *static*. ``significance``: an effect is named missing only if its held-out gain
    exceeds this many standard deviations of the discrepancy between seeds;
    ``min_relative_gain``: and this fraction of the held-out discrepancy left after the
    basic refit. ``signature_significance``: the second way to be named (0 = off): an effect
    whose own statistic (``Effect.statistic``) drops by more than this many of *its* seed
    spreads, whose held-out gain is positive in every seed (paired: the candidates share the
    seeds) and above ``min_relative_gain``, is named even when its total gain is within
    ``significance`` seed spreads: the total's seed spread also carries the terms of the
    structural mismatch that the effect does not touch (:func:`rdnet.calib.fit.score`).
    An effect's tuning parameter (the bandwidth's dark-current floor) leaves its declared
    value only when that lowers the fit discrepancy by more than ``min_relative_gain`` too.
    ``max_effects``: forward selection stops after this many.
    ``search_points``: grid points of the screen of an effect without a data-driven first
    guess (log-spaced over its range; its weak end is not simulated); ``refine_steps``:
    evaluations of each golden-section refinement. ``screen_gain``: an effect is fitted
    only if its best screen point lowers the fit discrepancy by this fraction of the one
    after the basic refit; ``max_fitted``: at most this many effects that act in the pixel
    circuit (the best screened) are fitted per round (plausible additive effects, which
    cost no circuit runs, always are). ``max_lag_us``: range of the latency
    cross-correlation. ``max_sim_steps``: budget of simulated pixel-frames of the final
    scoring; the pixel stride is raised automatically until the interpolated recording
    fits it (counting every frame pair at ``max_upsample``; 0 = off).
    ``search_max_sim_steps``: the same budget for the search (a coarser pixel sample of
    the final one; 0 = the final sample). ``max_upsample``: cap of
    ``interpolate.max_upsample`` for the calibration (real frames carry sensor noise that
    keeps the log-step bound from ever being met; 0 = no cap). ``threads``: numba and OpenCV
    threads while calibrating (0 = their defaults; the calibration runs hundreds of short
    simulations and one optical flow per frame pair, which on 2 shared cores run fastest
    single-threaded: a parallel region waits for its slowest thread). ``candidates``: the
    left-out effects to test (names of :data:`rdnet.calib.effects.EFFECTS`; empty = all of
    them). ``interpolation``: frame-interpolation methods (``interpolate.method``: flow,
    linear, cubic, selected; default flow and selected: linear blending, a candidate until
    session 47, was kept in none of the 104 proof and DAVIS346 calibrations of the tenth
    study run nor in the 10 DAVIS346 stability seeds) tried as a nuisance choice in the basic
    refit: the recording is upsampled with each, the configured parameters are re-fitted and the left-out effects screened on each,
    and the one with the lowest reachable fit-segment discrepancy (the basic refit's, or
    that of one of its ``screen_refine`` best screened effects fitted on top of it) is kept
    for everything after (reported as ``frame_interpolation``; empty = the ``interpolate``
    config as given). ``screen_refine``: how many of the best screened effects are fitted
    for that choice (more than 1: look-alikes trade places in the one-seed screen).
    ``warp``: ``interpolate.warp`` of every interpolation the calibration runs ('bicubic',
    'bicubic_clamped' or 'bilinear'; None = the ``interpolate`` section's): bicubic, because a bilinear
    warp delays the simulated events within each frame interval (docs/calibration.md,
    "Bicubic warps").
    ``random_reference``: each simulation seed starts every pixel's reference at a uniform
    random point between its OFF and ON thresholds (the unknown state at recording start)
    instead of at the first frame, so even a deterministic pixel model has an honest seed
    spread; off = the simulator's own start (seed-independent for deterministic configs).
    ``warmup_us``: with leak or shot noise, every simulation first runs the pixels this
    long on the first frame held still and drops those events, then draws the reference of
    the pixels that move in the recording between the thresholds again
    (:func:`rdnet.calib.engine.start`): a real recording starts from a sensor that has been
    running, whose static pixels sit where leak drift and noise resets left them (default
    3 s; 0 = start at the reference above; docs/calibration.md "The warm-up" and
    "Stationary truths").
    """

    segments: int = 6
    seeds: int = 3
    search_seeds: int = 1
    pixel_stride: int = 1
    time_bin_us: int = 2000
    grid_px: int = 8
    intensity_bins: int = 6
    static_contrast: float = 0.15
    significance: float = 3.0
    min_relative_gain: float = 0.05
    signature_significance: float = 10.0
    max_effects: int = 3
    search_points: int = 5
    refine_steps: int = 4
    screen_gain: float = 0.02
    max_fitted: int = 2
    screen_refine: int = 2
    max_lag_us: int = 20000
    max_sim_steps: int = 25_000_000
    search_max_sim_steps: int = 4_000_000
    max_upsample: int = 16
    threads: int = 1
    candidates: Tuple[str, ...] = ()
    interpolation: Tuple[str, ...] = ("flow", "selected")
    warp: Optional[str] = "bicubic"
    random_reference: bool = True
    warmup_us: int = 3_000_000

    def __post_init__(self):
        if self.segments < 2:
            raise ConfigError("calibrate.segments", f"must be >= 2 (fit and held-out), got {self.segments}")
        if self.seeds < 2:
            raise ConfigError("calibrate.seeds", f"must be >= 2 (the seed spread is the noise scale), got {self.seeds}")
        if not 1 <= self.search_seeds <= self.seeds:
            raise ConfigError("calibrate.search_seeds", f"must be in [1, seeds={self.seeds}], got {self.search_seeds}")
        for key in ("pixel_stride", "time_bin_us", "grid_px", "intensity_bins", "search_points", "max_fitted",
                    "screen_refine"):
            positive(f"calibrate.{key}", getattr(self, key), allow_zero=False)
        for key in ("static_contrast", "significance", "min_relative_gain", "signature_significance", "max_effects", "screen_gain",
                    "refine_steps", "max_lag_us", "max_sim_steps", "search_max_sim_steps", "max_upsample",
                    "threads", "warmup_us"):
            positive(f"calibrate.{key}", getattr(self, key))
        check_bounds("calibrate", self, UPPER_BOUNDS)     # beyond these a run overflows or exhausts the machine
        object.__setattr__(self, "candidates", tuple(self.candidates))
        object.__setattr__(self, "interpolation", tuple(self.interpolation))
        from rdnet.sim.interpolate import METHODS
        for m in self.interpolation:
            if m not in METHODS:
                raise ConfigError("calibrate.interpolation", f"unknown method {m!r}; known: {', '.join(METHODS)}")
        from rdnet.sim.interpolate import WARPS
        if self.warp is not None and self.warp not in WARPS:
            raise ConfigError("calibrate.warp", f"must be one of {', '.join(WARPS)} or null, got {self.warp!r}")
        if len(set(self.interpolation)) != len(self.interpolation):
            raise ConfigError("calibrate.interpolation", f"duplicate method in {list(self.interpolation)}")
        from rdnet.calib.effects import EFFECTS
        for name in self.candidates:
            if name not in EFFECTS:
                raise ConfigError("calibrate.candidates", f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        if self.search_points < 3:
            raise ConfigError("calibrate.search_points", f"must be >= 3, got {self.search_points}")
