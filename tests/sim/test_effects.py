"""Each degradation moves the statistic it models and leaves the others alone."""
import math

import numpy as np
import pytest

from rdnet.config import from_dict
from rdnet.errors import ConfigError
from rdnet.events.core import EVENT_DTYPE, concatenate
from rdnet.sim import effects
from rdnet.sim.sensor import Sensor, apply_timing
from rdnet.sim.settings import DegradeConfig, RandomizeConfig, SensorConfig


def run(frames, t, degrade=None, seed=0, sensor=SensorConfig(), chunk=None, log=False):
    s = Sensor(frames.shape[2], frames.shape[1], sensor, degrade, np.random.default_rng(seed))
    chunk = chunk or len(t)
    parts = [s.step(frames[i:i + chunk], t[i:i + chunk], log=log) for i in range(0, len(t), chunk)]
    ev = concatenate(parts + [s.flush()])     # validates time order
    return ev, s


def up_down_ramp(n_thr, thr, h=64, w=64, steps=100):
    """Log frames rising by n_thr nominal thresholds, then falling back."""
    a = np.linspace(0, n_thr * thr, steps + 1)
    L = np.concatenate([a, a[-2::-1]])
    t = np.arange(L.size, dtype=np.int64) * 1000
    return np.broadcast_to(L[:, None, None], (L.size, h, w)).copy(), t


def test_threshold_sigma_recovered_from_ramp_counts():
    thr, n_thr, sigma = 0.2, 100, 0.1
    L, t = up_down_ramp(n_thr, thr)
    ev, s = run(L, t, DegradeConfig(threshold_sigma=sigma), log=True)
    for pol in (1, 0):
        n = ev.count_per_pixel(pol)
        est = n_thr * thr / (n + 0.5) / thr          # per-pixel threshold / nominal
        assert abs(est.std() / sigma - 1) < 0.1
        assert abs(est.mean() - 1) < 0.02           # nominal threshold kept on average
    ideal, _ = run(L, t, None, log=True)
    assert np.all(ideal.count_per_pixel(1) == n_thr) and np.all(ideal.count_per_pixel(0) == n_thr)


def test_onoff_ratio_keeps_geometric_mean():
    L, t = up_down_ramp(20, 0.2, h=4, w=4)
    ev, s = run(L, t, DegradeConfig(onoff_ratio=2.0), log=True)
    np.testing.assert_allclose(s.thr_on / s.thr_off, 2.0)
    np.testing.assert_allclose(np.sqrt(s.thr_on * s.thr_off), 0.2)
    n_on, n_off = ev.count_per_pixel(1), ev.count_per_pixel(0)
    assert np.all(n_on == math.floor(20 / math.sqrt(2))) and np.all(n_off == math.floor(20 * math.sqrt(2)))


@pytest.mark.parametrize("floor", [effects.CUTOFF_FLOOR, 0.01])
def test_cutoff_delays_events_more_in_the_dark_and_keeps_counts(floor):
    eps, thr, f0, dt = 0.01, 0.2, 200.0, 25
    sensor = SensorConfig(thr, thr, eps)
    levels = np.array([0.05, 0.8])             # dark, bright pixel (after a x e^1 step)
    before = levels / math.e
    n = 2400
    frames = np.empty((n, 1, 2), np.float32)
    frames[0, 0] = before
    frames[1:, 0] = levels
    t = np.arange(n, dtype=np.int64) * dt
    ideal, _ = run(frames, t, None, sensor=sensor)
    ev, _ = run(frames, t, DegradeConfig(cutoff_hz=f0, cutoff_floor=floor), sensor=sensor)
    assert np.array_equal(ev.count_per_pixel(), ideal.count_per_pixel())
    # analytic crossing times of lp = Lb + (La - Lb) exp(-2 pi f(I) t)
    for x, lvl in enumerate(levels):
        La, Lb = math.log(before[x] + eps), math.log(lvl + eps)
        k = np.arange(1, int((Lb - La) / thr + 1e-9) + 1)
        f = f0 * (lvl + floor) / (1 + floor)
        expect = -np.log(1 - k * thr / (Lb - La)) / (2 * math.pi * f) * 1e6
        got = ev.t[ev.x == x]
        assert np.abs(got - expect).max() < dt      # within one (linearly interpolated) step
    delay = [ev.t[ev.x == x].mean() for x in range(2)]
    assert delay[0] > 3 * delay[1]


