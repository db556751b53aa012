"""Known-answer tests of the circuit event generator (rdnet.circuit)."""
import math

import numpy as np
import pytest

from rdnet.circuit import CircuitParams, from_degrade, generate, pixel_parameters
from rdnet.errors import ConfigError, ValidationError
from rdnet.sim.settings import DegradeConfig, SensorConfig

TINY_DARK = 1e-9          # log(I + i_dark) = log(I) to 1e-7 at the intensities used


def frames_of(values, t_us):
    """(N, 1, P) frames whose pixel k follows values[:, k]."""
    v = np.asarray(values, np.float32)
    return v[:, None, :], np.asarray(t_us, np.int64)


def static(intensity, n_frames, dt_us, shape=(8, 8)):
    im = np.full((n_frames,) + shape, intensity, np.float32)
    return im, np.arange(n_frames, dtype=np.int64) * dt_us


def test_step_gives_floor_dlog_over_threshold_events():
    # a step up then back down, infinite bandwidth, no noise, reset start: ON then OFF events
    dlog = np.array([0.3, 0.5, 0.9, 1.25, 0.19])
    lo = np.full(5, 0.02)
    hi = lo * np.exp(dlog)
    im, t = frames_of([lo, lo, hi, hi, lo, lo], [0, 1000, 1100, 5000, 5100, 9000])
    ev = generate(im, t, CircuitParams(i_dark=TINY_DARK), np.random.default_rng(0), random_start=False)
    expect = np.floor(dlog / 0.2).astype(int)                  # 1, 2, 4, 6, 0
    on = np.bincount(ev.x[ev.p == 1], minlength=5)
    off = np.bincount(ev.x[ev.p == 0], minlength=5)
    np.testing.assert_array_equal(on, expect)
    np.testing.assert_array_equal(off, expect)
    # ON events inside the rising ramp, OFF inside the falling one
    assert ev.t[ev.p == 1].min() >= 1000 and ev.t[ev.p == 1].max() <= 1100
    assert ev.t[ev.p == 0].min() >= 5000 and ev.t[ev.p == 0].max() <= 5100


def test_crossing_times_on_a_log_ramp_are_exact():
    # log I rises 5 per second; threshold 0.05: one ON event every 10 ms, at k * 10 ms
    t = np.arange(0, 1_000_001, 1000)
    im, t = frames_of(0.005 * np.exp(5.0 * t[:, None] * 1e-6), t)
    ev = generate(im, t, CircuitParams(threshold_on=0.05, threshold_off=0.05, i_dark=TINY_DARK),
                  np.random.default_rng(0), random_start=False)
    assert len(ev) == 99 or len(ev) == 100
    np.testing.assert_allclose(ev.t, 10_000 * np.arange(1, len(ev) + 1), atol=2)


def test_refractory_holds_reset_and_rereferences_on_waking():
    # same ramp, refractory 20 ms: after each event the pixel waits 20 ms, memorises the
    # level at wake-up, and fires one threshold (10 ms) later: period 30 ms
    t = np.arange(0, 1_000_001, 1000)
    im, t = frames_of(0.005 * np.exp(5.0 * t[:, None] * 1e-6), t)
    p = CircuitParams(threshold_on=0.05, threshold_off=0.05, i_dark=TINY_DARK, refractory_us=20_000)
    ev = generate(im, t, p, np.random.default_rng(0), random_start=False)
    gaps = np.diff(ev.t)
    np.testing.assert_allclose(gaps, 30_000, atol=2)
    assert len(ev) == 1_000_000 // 30_000 + 1 - 1 or len(ev) == 1_000_000 // 30_000


def test_refractory_caps_the_rate_of_a_very_fast_change():
    # log I rises 12 in 0.2 s (ideal: 60 events per pixel at threshold 0.2); 10 ms dead time
    t = np.arange(0, 200_001, 500)
    im, t = frames_of(np.tile(1e-6 * np.exp(60.0 * t[:, None] * 1e-6), (1, 3)), t)
    ev = generate(im, t, CircuitParams(i_dark=TINY_DARK, refractory_us=10_000), np.random.default_rng(0))
    per_pixel = np.bincount(ev.x, minlength=3)
    assert per_pixel.max() <= 200_000 // 10_000 + 1
    assert per_pixel.min() >= 0.8 * 200_000 / (10_000 + 0.2 / 60 * 1e6)


