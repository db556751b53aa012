"""The bandwidth limit's low-pass does not depend on the simulation's time step: a pixel on a
log-intensity ramp fires at the same times whether its frames come every 5 us or every 2.5 ms
(the continuous filter; rdnet.sim.sensor integrates the input as linear within each step)."""
import sys
from pathlib import Path

import numpy as np
import pytest

from rdnet.sim.sensor import Sensor
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bandwidth_step_size import event_times as first_events  # noqa: E402  (one pixel on the benchmark's ramp)


@pytest.mark.parametrize("cutoff_hz, start", [(100.0, 0.5), (100.0, 0.05), (300.0, 0.5), (300.0, 0.05)])
def test_lag_does_not_depend_on_the_step(cutoff_hz, start):
    ref = first_events(5, cutoff_hz, start)
    assert len(ref) == 3
    # holding each step's end value made these 263-306 us (625 us steps) and 618-1191 us
    # (2.5 ms) early; the linear-input response leaves what the intensity-dependent cutoff,
    # held within a step, costs: 8-49 and 20-205 us
    for step, tol in ((625, 100), (2500, 300)):
        t = first_events(step, cutoff_hz, start)
        assert len(t) == 3
        assert np.all(np.abs(t - ref) < tol), (step, t - ref)


def test_the_filter_lags_a_ramp_by_its_time_constant():
    """Bright pixel (I about 1: the cutoff is cutoff_hz), a slow ramp: after the transient the
    filtered log trails the input by tau = 1 / (2 pi f), so each event comes tau late."""
    sensor = SensorConfig()
    f = 200.0
    tau_us = 1e6 / (2 * np.pi * f)
    t = np.arange(0, 200_001, 1000, dtype=np.int64)
    log_i = np.log(1.0 + sensor.log_eps) + 0.5 * t / 200_000           # from I = 1, + 0.5 in 200 ms
    frames = np.maximum(np.exp(log_i) - sensor.log_eps, 0.0).astype(np.float32)[:, None, None]
    deg = DegradeConfig(cutoff_hz=f, cutoff_floor=0.0)
    ideal = Sensor(1, 1, sensor, DegradeConfig(), np.random.default_rng(0)).step(frames, t)
    lagged = Sensor(1, 1, sensor, deg, np.random.default_rng(0)).step(frames, t)
    k = min(len(ideal.t), len(lagged.t))
    assert k >= 2
    # the intensity grows 65 % over the ramp, so the cutoff (and tau) changes by that much
    # over it: the late events trail by tau / 1.65 .. tau
    lag = (np.asarray(lagged.t[1:k], np.float64) - np.asarray(ideal.t[1:k], np.float64))
    assert np.all(lag > tau_us / 1.7 - 20) and np.all(lag < tau_us + 20), (lag, tau_us)