def test_cutoff_floor_default_is_v2e_and_a_lower_floor_slows_only_the_dark():
    assert DegradeConfig().cutoff_floor == effects.CUTOFF_FLOOR == 20.0 / 255.0
    c = effects.lowpass_coef(DegradeConfig(cutoff_hz=100.0, cutoff_floor=0.01))
    assert c == pytest.approx(2 * math.pi * 100.0 * 1e-6 / 1.01)
    # the cutoff at I = 1 is cutoff_hz whatever the floor (the floor moves the dark end only)
    for b in (0.01, effects.CUTOFF_FLOOR):
        assert effects.lowpass_coef(DegradeConfig(cutoff_hz=100.0, cutoff_floor=b)) * (1 + b) == \
            pytest.approx(2 * math.pi * 100.0 * 1e-6)
    assert effects.cutoff_at(100.0, 0.01, 1.0) == pytest.approx(100.0)
    assert effects.cutoff_at(100.0, 0.01, 0.0) == pytest.approx(100.0 * 0.01 / 1.01)
    with pytest.raises(ConfigError, match="degrade.cutoff_floor"):
        DegradeConfig(cutoff_floor=-0.1)


def fast_ramp(h=16, w=16, n_thr=40, steps=20, dt=500):
    L = np.linspace(0, n_thr * 0.2, steps + 1)
    t = np.arange(steps + 1, dtype=np.int64) * dt
    return np.broadcast_to(L[:, None, None], (steps + 1, h, w)).copy(), t


def _per_pixel_gaps(ev):
    order = np.lexsort((ev.t, ev.y.astype(np.int64) * 10000 + ev.x))
    pix = (ev.y.astype(np.int64) * 10000 + ev.x)[order]
    t = ev.t[order]
    same = pix[1:] == pix[:-1]
    return np.diff(t)[same]


def test_refractory_period():
    L, t = fast_ramp()
    ideal, _ = run(L, t, None, log=True)
    ev, _ = run(L, t, DegradeConfig(refractory_us=700), log=True)
    assert _per_pixel_gaps(ideal).min() < 700
    assert _per_pixel_gaps(ev).min() >= 700
    assert 0 < len(ev) < len(ideal) and ev.p.all()


def test_refractory_reset_holds_the_reference_at_the_input():
    # a ramp of one threshold (0.2) per 250 us: held in reset for R after each event, the
    # pixel re-references to the input at the wake-up and fires one threshold later, so
    # every interval is R + 250 us (a reference moved by whole thresholds would give 750)
    L, t = fast_ramp(h=2, w=3, n_thr=40, steps=40, dt=250)
    ev, _ = run(L, t, DegradeConfig(refractory_us=700), log=True)
    gaps = _per_pixel_gaps(ev)
    assert gaps.size >= 6 * 8 and np.abs(gaps - 950).max() <= 1
    # the wake-up inside a frame step and across steps: longer steps, same answer
    L2, t2 = fast_ramp(h=2, w=3, n_thr=40, steps=10, dt=1000)
    gaps2 = _per_pixel_gaps(run(L2, t2, DegradeConfig(refractory_us=700), log=True)[0])
    assert np.abs(gaps2 - 950).max() <= 1
    # a reference held through a whole step: R longer than the step
    gaps3 = _per_pixel_gaps(run(L, t, DegradeConfig(refractory_us=1600), log=True)[0])
    assert np.abs(gaps3 - 1850).max() <= 1


def test_sample_period_limits_one_event_per_period():
    P = 800
    L, t = fast_ramp()
    ev, _ = run(L, t, DegradeConfig(sample_period_us=P), log=True)
    key = (ev.y.astype(np.int64) * 10000 + ev.x) * 10**6 + ev.t // P
    assert np.unique(key).size == len(ev)
    ideal, _ = run(L, t, None, log=True)
    assert len(ev) < 0.5 * len(ideal)                       # fast change: events lost
    slow, _ = run(*fast_ramp(n_thr=4, steps=40, dt=5000), DegradeConfig(sample_period_us=P), log=True)
    slow_ideal, _ = run(*fast_ramp(n_thr=4, steps=40, dt=5000), None, log=True)
    assert np.array_equal(slow.array, slow_ideal.array)   # slow change: untouched


def static(h, w, level, seconds, steps=2):
    t = np.linspace(0, seconds * 1e6, steps).astype(np.int64)
    return np.full((steps, h, w), level, np.float32), t


