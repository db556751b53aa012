"""The calibration's fast paths agree with the project's simulator and interpolator: the
composed engine (pixel circuit cached, noise and timing added on top) gives the same events
as ``rdnet.sim.pair.simulate`` for deterministic configs and the same event counts for
random ones; the numba summary equals the reference numpy one; frames warped only at the
sampled pixels equal the full-resolution frames sampled."""
import numpy as np
import pytest

from rdnet.calib import stats as st
from rdnet.calib.context import build_context, subsample_context, upsample_sampled
from rdnet.calib.engine import Engine
from rdnet.calib.fit import default_simulate
from rdnet.calib.settings import CalibrateConfig
from rdnet.sim.interpolate import InterpolateConfig, upsample_all
from rdnet.sim.settings import DegradeConfig, SensorConfig

import calib_cases

SENSOR = SensorConfig()


@pytest.fixture(scope="module")
def ctx():
    rec, _ = calib_cases.null_recording()
    return build_context(rec, CalibrateConfig(), SENSOR.log_eps, interpolate=calib_cases.INTERP)


def _sorted(a):
    return np.sort(a, order=["t", "y", "x", "p"])


@pytest.mark.parametrize("values", [{}, {"latency_us": 3000.0}, {"cutoff_hz": 100.0},
                                    {"refractory_us": 5000.0, "onoff_ratio": 1.4},
                                    {"sample_period_us": 2000.0}])
def test_engine_equals_simulator_for_deterministic_configs(ctx, values):
    d = DegradeConfig(**values)
    eng = Engine(ctx, random_reference=False)
    a = eng.events(SENSOR, d, 0).array
    b = default_simulate(ctx.sim_images, ctx.sim_t, SENSOR, d, None).array
    assert np.array_equal(_sorted(a), _sorted(b))
    assert np.all(np.diff(a["t"]) >= 0)


@pytest.mark.parametrize("values", [{"shot_noise_hz": 3.0},
                                    {"hot_pixel_fraction": 0.01, "hot_pixel_hz": 100.0, "jitter_us": 1000.0},
                                    {"threshold_sigma": 0.1, "leak_hz": 1.0}])
def test_engine_matches_simulator_in_distribution(ctx, values):
    d = DegradeConfig(**values)
    eng = Engine(ctx, random_reference=False)
    na = np.array([len(eng.events(SENSOR, d, s)) for s in range(6)], float)
    nb = np.array([len(default_simulate(ctx.sim_images, ctx.sim_t, SENSOR, d, np.random.default_rng(s)))
                   for s in range(6)], float)
    spread = np.sqrt(0.5 * (na.var(ddof=1) + nb.var(ddof=1)) * (2 / 6)) + 1.0
    assert abs(na.mean() - nb.mean()) < 4 * spread, (na, nb)
    # the same seed reuses the cached pixel-circuit events and the same noise streams
    assert np.array_equal(eng.compose(SENSOR, d, 3), eng.compose(SENSOR, d, 3))


def test_random_reference_gives_an_honest_seed_spread(ctx):
    """A deterministic config varies with the seed only through the initial reference:
    the same seed repeats, other seeds differ, and the count stays that of the simulator's
    own start (the reference is uniform between the thresholds, centred on it)."""
    d = DegradeConfig()
    eng = Engine(ctx, random_reference=True)
    assert eng.randomizes(d) and not Engine(ctx, random_reference=False).randomizes(d)
    runs = [eng.kernel_events(SENSOR, d, s) for s in range(4)]
    assert np.array_equal(runs[0], eng.kernel_events(SENSOR, d, 0))
    assert not np.array_equal(runs[0], runs[1])
    n = np.array([len(r) for r in runs], float)
    n0 = len(default_simulate(ctx.sim_images, ctx.sim_t, SENSOR, d, None))
    assert abs(n.mean() - n0) < 0.03 * n0, (n, n0)


def _reference_summary(events, ctx):
    """The numpy summary the numba kernel replaced."""
    a = events.array
    t = a["t"]
    a = a[(t >= ctx.t0) & (t < ctx.t1)]
    t = a["t"]
    S, P, B = len(ctx.segments), ctx.n_pixels, len(ctx.intensity_edges) - 1
    seg = np.minimum(np.searchsorted(ctx.segments[:, 1], t, side="right"), S - 1)
    pixel = a["y"].astype(np.int64) * ctx.width + a["x"]
    on = a["p"].astype(bool)
    key = seg * P + pixel
    pix = np.bincount(key, minlength=S * P).reshape(S, P)
    mids = (ctx.frame_t[:-1] + ctx.frame_t[1:]) // 2
    b = ctx.frame_bin_flat[np.searchsorted(mids, t, side="right"), pixel].astype(np.int64)
    ibin_on = np.bincount((seg * B + b)[on], minlength=S * B).reshape(S, B)
    order = np.argsort(pixel, kind="stable")
    same = pixel[order][1:] == pixel[order][:-1]
    dt = (t[order][1:] - t[order][:-1])[same]
    lb = np.searchsorted(st.IEI_EDGES, np.log10(np.maximum(dt, 1).astype(np.float64)), side="right")
    nI = len(st.IEI_EDGES) + 1
    iei = np.bincount(seg[order][1:][same] * nI + lb, minlength=S * nI).reshape(S, nI)
    return pix, ibin_on, iei


