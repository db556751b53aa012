"""Ideal DVS sensor: exact crossing times, streaming state, input validation."""
import numpy as np
import pytest

from rdnet.errors import ValidationError
from rdnet.events.core import Events, concatenate
from rdnet.sim.sensor import Sensor, sort_events
from rdnet.sim.settings import SensorConfig


def _ramp_log(k_per_pixel, thr, n_steps=37, dt=1000, t0=5000, sign=1.0):
    """Log frames (float64) ramping linearly by k[y, x] thresholds over n_steps."""
    t = t0 + np.arange(n_steps + 1, dtype=np.int64) * dt
    frac = (t - t[0]) / (t[-1] - t[0])
    L = -1.0 + sign * frac[:, None, None] * (k_per_pixel[None] * thr)
    return L, t


def test_linear_ramp_gives_k_events_at_analytic_times():
    thr = 0.2
    k = np.array([[1, 2, 3], [5, 7, 11]], float)
    L, t = _ramp_log(k, thr)
    s = Sensor(3, 2, SensorConfig(thr, thr, 0.01))
    ev = s.step(L, t, log=True)
    assert np.array_equal(ev.count_per_pixel(), k.astype(int))
    assert ev.p.all()
    T = t[-1] - t[0]
    for y in range(2):
        for x in range(3):
            sel = (ev.x == x) & (ev.y == y)
            expect = t[0] + np.arange(1, int(k[y, x]) + 1) * T / k[y, x]
            assert np.abs(ev.t[sel] - expect).max() <= 1
    # reference moved by exactly one threshold per event
    np.testing.assert_allclose(s.ref, -1.0 + k * thr, atol=1e-9)
    Events(ev.array, 3, 2)  # time-sorted


def test_down_ramp_off_events_with_own_threshold():
    k = np.full((1, 4), 6.0)
    L, t = _ramp_log(k, 0.3, sign=-1.0, n_steps=10)
    ev = Sensor(4, 1, SensorConfig(0.2, 0.3, 0.01)).step(L, t, log=True)
    assert len(ev) == 24 and not ev.p.any()


def test_several_events_per_step_interpolated_inside_the_step():
    L = np.array([0.0, 3.5 * 0.2])[:, None, None]
    ev = Sensor(1, 1).step(L, np.array([0, 7000]), log=True)
    np.testing.assert_array_equal(ev.t, [2000, 4000, 6000])


def test_linear_input_ramp_and_static_scene():
    thr, eps = 0.2, 0.01
    t = np.arange(51, dtype=np.int64) * 500
    L = np.log(0.05 + eps) + (7.5 * thr) * t / t[-1]
    frames = np.broadcast_to((np.exp(L) - eps)[:, None, None], (51, 3, 4)).astype(np.float32)
    ev = Sensor(4, 3, SensorConfig(thr, thr, eps)).step(frames, t)
    assert np.all(ev.count_per_pixel() == 7)
    static = np.full((20, 3, 4), 0.3, np.float32)
    assert len(Sensor(4, 3).step(static, np.arange(20) * 1000)) == 0


def test_streaming_in_chunks_matches_one_call():
    rng = np.random.default_rng(3)
    frames = rng.uniform(0.05, 1, size=(60, 8, 9)).astype(np.float32)
    t = np.cumsum(rng.integers(100, 3000, size=60)).astype(np.int64)
    whole = Sensor(9, 8).step(frames, t)
    s = Sensor(9, 8)
    parts = [s.step(frames[i:i + 7], t[i:i + 7]) for i in range(0, 60, 7)] + [s.flush()]
    chunked = concatenate(parts)
    assert len(whole) > 100
    assert np.array_equal(whole.array, chunked.array)


@pytest.mark.parametrize("effects", [
    {}, {"shot_noise_hz": 3.0, "refractory_us": 400.0}, {"cutoff_hz": 150.0, "leak_hz": 0.5},
    {"sample_period_us": 300.0, "threshold_sigma": 0.05},
    {"hot_pixel_fraction": 0.05, "hot_pixel_hz": 40.0, "jitter_us": 200.0, "latency_us": 700.0}])