def test_latency_shifts_timestamps_by_exactly_latency():
    rng_im = np.random.default_rng(3)
    im = rng_im.random((20, 6, 6)).astype(np.float32)
    t = np.arange(20, dtype=np.int64) * 5000
    base = CircuitParams(shot_noise_hz=5.0, refractory_us=300.0)
    a = generate(im, t, base, np.random.default_rng(9))
    b = generate(im, t, CircuitParams(**{**base.__dict__, "latency_us": 1234.0}), np.random.default_rng(9))
    assert len(a) > 100
    np.testing.assert_array_equal(b.t, a.t + 1234)
    np.testing.assert_array_equal(b.x, a.x)
    np.testing.assert_array_equal(b.p, a.p)


def test_jitter_has_the_declared_std():
    # one ON event per pixel (a log step of 0.3 at threshold 0.2), matched by pixel
    lo = np.full((40, 40), 0.1, np.float32)
    im = np.stack([lo, lo, lo * math.exp(0.3), lo * math.exp(0.3)])
    t = np.array([0, 10_000, 10_100, 30_000])
    a = generate(im, t, CircuitParams(), np.random.default_rng(9), random_start=False)
    b = generate(im, t, CircuitParams(jitter_us=400.0, latency_us=5000.0), np.random.default_rng(9),
                 random_start=False)
    assert len(a) == len(b) == 1600
    ka = np.argsort(a.y.astype(int) * 40 + a.x)
    kb = np.argsort(b.y.astype(int) * 40 + b.x)
    d = b.t[kb].astype(float) - a.t[ka]
    assert abs(d.mean() - 5000) < 4 * 400 / 40 and abs(d.std() - 400) < 30


def _first_on_time(bandwidth_hz):
    # pixel 0 bright (1.0 -> 0.5 -> 1.0), pixel 1 dark (0.01 -> 0.005 -> 0.01): same log step
    lo = np.array([0.5, 0.005])
    im, t = frames_of([2 * lo, 2 * lo, lo, lo, 2 * lo, 2 * lo], [0, 1000, 1010, 200_000, 200_010, 400_000])
    ev = generate(im, t, CircuitParams(i_dark=1e-4, photoreceptor_hz=bandwidth_hz), np.random.default_rng(0),
                  random_start=False)
    return [int(ev.t[(ev.x == k) & (ev.p == 1)].min()) - 200_000 for k in (0, 1)]


def test_dark_pixels_lag_bright_ones_when_bandwidth_is_limited():
    bright, dark = _first_on_time(200.0)
    assert bright < 1000                      # ~ 1 / (2 pi 200 Hz) scale
    assert dark > 20 * bright                 # cutoff ~ 100x lower in the dark
    b0, d0 = _first_on_time(0.0)              # infinite bandwidth: same time (inside the 10 us ramp)
    assert abs(b0 - d0) <= 10


def test_leak_rate_in_a_static_scene():
    im, t = static(0.3, 41, 50_000)           # 2 s
    p = CircuitParams(leak_hz=5.0, leak_spread_decades=0.0)
    ev = generate(im, t, p, np.random.default_rng(1))
    per_pixel = np.bincount(ev.y.astype(int) * 8 + ev.x, minlength=64)
    assert np.all(ev.p == 1)
    assert per_pixel.min() >= 9 and per_pixel.max() <= 11    # 5 Hz x 2 s, random phase
    # leak events are not tied to the sub-steps (exact crossing times of the drift)
    assert len(np.unique(ev.t % 250)) > 50
    # with a spread, the mean over pixels is still leak_hz (1024 pixels: std of the mean ~0.12)
    im, t = static(0.3, 41, 50_000, shape=(32, 32))
    ev = generate(im, t, CircuitParams(leak_hz=5.0, leak_spread_decades=0.3), np.random.default_rng(1))
    assert abs(len(ev) / 1024 / 2.0 - 5.0) < 0.5