def test_numba_summary_equals_reference(ctx):
    ev = Engine(ctx).events(SENSOR, DegradeConfig(shot_noise_hz=2.0, jitter_us=500.0), 1)
    s = st.summarize(ev, ctx)
    pix, ibin_on, iei = _reference_summary(ev, ctx)
    assert np.array_equal(s.pix, pix) and np.array_equal(s.ibin_on, ibin_on) and np.array_equal(s.iei, iei)
    # order does not matter
    rng = np.random.default_rng(0)
    a = ev.array[rng.permutation(len(ev))]
    s2 = st.summarize_arrays(a["t"], a["x"], a["y"], a["p"], ctx)
    assert all(np.array_equal(getattr(s, f), getattr(s2, f)) for f in ("pix", "pix_on", "ibin", "ibin_on",
                                                                         "iei", "rate_t"))


@pytest.mark.parametrize("method", ["flow", "linear"])
def test_sampled_upsampling_equals_full_resolution(method):
    rec, _ = calib_cases.null_recording()
    g, t = rec.frames.grey()[:6], rec.frames.t_us[:6].astype(np.int64)
    cfg = InterpolateConfig(method=method, max_upsample=8)
    a, ta = upsample_sampled(g, t, cfg, 0.01, 3)
    b, tb = upsample_all(g, t, cfg, 0.01)
    b = b[:, ::3, ::3]
    if np.array_equal(ta, tb):            # the counts may differ (the bound is checked on the sample)
        assert np.allclose(a, b, atol=1e-6)
    else:
        assert a.shape[0] <= b.shape[0]


def test_subsample_context_slices_the_sample(ctx):
    sub = subsample_context(ctx, 2)
    assert sub.stride == 2 * ctx.stride and sub.width == len(range(0, ctx.width, 2))
    assert np.array_equal(sub.sim_images, ctx.sim_images[:, ::2, ::2])
    assert np.array_equal(sub.intensity_edges, ctx.intensity_edges)
    assert len(sub.real) == int(((ctx.real.x % 2 == 0) & (ctx.real.y % 2 == 0)).sum())


def test_sensor_uses_the_log_frames_it_is_given(ctx):
    """The engine hands the sensor the log frames it keeps (low-pass runs need both the
    linear and the log intensity): the events are those of the sensor computing them."""
    from rdnet.errors import ValidationError
    from rdnet.sim.sensor import Sensor

    d = DegradeConfig(cutoff_hz=100.0)
    lin, t = ctx.sim_images, ctx.sim_t
    logf = Engine(ctx).log_frames(SENSOR.log_eps)
    runs = []
    for given in (None, logf):
        s = Sensor(ctx.width, ctx.height, SENSOR, d)
        runs.append(s.step(lin, t, log_frames=given).array)
    assert len(runs[0]) > 100 and np.array_equal(runs[0], runs[1])
    with pytest.raises(ValidationError):
        Sensor(ctx.width, ctx.height, SENSOR, d).step(lin, t, log_frames=logf.astype(np.float64))
    with pytest.raises(ValidationError):
        Sensor(ctx.width, ctx.height, SENSOR, d).step(logf, t, log=True, log_frames=logf)