def test_events_do_not_depend_on_the_row_grouping(effects):
    """The kernel advances groups of rows (rdnet.sim.sensor.row_group, ``group_pixels``): one
    row per group, three (the last group shorter) or all 13 give the same events in the same
    order."""
    import dataclasses

    from rdnet.calib.effects import ideal
    from rdnet.sim.settings import DegradeConfig
    rng = np.random.default_rng(11)
    frames = np.clip(rng.uniform(0.05, 1, (1, 13, 37)) * (1 + 0.6 * np.sin(
        np.arange(80)[:, None, None] * 0.3 + rng.uniform(0, 6, (1, 13, 37)))), 0, 1).astype(np.float32)
    t = np.cumsum(rng.integers(200, 900, size=80)).astype(np.int64)
    degrade = dataclasses.replace(ideal(DegradeConfig()), **effects)     # every other effect off
    runs = {}
    for pixels in (1, 3 * 37, 10_000):
        s = Sensor(37, 13, SensorConfig(), degrade, np.random.default_rng(5), group_pixels=pixels)
        runs[s._group] = concatenate([s.step(frames[:30], t[:30]), s.step(frames[30:], t[30:]), s.flush()])
    assert sorted(runs) == [1, 3, 13]
    assert len(runs[1]) > 500
    for g in (3, 13):
        assert np.array_equal(runs[g].array, runs[1].array), g


def test_row_group_makes_about_a_page_of_pixels():
    """Rows per kernel group: ceil(GROUP_PIXELS / width), at least 1, at most the height."""
    from rdnet.sim.sensor import GROUP_PIXELS, row_group
    assert GROUP_PIXELS == 1024
    assert row_group(173, 130) == 6          # the calibration's DAVIS346 sample: 1038 pixels
    assert row_group(64, 64) == 16           # a proof scene
    assert row_group(346, 260) == 3
    assert row_group(1280, 720) == 1 and row_group(1024, 10) == 1
    assert row_group(5, 7) == 7              # the whole frame
    assert row_group(1, 1) == 1
    assert row_group(173, 130, group_pixels=1) == 1 and row_group(37, 13, group_pixels=111) == 3


def test_bad_input_raises_and_keeps_state():
    s = Sensor(4, 3)
    good = np.full((2, 3, 4), 0.5, np.float32)
    s.step(good, np.array([0, 1000]))
    bad = good.copy()
    bad[1, 2, 3] = np.nan
    with pytest.raises(ValidationError):
        s.step(bad, np.array([2000, 3000]))
    bad[1, 2, 3] = -0.1
    with pytest.raises(ValidationError):
        s.step(bad, np.array([2000, 3000]))
    with pytest.raises(ValidationError):
        s.step(np.full((1, 4, 3), 0.5, np.float32), np.array([2000]))
    with pytest.raises(ValidationError):
        s.step(good, np.array([2000, 2000]))
    with pytest.raises(ValidationError):
        s.step(good, np.array([500, 3000]))     # before frames already seen
    with pytest.raises(ValidationError):
        s.step(np.array([[[np.inf]]]), np.array([5]), log=True)
    # the state is intact: a brighter frame still gives ON events from the 0.5 reference
    ev = s.step(np.full((1, 3, 4), 0.5 * np.exp(0.45), np.float32), np.array([4000]))
    assert np.all(ev.count_per_pixel(1) == 2)


def test_sort_events_is_stable_by_time():
    from rdnet.events.core import make_events
    arr = make_events([5, 3, 5, 1, 3], [0, 1, 2, 3, 4], [0] * 5, [1] * 5)
    out = sort_events(arr)
    np.testing.assert_array_equal(out["t"], [1, 3, 3, 5, 5])
    np.testing.assert_array_equal(out["x"], [3, 1, 4, 0, 2])
    far = make_events([10**9, 0, 5], [0, 1, 2], [0] * 3, [0] * 3)    # long span: argsort path
    np.testing.assert_array_equal(sort_events(far)["x"], [1, 2, 0])
