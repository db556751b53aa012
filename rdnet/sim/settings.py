"""``sensor``, ``degrade`` and ``randomize`` sections of params.yaml.

Zero (or ``onoff_ratio = 1``) turns a degradation off; the equations live in
:mod:`rdnet.sim.effects`.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

from rdnet.config import positive
from rdnet.errors import ConfigError


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


@dataclass(frozen=True)
class DegradeConfig:
    """Real-sensor degradations (all off when zero; ``onoff_ratio`` off at 1)."""

    threshold_sigma: float = 0.0      # per-pixel Gaussian threshold mismatch (fraction of threshold)
    onoff_ratio: float = 1.0          # ON threshold / OFF threshold
    cutoff_hz: float = 0.0            # photoreceptor low-pass cutoff at full intensity
    sample_period_us: float = 0.0     # readout: at most one event per pixel per period
    refractory_us: float = 0.0        # dead time after each event of a pixel
    shot_noise_hz: float = 0.0        # balanced ON/OFF Poisson noise per pixel
    leak_hz: float = 0.0              # ON-only leak events per pixel
    hot_pixel_fraction: float = 0.0   # fraction of pixels that fire continuously
    hot_pixel_hz: float = 0.0         # rate of each hot pixel
    jitter_us: float = 0.0            # Gaussian timestamp noise (std)
    latency_us: float = 0.0           # constant timestamp delay

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "onoff_ratio":
                positive("degrade.onoff_ratio", v, allow_zero=False)
            else:
                positive(f"degrade.{f.name}", v)
        if self.hot_pixel_fraction > 1:
            raise ConfigError("degrade.hot_pixel_fraction", f"must be <= 1, got {self.hot_pixel_fraction}")

    def active(self) -> list[str]:
        """Names of the effects that are on."""
        return [f.name for f in fields(self)
                if (getattr(self, f.name) != 1.0 if f.name == "onoff_ratio" else getattr(self, f.name) != 0)]
