"""Paired simulation, frame inputs, and randomized degradation."""
import dataclasses

import numpy as np
import pytest

from rdnet.errors import ConfigError, ValidationError
from rdnet.events.recording import Frames
from rdnet.sim.pair import frame_chunks, simulate, simulate_pair
from rdnet.sim.randomize import degradation_level, degrade_factors, draw_degrade, draw_scale, scale_degrade
from rdnet.sim.settings import EFFECT_KEYS, EFFECT_SCALING, DegradeConfig, RandomizeConfig, SensorConfig

DEG = DegradeConfig(threshold_sigma=0.1, onoff_ratio=1.3, cutoff_hz=300, sample_period_us=200,
                    refractory_us=100, shot_noise_hz=5, leak_hz=1, hot_pixel_fraction=0.01,
                    hot_pixel_hz=200, jitter_us=300, latency_us=50)


def moving_bar(n=24, h=16, w=20, color=False):
    t = np.arange(n, dtype=np.int64) * 1000
    x = np.arange(w)[None, None, :]
    im = 0.1 + 0.8 / (1 + np.exp(-(x - 3 - 0.5 * np.arange(n)[:, None, None])))
    im = np.broadcast_to(im, (n, h, w)).astype(np.float32)
    if color:
        im = np.stack([im, 0.5 * im, 0.25 * im], axis=-1)
    return np.ascontiguousarray(im), t


def test_pair_matches_single_simulations_and_is_deterministic():
    im, t = moving_bar()
    ideal, deg = simulate_pair(im, t, SensorConfig(), DEG, np.random.default_rng(5), chunk=5)
    assert len(ideal) > 100
    assert np.array_equal(ideal.array, simulate(im, t).array)
    assert np.array_equal(deg.array, simulate(im, t, SensorConfig(), DEG, np.random.default_rng(5), chunk=5).array)
    again = simulate_pair(im, t, SensorConfig(), DEG, np.random.default_rng(5), chunk=5)
    assert again[1].array.tobytes() == deg.array.tobytes()
    other = simulate_pair(im, t, SensorConfig(), DEG, np.random.default_rng(6), chunk=5)
    assert other[1].array.tobytes() != deg.array.tobytes()
    assert np.array_equal(other[0].array, ideal.array)


def test_no_degradation_is_ideal():
    im, t = moving_bar()
    a, b = simulate_pair(im, t, SensorConfig(), DegradeConfig(), None)
    assert np.array_equal(a.array, b.array)


def test_colour_and_uint8_frames_become_luminance():
    im, t = moving_bar(color=True)
    grey = Frames(im, t, 0).grey()
    assert np.array_equal(simulate(Frames(im, t, 0)).array, simulate(grey, t).array)
    u8 = (im * 255).round().astype(np.uint8)
    assert np.array_equal(simulate(u8, t).array, simulate(u8.astype(np.float32) / 255, t).array)


def test_bad_input():
    im, t = moving_bar()
    bad = im.copy()
    bad[3, 2, 1] = np.nan
    with pytest.raises(ValidationError):
        simulate(bad, t)
    bad[3, 2, 1] = -1
    with pytest.raises(ValidationError):
        simulate(bad, t)
    with pytest.raises(ValidationError):
        simulate(im[0], t[:1])                  # (H, W): not a frame stack
    with pytest.raises(ValidationError):
        simulate(im, t[::-1])
    with pytest.raises(ValidationError):
        simulate(im, t[:-1])
    with pytest.raises(ValidationError):
        simulate(im, None)


def test_frame_chunks_stream_and_interpolation():
    from rdnet.sim.interpolate import InterpolateConfig
    im, t = moving_bar(n=12)
    parts = [Frames(im[i:i + 5], t[i:i + 5], 0) for i in range(0, 12, 5)]
    got = list(frame_chunks(iter(parts), chunk=4))
    assert np.array_equal(np.concatenate([c[1] for c in got]), t)
    assert np.array_equal(np.concatenate([c[0] for c in got]), im)
    cfg = InterpolateConfig(method="linear", max_log_step=0.02, max_upsample=8)
    up = list(frame_chunks(iter(parts), interpolate=cfg, chunk=16))
    tt = np.concatenate([c[1] for c in up])
    assert np.all(np.diff(tt) > 0) and set(t) <= set(tt) and tt.size > t.size
    assert simulate(im, t, interpolate=InterpolateConfig(method="none")).array.tobytes() == \
        simulate(im, t).array.tobytes()