@pytest.mark.parametrize("level,factor", [(0.0, 1.0), (1.0, 0.25)])
def test_shot_noise_rate(level, factor):
    rate = 20.0
    fr, t = static(32, 32, level, 1.0, steps=5)
    ev, _ = run(fr, t, DegradeConfig(shot_noise_hz=rate))
    measured = len(ev) / (32 * 32) / 1.0
    assert abs(measured / (rate * factor) - 1) < 0.1
    assert abs(ev.on_fraction - 0.5) < 0.05


def test_leak_events_on_only_at_leak_rate():
    rate = 5.0
    fr, t = static(32, 32, 0.4, 2.0, steps=4)
    ev, s = run(fr, t, DegradeConfig(leak_hz=rate, leak_spread_decades=0.1))
    assert len(ev) > 0 and ev.p.all()
    assert abs(len(ev) / (32 * 32 * 2.0) / rate - 1) < 0.1
    assert abs(np.log10(s.leak_rate_hz).std() - 0.1) < 0.01


def test_shot_noise_resets_the_pixel_so_leak_fires_only_after_a_quiet_period():
    """A noise event resets the pixel (reference = input), restarting the leak's
    accumulation: with a uniform leak rate l and a noise rate R, a static pixel leaks only
    when no noise event came for 1 / l since its last event, i.e. at the renewal rate
    R e^{-R/l} / (1 - e^{-R/l}); noise stays balanced, so the leak rate is ON - OFF."""
    leak, dark, level, seconds = 1.0, 2.0, 0.4, 12.0
    fr, t = static(64, 64, level, seconds, steps=13)
    ev, _ = run(fr, t, DegradeConfig(leak_hz=leak, leak_spread_decades=0.0, shot_noise_hz=dark), seed=3)
    noise = dark * (1 + (0.25 - 1) * level)                 # 1.4 Hz at I = 0.4
    q = math.exp(-noise / leak)
    expected_leak = noise * q / (1 - q)                     # 0.46 Hz (1.0 without the reset)
    n_on, n_off = int(ev.p.sum()), int((~ev.p.astype(bool)).sum())
    per_pixel_s = 64 * 64 * seconds
    assert abs((n_on - n_off) / per_pixel_s / expected_leak - 1) < 0.06
    assert abs(2 * n_off / per_pixel_s / noise - 1) < 0.03   # the noise rate is unchanged


def test_shot_noise_events_are_lost_in_the_refractory_hold_and_chunking_does_not_matter():
    fr, t = static(32, 32, 0.0, 2.0, steps=21)
    d = DegradeConfig(shot_noise_hz=400.0, refractory_us=2000.0)
    ev, _ = run(fr, t, d, seed=5)
    order = np.lexsort((ev.t, ev.y, ev.x))
    gaps = np.diff(ev.t[order])[(np.diff(ev.x[order]) == 0) & (np.diff(ev.y[order]) == 0)]
    assert gaps.min() >= 2000                                # nothing fires during the hold
    # a dead time R after each of a Poisson(r) process's kept events: rate r / (1 + r R)
    assert abs(len(ev) / (32 * 32 * 2.0) / (400.0 / (1 + 400.0 * 2e-3)) - 1) < 0.03
    chunked, _ = run(fr, t, d, seed=5, chunk=3)
    assert np.array_equal(ev.array, chunked.array)           # counter-based noise stream


def test_hot_pixel_fraction_recovered():
    fr, t = static(64, 64, 0.5, 0.1)
    d = DegradeConfig(hot_pixel_fraction=0.01, hot_pixel_hz=1000.0)
    ev, s = run(fr, t, d)
    counts = ev.count_per_pixel()
    hot = counts > 20
    assert hot.sum() == round(0.01 * 64 * 64)
    assert abs(counts[hot].mean() / 100 - 1) < 0.1
    assert counts[~hot].sum() == 0


def one_event_per_pixel(h=48, w=48, steps=30, step_at=20):
    """Every pixel crosses one ON threshold at exactly t = 20_000 us."""
    L = np.zeros((steps, h, w))
    L[step_at:] = 0.2 * 1.5
    t = np.arange(steps, dtype=np.int64) * 1500
    t_event = t[step_at - 1] + round(1500 / 1.5)
    return L, t, t_event