def test_shot_noise_rate_falls_with_intensity_and_noise_resets_the_pixel():
    T = 2.0
    for inten, rate in ((0.0, 20.0), (0.3, 20.0 / (1 + 0.3 / 0.1))):
        im, t = static(inten, 41, 50_000, shape=(16, 16))
        ev = generate(im, t, CircuitParams(shot_noise_hz=20.0), np.random.default_rng(2))
        expect = rate * T * 256
        assert abs(len(ev) - expect) < 4 * math.sqrt(expect) + 0.02 * expect
        assert abs(ev.on_fraction - 0.5) < 0.05
    # a noise event re-references the pixel: with a leak of 1 Hz and noise of 20 Hz, noise
    # keeps resetting the memory, so almost no leak events come (without reset: ~2 per pixel)
    im, t = static(0.3, 41, 50_000, shape=(16, 16))
    ev = generate(im, t, CircuitParams(shot_noise_hz=40.0, shot_noise_half=1e9, leak_hz=1.0,
                                       leak_spread_decades=0.0), np.random.default_rng(2))
    noise_only = generate(im, t, CircuitParams(shot_noise_hz=40.0, shot_noise_half=1e9), np.random.default_rng(2))
    extra = len(ev) - len(noise_only)
    assert extra < 0.2 * 256 * 2.0


def test_hot_pixels_fire_at_their_rate():
    im, t = static(0.3, 21, 50_000, shape=(20, 20))
    p = CircuitParams(hot_pixel_fraction=0.02, hot_pixel_hz=200.0)
    ev = generate(im, t, p, np.random.default_rng(4))
    counts = np.bincount(ev.y.astype(int) * 20 + ev.x, minlength=400)
    assert np.count_nonzero(counts) == 8
    assert np.all(np.abs(counts[counts > 0] - 200) <= 1)


def test_threshold_mismatch_draws_per_pixel_thresholds():
    on, off, _ = pixel_parameters(20000, CircuitParams(threshold_sigma=0.1), np.random.default_rng(0))
    assert abs(on.std() / 0.2 - 0.1) < 0.005 and abs(off.mean() - 0.2) < 0.002
    assert abs(np.corrcoef(on, off)[0, 1]) < 0.03


def test_same_seed_same_bits_other_seed_differs():
    rng_im = np.random.default_rng(5)
    im = rng_im.random((15, 8, 8)).astype(np.float32)
    t = np.arange(15, dtype=np.int64) * 4000
    p = CircuitParams(threshold_sigma=0.1, photoreceptor_hz=300.0, follower_hz=2000.0, voltage_noise=0.3,
                      refractory_us=200.0, shot_noise_hz=10.0, leak_hz=1.0, hot_pixel_fraction=0.02,
                      hot_pixel_hz=50.0, jitter_us=100.0, latency_us=50.0)
    a = generate(im, t, p, np.random.default_rng(7))
    b = generate(im, t, p, np.random.default_rng(7))
    c = generate(im, t, p, np.random.default_rng(8))
    assert len(a) > 50
    assert a.array.tobytes() == b.array.tobytes()
    assert a.array.tobytes() != c.array.tobytes()


def test_small_event_buffer_is_retried_without_changing_the_result():
    # 4 x 272 events in one interval overflow the first buffer (4 per pixel + 1024)
    lo = np.full((1, 4), 1e-4, np.float32)
    im = np.concatenate([lo, lo * math.exp(3.0)])[:, None, :]
    ev = generate(im.reshape(2, 1, 4), np.array([0, 1000]), CircuitParams(threshold_on=0.011, threshold_off=0.011,
                                                                          i_dark=TINY_DARK),
                  np.random.default_rng(0), random_start=False)
    np.testing.assert_array_equal(np.bincount(ev.x), [272] * 4)
    assert np.all(np.diff(ev.t) >= 0) and np.all(ev.p == 1)


def test_from_degrade_maps_the_shared_keys():
    s = SensorConfig(threshold_on=0.3, threshold_off=0.3, log_eps=0.02)
    d = DegradeConfig(onoff_ratio=2.25, cutoff_hz=50.0, refractory_us=700.0, latency_us=3.0, jitter_us=4.0,
                      shot_noise_hz=0.5)
    c = from_degrade(s, d, voltage_noise=0.1)
    assert c.threshold_on == pytest.approx(0.45) and c.threshold_off == pytest.approx(0.2)
    assert (c.i_dark, c.photoreceptor_hz, c.refractory_us, c.latency_us, c.jitter_us, c.shot_noise_hz,
            c.voltage_noise) == (0.02, 50.0, 700.0, 3.0, 4.0, 0.5, 0.1)
    with pytest.raises(ConfigError):
        from_degrade(s, DegradeConfig(sample_period_us=100.0))
    with pytest.raises(ConfigError):
        CircuitParams(threshold_on=0.0)