def _draws(split, n=200, base=DEG, cfg=RandomizeConfig()):
    rng = np.random.default_rng(0)
    return [draw_degrade(base, cfg, split, rng) for _ in range(n)]


def test_train_and_test_degradations_are_disjoint_for_every_key():
    train, test = _draws("train"), _draws("test")
    for k in DEG.active():
        a = np.array([getattr(d, k) for d in train])
        b = np.array([getattr(d, k) for d in test])
        if k == "cutoff_hz":                         # a lower cutoff is the stronger limit
            assert a.min() > b.max(), k
        else:
            assert a.max() < b.min(), k
        assert np.unique(a).size > 100               # drawn per sequence
    lv_train = [degradation_level(d, DEG) for d in train]
    lv_test = [degradation_level(d, DEG) for d in test]
    assert max(lv_train) < min(lv_test)
    assert degradation_level(DEG, DEG) == pytest.approx(1.0)
    assert degradation_level(DegradeConfig(), DEG) == 0.0


def test_a_key_with_a_training_scale_of_its_own():
    # train_scale brackets the test range for every key but the bandwidth limit, whose own
    # training scale stays on one side of it; every other draw is the shared config's, bit
    # for bit, and the test split is untouched
    bracket = [[0.5, 0.9], [1.6, 2.0]]
    own = RandomizeConfig(train_scale=bracket, train_scale_keys={"cutoff_hz": [0.5, 0.9]})
    shared = RandomizeConfig(train_scale=bracket)
    assert own.train_ranges_of("cutoff_hz") == ((0.5, 0.9),) and own.train_ranges_of("leak_hz") == ((0.5, 0.9), (1.6, 2.0))
    a, b = _draws("train", cfg=own), _draws("train", cfg=shared)
    m_own = np.array([degrade_factors(d, DEG)["cutoff_hz"] for d in a])
    m_shared = np.array([degrade_factors(d, DEG)["cutoff_hz"] for d in b])
    assert m_own.min() >= 0.5 - 1e-9 and m_own.max() <= 0.9 + 1e-9
    assert (m_shared > 1.5).any()                                # the shared scale would bracket it
    for seed in range(50):        # one sequence's other keys: the shared draws (the own draw comes after)
        x, y = (draw_degrade(DEG, c, "train", np.random.default_rng(seed)) for c in (own, shared))
        assert dataclasses.replace(x, cutoff_hz=0.0) == dataclasses.replace(y, cutoff_hz=0.0)
    assert _draws("test", cfg=own) == _draws("test", cfg=shared)
    with pytest.raises(ConfigError, match="train_scale_keys.cutoff_hz.*disjoint"):
        RandomizeConfig(train_scale_keys={"cutoff_hz": [0.5, 1.2]})
    with pytest.raises(ConfigError, match="randomize.train_scale_keys.*unknown degrade key 'bogus'"):
        RandomizeConfig(train_scale_keys={"bogus": [0.5, 0.9]})
    with pytest.raises(ConfigError, match=r"randomize.train_scale_keys.leak_hz.*\[lo, hi\]"):
        RandomizeConfig(train_scale_keys={"leak_hz": [0.5]})
    with pytest.raises(ConfigError, match=r"'randomize.train_scale_keys.leak_hz': must be at most 100"):
        RandomizeConfig(train_scale_keys={"leak_hz": [[0.5, 0.9], [2.0, 1e300]]})
    with pytest.raises(ConfigError, match="randomize.train_scale_keys.*'leak_hz' is not randomized"):
        RandomizeConfig(keys=("cutoff_hz",), train_scale_keys={"leak_hz": [0.5, 0.9]})
    with pytest.raises(ConfigError, match="randomize.train_scale_keys.*mapping"):
        RandomizeConfig(train_scale_keys=[0.5, 0.9])