@pytest.mark.parametrize("group", [1, 2])
@pytest.mark.parametrize("scale", [1, 5])
def test_gather_sorts_each_step_stably(scale, group):
    """The ideal sensor's gather sorts each step's events by time, ties in row then buffer
    order, steps in order (an event at a step's end time precedes the next step's), whether
    the step is sorted by a histogram over its span (scale 1: 1,001 us, 4 events) or by a
    merge sort (scale 5: the span is long for its events), and whether the kernel wrote a
    buffer per row (group 1) or one for both rows (group 2: step by step, row by row)."""
    from rdnet.events.core import EVENT_DTYPE
    from rdnet.sim.sensor import _gather_sorted

    # (t, x, p) per row and step: row 0 = step 0: (5, 1), (3, 2); step 1: (1000, 0), (1700, 1)
    #                             row 1 = step 0: (3, 0), (1000, 3); step 1: (1000, 4)
    ev = {(0, 0): [(5, 1, 1), (3, 2, 0)], (0, 1): [(1000, 0, 1), (1700, 1, 0)],
          (1, 0): [(3, 0, 1), (1000, 3, 1)], (1, 1): [(1000, 4, 0)]}
    order = ([(0, 0), (0, 1), (1, 0), (1, 1)] if group == 1 else [(0, 0), (1, 0), (0, 1), (1, 1)])  # (row, step)
    cap = 4 if group == 1 else 8
    buf = {0: [], 1: []}
    for row, step in order:
        buf[row // group] += ev[row, step]
    rows = [buf[b] + [(0, 0, 0)] * (cap - len(buf[b])) for b in range(2 // group)]
    t, x, p = (np.array([e[i] for r in rows for e in r], dt) for i, dt in ((0, np.int64), (1, np.uint16), (2, np.uint8)))
    t = t * scale
    seg = np.array([[2, 2], [2, 1]], np.int64)
    out = np.empty(7, EVENT_DTYPE)
    _gather_sorted(t, x, p, seg, cap, group, np.array([1000, 2000], np.int64) * scale, 0, out)
    want = [(3, 2, 0), (3, 0, 1), (5, 1, 0), (1000, 3, 1), (1000, 0, 0), (1000, 4, 1), (1700, 1, 0)]
    assert [(int(e["t"]), int(e["x"]), int(e["y"])) for e in out] == [(a * scale, b, c) for a, b, c in want]


def test_warm_up_runs_only_configs_with_leak_or_shot_noise(ctx):
    """The warm-up on the held first frame (rdnet.calib.engine.start) runs only with leak
    or shot noise: any other config gives the same events with or without it, and events
    before the recording's first frame are dropped. (Its known answers: the stationary leak
    rate under noise resets, tested against the circuit model in tests/circuit, and the
    state it leaves, below.)"""
    cold, warm = Engine(ctx, warmup_us=0), Engine(ctx, warmup_us=3_000_000)
    det = DegradeConfig(refractory_us=2000.0, threshold_sigma=0.1)
    assert np.array_equal(cold.events(SENSOR, det, 1).array, warm.events(SENSOR, det, 1).array)
    for noisy in (DegradeConfig(shot_noise_hz=2.0), DegradeConfig(leak_hz=1.0, shot_noise_hz=1.0)):
        a, b = cold.events(SENSOR, noisy, 1).array, warm.events(SENSOR, noisy, 1).array
        assert not np.array_equal(a, b)
        assert b["t"].min() >= ctx.sim_t[0]


def test_warm_up_leaves_static_pixels_at_their_last_reset_and_redraws_moving_ones():
    """The state rdnet.calib.engine.start leaves on a still frame under shot noise alone:
    after 20 s at 2 Hz every pixel has fired a noise event (all but e^-40 of them), which
    set its reference to its constant level, so ref == S for the static pixels. The pixels
    that move in the recording did not see a still scene before it, so their reference is
    drawn between the thresholds again: S - ref = u (theta_on + theta_off) - theta_off."""
    from rdnet.calib.engine import start
    from rdnet.sim.sensor import Sensor
    h, w = 8, 16
    frame = np.full((1, h, w), 0.3, np.float32)
    deg = DegradeConfig(shot_noise_hz=2.0)
    u = np.random.default_rng(1).random((h, w))
    moving = np.zeros((h, w), bool)
    moving[:, :5] = True
    states = {}
    for name, mask in (("masked", moving), ("unmasked", None)):
        s = Sensor(w, h, SENSOR, deg, np.random.default_rng(0))
        assert start(s, deg, frame, 0, u, 20_000_000, moving=mask)
        states[name] = (s.s_prev.copy(), s.ref.copy(), s.thr_on, s.thr_off)
    level, ref, on, off = states["masked"]
    np.testing.assert_allclose(ref[~moving], level[~moving], rtol=0, atol=1e-12)
    np.testing.assert_allclose((level - ref)[moving], (u * (on + off) - off)[moving], rtol=0, atol=1e-12)
    level_u, ref_u = states["unmasked"][:2]
    np.testing.assert_allclose(ref_u, level_u, rtol=0, atol=1e-12)   # without the mask: all at a reset
    # and the spread the redraw restores is the full interval between the thresholds
    assert (level - ref)[moving].min() < -0.5 * off[0, 0] and (level - ref)[moving].max() > 0.5 * on[0, 0]


def test_warm_up_must_not_be_negative():
    from rdnet.errors import ConfigError
    with pytest.raises(ConfigError, match="calibrate.warmup_us"):
        CalibrateConfig(warmup_us=-1)