def test_latency_and_jitter_shift_timestamps():
    L, t, te = one_event_per_pixel()
    lat, jit = 300.0, 200.0
    ev, _ = run(L, t, DegradeConfig(latency_us=lat), log=True, chunk=4)
    assert np.all(ev.t == te + 300)
    ev, _ = run(L, t, DegradeConfig(latency_us=lat, jitter_us=jit), log=True, chunk=4)
    dev = ev.t - te
    n = len(dev)
    assert n == 48 * 48 and ev.p.all()
    assert abs(dev.mean() - lat) < 4 * jit / math.sqrt(n)
    assert abs(dev.std() / jit - 1) < 0.05
    assert np.abs(dev - lat).max() <= 4 * jit + 1


def test_jitter_resorting_across_chunks_keeps_every_event():
    rng = np.random.default_rng(0)
    fr = rng.uniform(0.05, 1, size=(40, 10, 12)).astype(np.float32)
    t = np.arange(40, dtype=np.int64) * 1000
    ideal, _ = run(fr, t, None)
    d = DegradeConfig(jitter_us=2500.0, latency_us=100.0)
    for chunk in (2, 7):
        ev, _ = run(fr, t, d, chunk=chunk)   # concatenate() checks the global order
        assert np.array_equal(ev.count_per_pixel(1), ideal.count_per_pixel(1))
        assert np.array_equal(ev.count_per_pixel(0), ideal.count_per_pixel(0))


ALL = DegradeConfig(threshold_sigma=0.1, onoff_ratio=1.3, cutoff_hz=300, sample_period_us=200,
                    refractory_us=100, shot_noise_hz=5, leak_hz=1, hot_pixel_fraction=0.01,
                    hot_pixel_hz=200, jitter_us=300, latency_us=50)


def test_determinism_per_seed():
    rng = np.random.default_rng(1)
    fr = rng.uniform(0.05, 1, size=(30, 20, 24)).astype(np.float32)
    t = np.arange(30, dtype=np.int64) * 2000
    a, _ = run(fr, t, ALL, seed=7, chunk=8)
    b, _ = run(fr, t, ALL, seed=7, chunk=8)
    c, _ = run(fr, t, ALL, seed=8, chunk=8)
    assert a.array.tobytes() == b.array.tobytes()
    assert a.array.tobytes() != c.array.tobytes()


def test_zero_degradation_is_ideal():
    rng = np.random.default_rng(2)
    fr = rng.uniform(0.05, 1, size=(10, 6, 7)).astype(np.float32)
    t = np.arange(10, dtype=np.int64) * 1000
    a, _ = run(fr, t, None)
    b, _ = run(fr, t, DegradeConfig())
    assert DegradeConfig().active() == [] and ALL.active()
    assert np.array_equal(a.array, b.array)


@pytest.mark.parametrize("key,value", [("shot_noise_hz", -1.0), ("threshold_sigma", -0.1),
                                       ("leak_hz", -2), ("onoff_ratio", 0.0), ("jitter_us", float("nan")),
                                       ("hot_pixel_fraction", 1.5), ("refractory_us", -5)])
def test_degrade_validation_names_key(key, value):
    with pytest.raises(ConfigError, match=f"degrade.{key}"):
        from_dict(DegradeConfig, {key: value}, "degrade")


@pytest.mark.parametrize("key", ["threshold_on", "threshold_off", "log_eps"])
def test_sensor_thresholds_positive(key):
    with pytest.raises(ConfigError, match=f"sensor.{key}"):
        from_dict(SensorConfig, {key: 0.0}, "sensor")


def test_randomize_validation():
    with pytest.raises(ConfigError, match="randomize.test_scale"):
        RandomizeConfig(train_scale=(0.5, 1.0), test_scale=(0.9, 1.5))
    with pytest.raises(ConfigError, match="randomize.keys"):
        from_dict(RandomizeConfig, {"keys": ["bogus"]}, "randomize")
    with pytest.raises(ConfigError, match="randomize.train_scale"):
        from_dict(RandomizeConfig, {"train_scale": [1.0, 0.5]}, "randomize")
    RandomizeConfig(enabled=False, train_scale=(1, 1), test_scale=(1, 1))


def test_randomize_union_of_ranges():
    c = from_dict(RandomizeConfig, {"train_scale": [[0.5, 0.9], [1.6, 2.0]], "test_scale": [1.0, 1.5]}, "randomize")
    assert c.train_ranges == ((0.5, 0.9), (1.6, 2.0)) and c.test_ranges == ((1.0, 1.5),)
    assert c.test_scale == (1.0, 1.5)                     # one range stays a pair
    with pytest.raises(ConfigError, match="randomize.test_scale.*disjoint"):   # every pair of ranges
        from_dict(RandomizeConfig, {"train_scale": [[0.5, 0.9], [1.4, 2.0]]}, "randomize")
    for bad in ([[0.5], [1.6, 2.0]], [[0.5, 0.9], 1.6], [], 3, ["a", 1]):
        with pytest.raises(ConfigError, match=r"randomize.train_scale.*\[lo, hi\]"):
            from_dict(RandomizeConfig, {"train_scale": bad}, "randomize")
    with pytest.raises(ConfigError, match="randomize.train_scale.*lo <= hi"):
        from_dict(RandomizeConfig, {"train_scale": [[0.5, 0.9], [2.0, 1.6]]}, "randomize")


