"""``sensor``, ``degrade`` and ``randomize`` sections of params.yaml.

Zero (or ``onoff_ratio = 1``) turns a degradation off; the equations live in
:mod:`rdnet.sim.effects`, the per-sequence randomization in :mod:`rdnet.sim.randomize`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Mapping, Tuple

from rdnet.config import MAX_RATE_HZ, ONE_HOUR_US, at_most, check_bounds, positive
from rdnet.errors import ConfigError

#: bounds of the ``sensor`` keys, in log units (checked by :func:`rdnet.config.check_bounds`)
SENSOR_LOWER_BOUNDS = {
    # a threshold below 0.1 % of log intensity fires on float rounding, one event per 1e-3 of
    # change (1e-300 ran until killed); real sensors' are 0.1-0.8
    "threshold_on": 1e-3, "threshold_off": 1e-3}
SENSOR_UPPER_BOUNDS = {
    # e^10 (22,000:1) per event: more than the log range of an 8- or 12-bit frame (5.5, 8.3),
    # so a larger threshold only silences the pixel
    "threshold_on": 10.0, "threshold_off": 10.0,
    # an offset of the full-scale intensity makes log(I + eps) nearly linear (a [0, 1] frame
    # spans less than ln 2); 1e308 overflowed float32 and the error blamed the frames
    "log_eps": 1.0}


@dataclass(frozen=True)
class SensorConfig:
    """Ideal DVS pixel: events when log(I + log_eps) moves by a contrast threshold.

    ``threshold_on``/``threshold_off``: contrast thresholds in log units (> 0).
    ``log_eps``: offset added to linear intensity in [0, 1] before the log.
    """

    threshold_on: float = 0.2
    threshold_off: float = 0.2
    log_eps: float = 0.01

    def __post_init__(self):
        positive("sensor.threshold_on", self.threshold_on, allow_zero=False)
        positive("sensor.threshold_off", self.threshold_off, allow_zero=False)
        positive("sensor.log_eps", self.log_eps, allow_zero=False)
        check_bounds("sensor", self, SENSOR_UPPER_BOUNDS, SENSOR_LOWER_BOUNDS)


#: The degradations proper (each off at 0, ``onoff_ratio`` off at 1); the remaining
#: DegradeConfig fields only shape an effect (``shot_noise_bright_factor``,
#: ``leak_spread_decades``) and are not randomized by default.
EFFECT_KEYS: tuple[str, ...] = (
    "threshold_sigma", "onoff_ratio", "cutoff_hz", "sample_period_us", "refractory_us",
    "shot_noise_hz", "leak_hz", "hot_pixel_fraction", "hot_pixel_hz", "jitter_us", "latency_us")

#: How each effect's strength follows its value, so that a factor m means the same for every
#: key (:mod:`rdnet.sim.randomize`: m = 0 the ideal sensor, a larger m a stronger effect):
#: ``linear`` (off at 0, stronger as it grows: value x m), ``log`` (``onoff_ratio``: off at 1,
#: stronger as its log grows: value ** m), ``inverse`` (``cutoff_hz``: off at 0, a *lower*
#: nonzero cutoff is the stronger bandwidth limit, its time constant 1 / (2 pi cutoff) the lag:
#: value / m). The calibration's search knows the same direction
#: (:class:`rdnet.calib.effects.Param` ``weak``; a test keeps the two in step).
EFFECT_SCALING: dict[str, str] = {**{k: "linear" for k in EFFECT_KEYS}, "onoff_ratio": "log", "cutoff_hz": "inverse"}

#: bounds of the ``degrade`` keys (checked by :func:`rdnet.config.check_bounds`; the fractions
#: ``threshold_sigma``, ``hot_pixel_fraction`` and ``hot_pixel_on_fraction`` are at most 1), far
#: beyond any real sensor's values and short of where the simulation overflowed, ran until
#: killed or dropped every event; :func:`rdnet.sim.randomize.scale_degrade` caps a scaled
#: value at them
DEGRADE_UPPER_BOUNDS = {
    # ON and OFF thresholds 100x apart (the calibration searches 0.4-2.5); beyond, one of them
    # shrinks towards 0 with the ratio's root (1e300 ran until killed)
    "onoff_ratio": 100.0,
    # durations in int64 microseconds: 1e19 us of refractory period gave 0 events without a
    # word, 1e30 us of latency or jitter overflowed
    "sample_period_us": ONE_HOUR_US, "refractory_us": ONE_HOUR_US, "jitter_us": ONE_HOUR_US,
    "latency_us": ONE_HOUR_US,
    # rates: a pixel cannot fire faster than ~1 MHz (1e300 Hz of shot noise ran until killed);
    # a photoreceptor's bandwidth is Hz to kHz (the calibration searches 1-3000 Hz)
    "shot_noise_hz": MAX_RATE_HZ, "leak_hz": MAX_RATE_HZ, "hot_pixel_hz": MAX_RATE_HZ,
    "cutoff_hz": MAX_RATE_HZ,
    # shot noise is a dark-pixel effect (v2e: 0.25 at full intensity); 10x the dark rate keeps
    # the bright rate within 10 MHz
    "shot_noise_bright_factor": 10.0,
    # std of log10 of the per-pixel leak rate (v2e: 0.1); at 3 decades the mean-preserving
    # factor is exp(-s^2 / 2) = 4e-11 and a few pixels hold all the leak (1e300 gave NaN rates)
    "leak_spread_decades": 3.0,
    # dark current as a fraction of full scale: at 1 the dark bandwidth is already half the
    # bright one (v2e: 20/255; the calibration searches 0.003-0.3)
    "cutoff_floor": 1.0,
    # Beta concentration: at 1e6 every hot pixel's ON share is within 0.001 of the mean (std
    # sqrt(m (1 - m) / (k + 1))), so larger values change nothing (the calibration clips at 1000)
    "hot_pixel_polarity_concentration": 1e6}
DEGRADE_LOWER_BOUNDS = {"onoff_ratio": 1 / DEGRADE_UPPER_BOUNDS["onoff_ratio"]}   # the mirror image


@dataclass(frozen=True)
class DegradeConfig:
    """Real-sensor degradations (all off when zero; ``onoff_ratio`` off at 1).

    Effects (equations and sources in :mod:`rdnet.sim.effects`):

    ``threshold_sigma``   per-pixel Gaussian mismatch of the ON and OFF thresholds, std as
                          a fraction of the nominal threshold (v2e ``sigma_thres``).
    ``onoff_ratio``       ON threshold / OFF threshold; the geometric mean of the nominal
                          thresholds is kept.
    ``cutoff_hz``         photoreceptor 3 dB bandwidth at full intensity (I = 1); scales
                          with intensity, so dark pixels are slower (v2e).
    ``sample_period_us``  readout period: at most one event per pixel per period.
    ``refractory_us``     dead time after each event of a pixel.
    ``shot_noise_hz``     ON+OFF Poisson noise rate of a pixel in the dark (I = 0).
    ``leak_hz``           mean rate of ON-only leak events per pixel.
    ``hot_pixel_fraction``/``hot_pixel_hz``  fraction of pixels that fire continuously
                          and their rate.
    ``jitter_us``         std of Gaussian timestamp noise (truncated at 4 std).
    ``latency_us``        constant timestamp delay.

    Shape parameters (not effects; 0 does not mean off):

    ``shot_noise_bright_factor``  shot-noise rate at I = 1 relative to the dark rate
                          (v2e ``SHOT_NOISE_INTEN_FACTOR`` = 0.25); linear in between.
    ``leak_spread_decades``  std of log10 of the per-pixel leak rate (v2e
                          ``noise_rate_cov_decades`` = 0.1).
    ``cutoff_floor``      the photoreceptor's dark current as a fraction of full scale: the
                          bandwidth ``cutoff_hz (I + floor) / (1 + floor)`` does not fall below
                          ``cutoff_hz floor / (1 + floor)`` in the dark (v2e: 20/255; a circuit
                          whose dark current is also its log offset has ``sensor.log_eps``).
    ``hot_pixel_on_fraction``  mean share of ON events among the hot pixels' events (0.5:
                          balanced; real hot pixels lean ON: 0.69 on a DVXplorer recording,
                          docs/calibration.md "Hot-pixel polarity").
    ``hot_pixel_polarity_concentration``  how alike the hot pixels' ON shares are: hot pixel
                          i fires ON with probability q_i ~ Beta(k m, k (1 - m)) (k this value,
                          m ``hot_pixel_on_fraction``); 0: each hot pixel fires one polarity, ON
                          with probability m (the limit k -> 0); large: every hot pixel fires
                          both polarities at the share m.
    """

    threshold_sigma: float = 0.0      # per-pixel Gaussian threshold mismatch (fraction of threshold)
    onoff_ratio: float = 1.0          # ON threshold / OFF threshold
    cutoff_hz: float = 0.0            # photoreceptor low-pass cutoff at full intensity
    sample_period_us: float = 0.0     # readout: at most one event per pixel per period
    refractory_us: float = 0.0        # dead time after each event of a pixel
    shot_noise_hz: float = 0.0        # balanced ON/OFF Poisson noise per pixel (in the dark)
    leak_hz: float = 0.0              # ON-only leak events per pixel (mean over pixels)
    hot_pixel_fraction: float = 0.0   # fraction of pixels that fire continuously
    hot_pixel_hz: float = 0.0         # rate of each hot pixel
    jitter_us: float = 0.0            # Gaussian timestamp noise (std)
    latency_us: float = 0.0           # constant timestamp delay
    shot_noise_bright_factor: float = 0.25  # shot-noise rate at I=1 / rate at I=0
    leak_spread_decades: float = 0.1  # std of log10(per-pixel leak rate)
    cutoff_floor: float = 20.0 / 255.0  # photoreceptor dark current / full scale (bandwidth floor, v2e)
    hot_pixel_on_fraction: float = 0.5  # mean ON share of the hot pixels' events
    hot_pixel_polarity_concentration: float = 0.0  # Beta concentration of the per-pixel ON share (0: one polarity each)

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ConfigError(f"degrade.{f.name}", f"expected a number, got {v!r}")
            if f.name == "onoff_ratio":
                positive("degrade.onoff_ratio", v, allow_zero=False)
            else:
                positive(f"degrade.{f.name}", v)
            if v == float("inf"):
                raise ConfigError(f"degrade.{f.name}", "must be finite")
        for k in ("hot_pixel_fraction", "hot_pixel_on_fraction"):
            if getattr(self, k) > 1:
                raise ConfigError(f"degrade.{k}", f"must be <= 1, got {getattr(self, k)}")
        if self.threshold_sigma > 1:
            raise ConfigError("degrade.threshold_sigma",
                              f"must be <= 1 (a fraction of the threshold), got {self.threshold_sigma}")
        check_bounds("degrade", self, DEGRADE_UPPER_BOUNDS, DEGRADE_LOWER_BOUNDS)

    def active(self) -> list[str]:
        """Names of the effects that are on."""
        return [k for k in EFFECT_KEYS
                if (getattr(self, k) != 1.0 if k == "onoff_ratio" else getattr(self, k) != 0)]

    @property
    def is_ideal(self) -> bool:
        return not self.active()


Range = Tuple[float, float]


def scale_ranges(value) -> tuple[Range, ...]:
    """The ranges of a ``randomize.*_scale`` value: ``[lo, hi]`` is one range,
    ``[[lo, hi], [lo, hi], ...]`` several (their union)."""
    if value and isinstance(value[0], (tuple, list)):
        return tuple((float(a), float(b)) for a, b in value)
    return ((float(value[0]), float(value[1])),)


#: bounds of the ``randomize`` scales, factors on the ``degrade`` section: the study's are
#: 0.5-2 (the stress test's 3); a scaled value is capped at its key's bound anyway
RANDOMIZE_UPPER_BOUNDS = {"train_scale": 100.0, "test_scale": 100.0}


@dataclass(frozen=True)
class RandomizeConfig:
    """``randomize`` section: per-sequence degradation drawn around ``degrade``.

    Each randomized key of the ``degrade`` section that is active is multiplied by a
    factor drawn uniformly from ``train_scale`` (training sequences) or ``test_scale``
    (test sequences), independently per key and per sequence; ``onoff_ratio`` is scaled
    in log space (r -> r ** factor) and ``cutoff_hz`` inversely (c -> c / factor: the
    bandwidth limit's time constant scales, so a larger factor is a stronger limit as for
    every other key; :data:`EFFECT_SCALING`). A scale is one range ``[lo, hi]`` or a union of
    ranges ``[[lo, hi], ...]`` (drawn uniformly over the union: a range is picked with
    probability proportional to its length). Every training range must be disjoint from
    every test range, so test degradations are never seen in training; a union lets the
    training draws bracket the test range (``[[0.5, 0.9], [1.6, 2.0]]`` around a test
    range ``[1.0, 1.5]``) instead of lying all on one side of it. ``keys``: the keys to
    randomize (empty = all active effects of :data:`EFFECT_KEYS`). ``train_scale_keys``:
    a training scale of its own for some keys (``{cutoff_hz: [0.5, 0.9]}`` keeps the
    bandwidth limit's training draws on one side of the test range while ``train_scale``
    brackets it for the others); each is disjoint from ``test_scale`` too, and is drawn
    after the shared draws, so a config without it draws exactly as before. ``enabled:
    false`` uses ``degrade`` unchanged for both splits (ranges then unchecked).
    """

    enabled: bool = True
    train_scale: Any = (0.5, 0.9)      # Range or tuple of Ranges (validated below)
    test_scale: Any = (1.0, 1.5)
    keys: Tuple[str, ...] = ()
    train_scale_keys: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        for name in ("train_scale", "test_scale"):
            object.__setattr__(self, name, _checked_scale(f"randomize.{name}", getattr(self, name)))
        check_bounds("randomize", self, RANDOMIZE_UPPER_BOUNDS)
        object.__setattr__(self, "keys", tuple(self.keys))
        for k in self.keys:
            _effect_key("randomize.keys", k)
        own = self.train_scale_keys
        if not isinstance(own, Mapping):
            raise ConfigError("randomize.train_scale_keys", f"expected a mapping of degrade keys to scales, got {own!r}")
        checked = {}
        for k, v in own.items():
            _effect_key("randomize.train_scale_keys", k)
            if self.keys and k not in self.keys:       # it would stay at its degrade value in both splits
                raise ConfigError("randomize.train_scale_keys", f"{k!r} is not randomized (randomize.keys: "
                                  f"{', '.join(self.keys)})")
            checked[k] = _checked_scale(f"randomize.train_scale_keys.{k}", v)
            for _, hi in scale_ranges(checked[k]):
                at_most(f"randomize.train_scale_keys.{k}", hi, RANDOMIZE_UPPER_BOUNDS["train_scale"])
        object.__setattr__(self, "train_scale_keys", checked)
        if self.enabled:
            for name, train in (("train_scale", self.train_scale),
                                *((f"train_scale_keys.{k}", v) for k, v in checked.items())):
                for a0, a1 in scale_ranges(train):
                    for b0, b1 in self.test_ranges:
                        if not (a1 < b0 or b1 < a0):
                            raise ConfigError("randomize.test_scale",
                                              f"{name} {_show(train)} and test_scale "
                                              f"{_show(self.test_scale)} must be disjoint")

    @property
    def train_ranges(self) -> tuple[Range, ...]:
        """``train_scale`` as a tuple of (lo, hi) ranges."""
        return scale_ranges(self.train_scale)

    @property
    def test_ranges(self) -> tuple[Range, ...]:
        """``test_scale`` as a tuple of (lo, hi) ranges."""
        return scale_ranges(self.test_scale)

    def train_ranges_of(self, key: str) -> tuple[Range, ...]:
        """The training ranges of one degrade key: its own (``train_scale_keys``) or the
        shared ``train_scale``."""
        own = self.train_scale_keys.get(key)
        return scale_ranges(own) if own is not None else self.train_ranges


def _effect_key(field_: str, key: str) -> None:
    """ConfigError naming ``field_`` unless ``key`` is one of :data:`EFFECT_KEYS`."""
    if key not in EFFECT_KEYS:
        raise ConfigError(field_, f"unknown degrade key {key!r}; known: {', '.join(EFFECT_KEYS)}")


def _checked_scale(key: str, value):
    """A ``randomize`` scale (``[lo, hi]`` or ``[[lo, hi], ...]``) validated, as tuples;
    ConfigError naming ``key`` otherwise."""
    shape = f"expected [lo, hi] or [[lo, hi], ...], got {value!r}"
    if not isinstance(value, (tuple, list)) or not value:
        raise ConfigError(key, shape)
    nested = isinstance(value[0], (tuple, list))
    for rng in (value if nested else (value,)):
        if not isinstance(rng, (tuple, list)) or len(rng) != 2 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in rng):
            raise ConfigError(key, shape)
        lo, hi = rng
        positive(key, lo, allow_zero=True)
        if not lo <= hi or hi == float("inf"):
            raise ConfigError(key, f"expected finite lo <= hi, got {list(rng)}")
    ranges = scale_ranges(value)
    return ranges if nested else ranges[0]


def _show(value) -> list:
    return [list(r) for r in value] if value and isinstance(value[0], tuple) else list(value)
