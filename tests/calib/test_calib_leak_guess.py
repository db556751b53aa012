"""The leak guess inverts the leak rate that shows through noise resets."""
import math

import numpy as np
import pytest

from rdnet.calib.fit import leak_rate_under_noise
from rdnet.sim.sensor import Sensor
from rdnet.sim.settings import DegradeConfig, SensorConfig


@pytest.mark.parametrize("leak,noise", [(0.6, 2.0), (1.5, 1.0), (0.2, 0.05)])
def test_inverts_the_renewal_rate(leak, noise):
    q = math.exp(-noise / leak)
    observed = noise * q / (1 - q)
    assert leak_rate_under_noise(observed, noise) == pytest.approx(leak, rel=1e-12)
    assert leak_rate_under_noise(observed, 0.0) == observed      # no noise: what shows is the rate


def test_recovers_the_simulators_leak_from_a_static_recording():
    """On rdnet's own static pixels (uniform leak, noise resets) the ON - OFF rate, inverted,
    gives back the leak rate; the observed rate alone is less than half of it."""
    leak, dark, level, seconds = 0.8, 2.0, 0.2, 12.0
    t = np.linspace(0, seconds * 1e6, 13).astype(np.int64)
    fr = np.full((13, 48, 48), level, np.float32)
    d = DegradeConfig(leak_hz=leak, leak_spread_decades=0.0, shot_noise_hz=dark)
    s = Sensor(48, 48, SensorConfig(), d, np.random.default_rng(4))
    p = np.concatenate([s.step(fr[:1], t[:1]).array["p"], s.step(fr[1:], t[1:]).array["p"], s.flush().array["p"]])
    observed = (2.0 * int(p.sum()) - p.size) / (48 * 48 * seconds)
    noise = dark * (1 + (d.shot_noise_bright_factor - 1) * level)
    assert observed < 0.5 * leak
    assert leak_rate_under_noise(observed, noise) == pytest.approx(leak, rel=0.08)
