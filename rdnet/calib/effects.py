"""The vocabulary of sensor effects the calibration can name, and how each maps to the
``degrade`` keys of the simulator (:class:`rdnet.sim.settings.DegradeConfig`)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from rdnet.sim.settings import DegradeConfig, SensorConfig


@dataclass(frozen=True)
class Param:
    """One fitted parameter: ``key`` of ``degrade`` (or ``threshold_scale``, the common
    factor of both sensor thresholds), search range [lo, hi], searched in log scale.
    ``weak``: where in the range the effect is weakest ('lo', 'hi', or 'off': its OFF
    value inside the range); the screen does not simulate that point (it is the current
    config, nearly)."""

    key: str
    lo: float
    hi: float
    weak: str = "lo"


@dataclass(frozen=True)
class Effect:
    """A named sensor effect: its parameters, the value that turns each off, the
    statistic that reveals it and a one-line description of the physics. ``shape``:
    parameters that come with the effect but do not switch it on or off (the hot pixels' ON
    share): read off the recording when the effect is fitted
    (:func:`rdnet.calib.fit.shape_estimate`), not searched; [lo, hi] is their clip range.
    ``tuning``: parameters that come with the effect and do not switch it on or off either,
    but are searched with it over [lo, hi] (the bandwidth's dark-current floor: how much
    slower dark pixels are is the sensor's, not a constant of the model). ``fit_own``: the
    weight of the effect's own statistic's fit-segment term added to the fit discrepancy
    while the effect's parameters are searched (:class:`rdnet.calib.fit.OwnGuided`; 0: the
    discrepancy alone), for an effect whose statistic has weight 0 in the discrepancy but
    reads its parameter where the discrepancy's terms are flat."""

    name: str
    params: tuple[Param, ...]
    statistic: str
    physics: str
    changes_count: bool = False     # removes or adds signal events: thresholds can hide it
    shape: tuple[Param, ...] = ()
    tuning: tuple[Param, ...] = ()
    fit_own: float = 0.0

    @property
    def keys(self) -> tuple[str, ...]:
        """The keys that switch the effect on (all off: absent)."""
        return tuple(p.key for p in self.params)

    @property
    def fitted(self) -> tuple[Param, ...]:
        """Every parameter fitted with the effect: its keys, its tuning, then its shape."""
        return self.params + self.tuning + self.shape

    def present(self, degrade: DegradeConfig) -> bool:
        return any(getattr(degrade, k) != OFF.get(k, 0.0) for k in self.keys)


#: value of a degrade key that turns its effect off
OFF = {"onoff_ratio": 1.0}

#: the basic parameter re-fitted first: both thresholds times a common factor
THRESHOLD_SCALE = Param("threshold_scale", 0.4, 2.5)

EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("threshold_mismatch", (Param("threshold_sigma", 0.01, 0.6),), "pixel_persistence",
           "per-pixel spread of the contrast thresholds (fixed-pattern mismatch)", True, fit_own=1.0),
    Effect("onoff_asymmetry", (Param("onoff_ratio", 0.4, 2.5, "off"),), "on_fraction",
           "ON and OFF contrast thresholds differ", True),
    Effect("bandwidth", (Param("cutoff_hz", 1.0, 3000.0, "hi"),), "rate_vs_intensity",
           "photoreceptor low-pass filter whose cutoff falls with intensity (slow dark pixels)", True,
           tuning=(Param("cutoff_floor", 0.003, 0.3),)),
    Effect("refractory_period", (Param("refractory_us", 20.0, 50000.0),), "iei",
           "dead time after each event of a pixel", True),
    Effect("shot_noise", (Param("shot_noise_hz", 1e-4, 30.0),), "static_rate",
           "balanced ON/OFF Poisson noise events"),
    Effect("leak_events", (Param("leak_hz", 1e-4, 30.0),), "static_on_fraction",
           "ON-only leak events from junction leakage"),
    Effect("hot_pixels", (Param("hot_pixel_fraction", 0.0005, 0.05), Param("hot_pixel_hz", 3.0, 3000.0)),
           "pixel_isolated", "a few pixels fire continuously",
           shape=(Param("hot_pixel_on_fraction", 0.0, 1.0), Param("hot_pixel_polarity_concentration", 0.0, 1000.0)),
           fit_own=1.0),
    Effect("timestamp_jitter", (Param("jitter_us", 20.0, 20000.0),), "rate_time",
           "random timestamp noise"),
    Effect("latency", (Param("latency_us", 50.0, 50000.0),), "lag_smoothed",
           "constant delay of the event timestamps"),
    Effect("readout_saturation", (Param("sample_period_us", 20.0, 50000.0),), "iei",
           "readout samples each pixel at most once per period", True),
)}


def ideal(degrade: DegradeConfig, keep: frozenset[str] | set[str] = frozenset()) -> DegradeConfig:
    """``degrade`` with every effect of the vocabulary switched off (each key of
    :attr:`Effect.keys` at its :data:`OFF` value) but those in ``keep``: the ideal sensor as
    a calibration's base, which asks which effects a camera has beyond it (the
    ``calibrate_real`` stage's ``--set`` list; ``rdnet calibrate --base ideal``). The shape and
    tuning keys stay: they only shape an effect once it is fitted."""
    return dataclasses.replace(degrade, **{k: OFF.get(k, 0.0) for e in EFFECTS.values() for k in e.keys
                                           if k not in keep})


def apply(sensor: SensorConfig, degrade: DegradeConfig, values: dict[str, float]
          ) -> tuple[SensorConfig, DegradeConfig]:
    """Configs with ``values`` applied (``threshold_scale`` multiplies both thresholds)."""
    vals = dict(values)
    scale = vals.pop("threshold_scale", 1.0)
    if scale != 1.0:
        sensor = dataclasses.replace(sensor, threshold_on=sensor.threshold_on * scale,
                                     threshold_off=sensor.threshold_off * scale)
    if vals:
        degrade = dataclasses.replace(degrade, **vals)
    return sensor, degrade


def absent_effects(degrade: DegradeConfig) -> list[Effect]:
    """Effects the config leaves out (all of their keys off), in vocabulary order."""
    return [e for e in EFFECTS.values() if not e.present(degrade)]


def present_effects(degrade: DegradeConfig) -> list[Effect]:
    return [e for e in EFFECTS.values() if e.present(degrade)]