def test_leak_under_noise_resets_agrees_with_rdnets_simulator():
    """Two independent models of the same physics (noise events reset the pixel) give the
    same leak rate under noise at equal local rates (in the dark, where both noise laws give
    the dark rate): the renewal rate R e^{-R/l} / (1 - e^{-R/l}) of a uniform leak."""
    from rdnet.sim.sensor import Sensor
    leak, noise, seconds, side = 1.0, 1.5, 10.0, 40
    im, t = static(0.0, 41, int(seconds * 1e6 / 40), shape=(side, side))
    ev = generate(im, t, CircuitParams(leak_hz=leak, leak_spread_decades=0.0, shot_noise_hz=noise),
                  np.random.default_rng(3))
    s = Sensor(side, side, SensorConfig(), DegradeConfig(leak_hz=leak, leak_spread_decades=0.0, shot_noise_hz=noise),
               np.random.default_rng(3))
    p = np.concatenate([s.step(im[:1], t[:1]).array["p"], s.step(im[1:], t[1:]).array["p"], s.flush().array["p"]])
    q = math.exp(-noise / leak)
    renewal = noise * q / (1 - q)
    rates = [(2.0 * int(pp.sum()) - pp.size) / (side * side * seconds) for pp in (np.asarray(ev.p), p)]
    for r in rates:
        assert abs(r / renewal - 1) < 0.1, (rates, renewal)
    assert renewal < 0.7 * leak          # without the resets both would show the full rate


def test_warm_up_starts_both_models_in_the_stationary_state():
    """A recording starts from a sensor that has been running. A static pixel under leak l
    and noise resets at rate R then leaks at the renewal rate R e^{-R/l} / (1 - e^{-R/l})
    from the first microsecond (0.233 Hz for l = 0.6, R = 1), which both models give after
    a warm-up on the held first frame. Without it, a recording shorter than 1 / l shows the
    start instead: rdnet's leak phase is uniform below the ON threshold, so its first leak
    event falls in (0, 1/l) (0.6 x (1 - e^-1) = 0.379 per pixel in 1 s, 1.63x), the
    circuit's memorised level is uniform between the OFF and the ON threshold, twice as far
    (0.190, 0.81x)."""
    from rdnet.calib.engine import simulate_random_start
    leak, noise, side = 0.6, 1.0, 128
    im, t = static(0.0, 41, 25_000, shape=(side, side))         # 1 s of a dark still scene
    deg = DegradeConfig(leak_hz=leak, leak_spread_decades=0.0, shot_noise_hz=noise)
    q = math.exp(-noise / leak)
    renewal = noise * q / (1 - q)

    def rate(p):                      # leak events per pixel and second: ON - OFF (noise is balanced)
        p = np.asarray(p)
        return (2.0 * int(p.sum()) - p.size) / (side * side * 1.0)

    def circuit(warm):
        return rate(generate(im, t, from_degrade(SensorConfig(), deg), np.random.default_rng(4), warmup_us=warm).p)

    def rdnet(warm):
        return rate(simulate_random_start(im, t, SensorConfig(), deg, np.random.default_rng(4),
                                          np.random.default_rng(5), warmup_us=warm).p)

    warmed = {"circuit": circuit(5e6), "rdnet": rdnet(5_000_000)}
    for model, r in warmed.items():
        assert abs(r / renewal - 1) < 0.1, (model, r, renewal)
    cold_rdnet, cold_circuit = rdnet(0), circuit(0.0)
    assert cold_rdnet / renewal > 1.45 and cold_rdnet / renewal < 1.8, cold_rdnet
    assert cold_circuit / renewal > 0.65 and cold_circuit / renewal < 0.92, cold_circuit


def test_warm_up_needs_a_non_negative_duration():
    im, t = static(0.5, 3, 1000)
    with pytest.raises(ValidationError, match="warmup_us"):
        generate(im, t, CircuitParams(), np.random.default_rng(0), warmup_us=-1.0)