def test_scale_makes_every_key_stronger_and_round_trips():
    # m = 0 is the ideal sensor, a larger m a stronger degradation, for every key; the
    # bandwidth limit's strength is its time constant, so its cutoff is divided by m
    s = scale_degrade(DEG, {"cutoff_hz": 2.0, "refractory_us": 2.0, "onoff_ratio": 2.0})
    assert s.cutoff_hz == pytest.approx(DEG.cutoff_hz / 2)
    assert s.refractory_us == pytest.approx(DEG.refractory_us * 2)
    assert s.onoff_ratio == pytest.approx(DEG.onoff_ratio ** 2)
    off = scale_degrade(DEG, {k: 0.0 for k in DEG.active()})
    assert off.is_ideal
    factors = {k: 0.5 + 0.1 * i for i, k in enumerate(DEG.active())}
    back = degrade_factors(scale_degrade(DEG, factors), DEG)
    assert back == pytest.approx(factors)
    assert degrade_factors(off, DEG) == {k: 0.0 for k in DEG.active()}


def test_effect_scaling_agrees_with_the_calibrations_search_direction():
    # one notion of "stronger" per degrade key: the calibration searches each parameter from
    # its weak end, which must be the end a factor m -> 0 moves the value towards
    from rdnet.calib.effects import EFFECTS
    weak_end = {"linear": "lo", "log": "off", "inverse": "hi"}
    keys = [p for e in EFFECTS.values() for p in e.params if p.key in EFFECT_SCALING]
    assert {p.key for p in keys} == set(EFFECT_KEYS)
    for p in keys:
        assert p.weak == weak_end[EFFECT_SCALING[p.key]], p.key


def test_randomize_details():
    base = DegradeConfig(shot_noise_hz=2.0, onoff_ratio=2.0)
    d = draw_degrade(base, RandomizeConfig(), "test", np.random.default_rng(1))
    assert d.active() == ["onoff_ratio", "shot_noise_hz"]           # off stays off
    f = degrade_factors(d, base)
    lo, hi = RandomizeConfig().test_scale                             # (1.0, 1.5)
    assert lo <= f["onoff_ratio"] <= hi and lo <= f["shot_noise_hz"] <= hi
    only = draw_degrade(base, RandomizeConfig(keys=("shot_noise_hz",)), "train", np.random.default_rng(1))
    assert only.onoff_ratio == 2.0 and only.shot_noise_hz < 2.0
    assert draw_degrade(base, RandomizeConfig(enabled=False, train_scale=(1, 1), test_scale=(1, 1)),
                        "train", np.random.default_rng(1)) == base
    with pytest.raises(ConfigError):
        draw_degrade(base, RandomizeConfig(), "val", np.random.default_rng(1))
    capped = draw_degrade(dataclasses.replace(base, hot_pixel_fraction=0.9, hot_pixel_hz=1.0),
                          RandomizeConfig(), "test", np.random.default_rng(1))
    assert capped.hot_pixel_fraction <= 1.0
    assert set(EFFECT_KEYS) >= set(DEG.active())


def test_draw_scale_union():
    # one range: the very bits of rng.uniform (configs with one range draw as before)
    assert np.array_equal(draw_scale([(0.5, 0.9)], 7, np.random.default_rng(3)),
                          np.random.default_rng(3).uniform(0.5, 0.9, size=7))
    d = draw_scale([(0.5, 0.9), (1.6, 2.4)], 20000, np.random.default_rng(0))
    assert ((d >= 0.5) & (d <= 0.9) | (d >= 1.6) & (d <= 2.4)).all()
    assert (d < 1.0).mean() == pytest.approx(0.4 / 1.2, abs=0.01)   # a range's share = its length's
    assert d[d > 1.0].min() < 1.62 and d[d > 1.0].max() > 2.38 and d[d < 1.0].max() > 0.88
    assert np.array_equal(draw_scale([(0.5, 0.9), (1.6, 2.4)], 5, np.random.default_rng(1)),
                          draw_scale([(0.5, 0.9), (1.6, 2.4)], 5, np.random.default_rng(1)))
    assert set(draw_scale([(1.0, 1.0), (2.0, 2.0)], 50, np.random.default_rng(0))) == {1.0, 2.0}
    # a degradation drawn from a union: every factor in one of the ranges, both sides used
    cfg = RandomizeConfig(train_scale=((0.5, 0.9), (1.6, 2.0)), test_scale=(1.0, 1.5))
    f = [m for s in range(30) for m in degrade_factors(draw_degrade(DEG, cfg, "train", np.random.default_rng(s)),
                                                        DEG).values()]
    f = np.array(f)
    assert (((f >= 0.5 - 1e-9) & (f <= 0.9 + 1e-9)) | ((f >= 1.6 - 1e-9) & (f <= 2.0 + 1e-9))).all()
    assert (f < 1).any() and (f > 1).any()