def test_rng_required_for_random_effects():
    from rdnet.errors import ValidationError
    with pytest.raises(ValidationError, match="rng"):
        Sensor(4, 4, SensorConfig(), DegradeConfig(shot_noise_hz=1.0), None)
    Sensor(4, 4, SensorConfig(), DegradeConfig(refractory_us=10, latency_us=5), None)


@pytest.mark.parametrize("jitter,latency", [(100.0, 50.0), (0.3, 2.7), (2500.0, -0.0)])
def test_jitter_shift_table_is_the_rounded_truncated_normal(jitter, latency):
    """The alias table holds the exact law of floor(d + s clip(z, -4, 4) + 0.5)."""
    d = DegradeConfig(jitter_us=jitter, latency_us=latency)
    lo, p = effects.shift_pmf(d)
    k = lo + np.arange(p.size)
    phi = np.array([0.5 * math.erfc(-(kk + 0.5 - latency) / jitter / math.sqrt(2)) for kk in k])
    q = (k + 0.5 - latency) / jitter
    cdf = np.where(q <= -4, 0.0, np.where(q > 4, 1.0, phi))
    cdf[-1] = 1.0
    np.testing.assert_allclose(np.cumsum(p), cdf, atol=1e-12)
    prob, alias = effects.alias_table(p)
    implied = prob.copy()
    np.add.at(implied, alias, 1 - prob)
    np.testing.assert_allclose(implied / p.size, p, atol=1e-12)
    # sampled through the sensor's shift (one uniform per event): chi-square against p
    arr = np.zeros(200_000, EVENT_DTYPE)
    arr["t"] = 10**8
    apply_timing(arr, d, np.random.default_rng(0), 0)
    counts = np.bincount(arr["t"] - 10**8 - lo, minlength=p.size)
    assert counts.size == p.size
    e = p * arr.size
    big = e > 20
    chi2 = ((counts[big] - e[big]) ** 2 / e[big]).sum()
    dof = big.sum() - 1
    assert chi2 < dof + 5 * math.sqrt(2 * dof)


@pytest.mark.skipif(__import__("numba").config.NUMBA_NUM_THREADS < 2,
                    reason="needs at least 2 numba threads to compare")
def test_output_does_not_depend_on_the_thread_count():
    import numba
    rng = np.random.default_rng(4)
    fr = rng.uniform(0.05, 1, size=(30, 40, 24)).astype(np.float32)
    t = np.arange(30, dtype=np.int64) * 1000
    old = numba.get_num_threads()
    try:
        out = []
        for n in (1, 2):
            numba.set_num_threads(n)
            out.append(run(fr, t, ALL, seed=3, chunk=7)[0].array.tobytes())
    finally:
        numba.set_num_threads(old)
    assert out[0] == out[1]


def _rdnet_imports(path):
    """Every rdnet module that ``path`` imports (top level or inside functions)."""
    import ast
    names = set()
    for node in ast.walk(ast.parse(open(path).read())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return {n for n in names if n.startswith("rdnet")}


def test_effects_does_not_import_the_sensor():
    """One direction only: the sensor builds on effects, never the reverse (issue 13)."""
    assert not {n for n in _rdnet_imports(effects.__file__) if "sensor" in n.split(".")[-1]}
    import rdnet.sim.sensor as sensor_mod
    assert "rdnet.sim.effects" in _rdnet_imports(sensor_mod.__file__)


@pytest.mark.parametrize("order", [("effects", "sensor"), ("sensor", "effects")])
def test_effects_and_sensor_import_alone_in_either_order(order):
    """A fresh interpreter imports each module first without pulling in the other one early."""
    import os
    import subprocess
    import sys
    first, second = order
    code = (f"import sys, rdnet.sim.{first}\n"
            f"assert ('rdnet.sim.sensor' in sys.modules) == ({first!r} == 'sensor')\n"
            f"import rdnet.sim.{second}\n")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