# --- prefetch: the producer thread of the CLI ---------------------------------------------------

def _prefetch_threads():
    import threading
    return [t for t in threading.enumerate() if t.name == "rdnet-prefetch"]


def test_prefetch_keeps_items_and_order_and_bounds_the_lead():
    from rdnet.sim.pair import prefetch
    produced = []

    def items():
        for i in range(50):
            produced.append(i)
            yield np.full(3, i)

    got = []
    for a in prefetch(items(), depth=2):
        # the producer is at most depth items (+ the one it holds) ahead of the consumer
        assert len(produced) - len(got) <= 4
        got.append(int(a[0]))
    assert got == list(range(50))
    assert not _prefetch_threads()
    assert list(prefetch([])) == []
    with pytest.raises(ValidationError):
        next(prefetch([1], depth=0))


def test_prefetch_raises_producer_errors_in_the_consumer_and_stops_on_close():
    from rdnet.sim.pair import prefetch

    def failing():
        yield 1
        yield 2
        raise ValueError("broken chunk")

    it = prefetch(failing())
    assert [next(it), next(it)] == [1, 2]
    with pytest.raises(ValueError, match="broken chunk"):
        next(it)
    assert not _prefetch_threads()

    closed = []

    def endless():
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.append(True)

    it = prefetch(endless(), depth=1)
    assert next(it) == 0
    it.close()   # the consumer stops early: the producer stops, its generator is closed
    assert closed == [True]
    assert not _prefetch_threads()


def test_frame_chunks_hand_over_the_log_frames_the_statistics_computed():
    import dataclasses as dc

    from rdnet.sim.interpolate import InterpolateConfig, UpsampleStats
    rng = np.random.default_rng(1)
    im = rng.integers(0, 256, (11, 36, 40), dtype=np.uint8)
    t = np.arange(11, dtype=np.int64) * 1000
    parts = [Frames(im[i:i + 4], t[i:i + 4], np.zeros(len(t[i:i + 4]), np.int64)) for i in range(0, 11, 4)]
    cfg = InterpolateConfig(method="flow", max_upsample=1, pixel_quantile=0.99)
    plain_stats, log_stats = UpsampleStats(), UpsampleStats()
    plain = list(frame_chunks(parts, interpolate=cfg, log_eps=0.02, chunk=4, stats=plain_stats))
    got = list(frame_chunks(parts, interpolate=cfg, log_eps=0.02, chunk=4, stats=log_stats, with_log=True))
    assert [len(c) for c in got] == [3] * len(plain) and len(plain) == 3
    assert plain_stats.as_dict() == log_stats.as_dict()
    for (g, tt), (g2, tt2, lg) in zip(plain, got):
        assert np.array_equal(g, g2) and np.array_equal(tt, tt2)
        assert lg.dtype == np.float32 and np.array_equal(lg, np.log(g + np.float32(0.02)))
    # not computed (None): frames inserted, another log_eps, no interpolation at all
    for c, eps in ((dc.replace(cfg, max_upsample=4, method="linear"), 0.02), (dc.replace(cfg, log_eps=0.05), 0.02)):
        assert all(lg is None for *_, lg in frame_chunks(parts, interpolate=c, log_eps=eps, chunk=4, with_log=True))
    assert all(lg is None for *_, lg in frame_chunks(parts, log_eps=0.02, chunk=4, with_log=True))
