"""Adaptive flow/linear upsampling (rdnet.sim.interpolate)."""
import numpy as np
import pytest

import cv2

from rdnet.config import from_dict
from rdnet.errors import ConfigError, ValidationError
from rdnet.sim.interpolate import (InterpolateConfig, UpsampleStats, interpolate_pair, log_steps,
                                   upsample, upsample_all)
from rdnet.sim.scenes import procedural_texture


def _psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((a - b) ** 2))


def _translated(tex, shifts, h=64, w=64, margin=24):
    """Crops of ``tex`` translated by sub-pixel (dx, dy) shifts (the true frames)."""
    out = []
    for dx, dy in shifts:
        m = np.float32([[1, 0, margin + dx], [0, 1, margin + dy]])
        out.append(cv2.warpAffine(tex, m, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP))
    return np.stack(out).astype(np.float32)


@pytest.fixture(scope="module")
def texture():
    tex = procedural_texture("noise", 128, 128, np.random.default_rng(3))[..., 1]
    return np.ascontiguousarray(cv2.GaussianBlur(tex, (0, 0), 1.0))


@pytest.mark.parametrize("flow", ["dis", "farneback"])
def test_flow_beats_linear_on_translation(texture, flow):
    # 6 px motion between the two inputs; truth at 5 intermediate times
    n = 5
    ts = np.arange(n + 2) / (n + 1)
    truth = _translated(texture, [(6.0 * t, 2.0 * t) for t in ts])
    f0, f1 = truth[0], truth[-1]
    fl = interpolate_pair(f0, f1, n, InterpolateConfig(method="flow", flow=flow))
    li = interpolate_pair(f0, f1, n, InterpolateConfig(method="linear"))
    inner = (slice(None), slice(8, -8), slice(8, -8))      # borders: content entering the view
    p_flow = _psnr(fl[inner], truth[1:-1][inner])
    p_lin = _psnr(li[inner], truth[1:-1][inner])
    assert fl.shape == (n, 64, 64) and fl.dtype == np.float32
    assert p_flow > p_lin + 6.0, (p_flow, p_lin)
    assert p_flow > 30.0


def test_linear_is_exact_blend():
    rng = np.random.default_rng(0)
    f0, f1 = rng.random((2, 8, 9, 3), dtype=np.float32)
    out = interpolate_pair(f0, f1, 3, InterpolateConfig(method="linear"))
    for k, t in enumerate([0.25, 0.5, 0.75]):
        np.testing.assert_allclose(out[k], (1 - t) * f0 + t * f1, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("method", ["flow", "linear", "cubic"])
def test_log_step_bound_and_timestamps(texture, method):
    shifts = [(1.5 * i, 0.5 * i) for i in range(4)]
    ims = _translated(texture, shifts) * 0.8 + 0.1
    t_us = np.array([0, 4167, 8333, 12500], np.int64)
    cfg = InterpolateConfig(method=method, max_log_step=0.1, max_upsample=256)
    stats = UpsampleStats()
    out, t = upsample_all(ims, t_us, cfg, log_eps=0.01, stats=stats)
    assert stats.violations == 0
    assert log_steps(out, 0.01, color=False) <= 0.1
    assert stats.max_log_step <= 0.1
    assert np.all(np.diff(t) > 0) and t.dtype == np.int64
    # inputs are kept at their timestamps
    idx = np.searchsorted(t, t_us)
    np.testing.assert_array_equal(t[idx], t_us)
    np.testing.assert_array_equal(out[idx], ims)
    assert log_steps(ims, 0.01, color=False) > 0.1         # the inputs alone violate the bound
    assert out.shape[0] == 4 + stats.inserted and stats.inserted >= 3


def test_stream_equals_all_and_chunk_layout(texture):
    ims = _translated(texture, [(2.0 * i, 0.0) for i in range(4)])
    rgb = np.stack([ims, 0.5 * ims, ims ** 2], -1).astype(np.float32)
    t_us = np.array([0, 1000, 2000, 3000], np.int64)
    cfg = InterpolateConfig(max_log_step=0.2)
    chunks = list(upsample(rgb, t_us, cfg))
    assert len(chunks) == 3
    for i, (c, t) in enumerate(chunks):
        assert t[0] == t_us[i] and np.array_equal(c[0], rgb[i])
        assert c.shape[1:] == (64, 64, 3)
    assert chunks[-1][1][-1] == 3000 and np.array_equal(chunks[-1][0][-1], rgb[-1])
    out, t = upsample_all(rgb, t_us, cfg)
    np.testing.assert_array_equal(out, np.concatenate([c for c, _ in chunks]))
    np.testing.assert_array_equal(t, np.concatenate([t for _, t in chunks]))


def test_cap_by_timestamps_and_max_upsample(texture):
    ims = _translated(texture, [(0, 0), (8, 0)])
    # only 3 us between the frames -> at most 2 inserted, strictly increasing
    out, t = upsample_all(ims, np.array([10, 13]), InterpolateConfig(max_log_step=0.01))
    np.testing.assert_array_equal(t, [10, 11, 12, 13])
    st = UpsampleStats()
    out, t = upsample_all(ims, np.array([0, 10_000]), InterpolateConfig(max_log_step=0.01, max_upsample=4), stats=st)
    assert out.shape[0] == 5 and st.violations == 1
    out, t = upsample_all(ims, np.array([0, 10_000]), InterpolateConfig(method="none"))
    assert out.shape[0] == 2


def test_pixel_quantile_relaxes_the_bound(texture):
    tex = texture.copy()
    tex[50:54, 60:64] = 0.08         # a few dark pixels, where log(I + eps) is steepest
    ims = _translated(tex, [(0, 0), (3, 1)])
    t = np.array([0, 100_000])
    counts = {}
    for q in (1.0, 0.9):
        st = UpsampleStats()
        out, _ = upsample_all(ims, t, InterpolateConfig(max_log_step=0.1, max_upsample=1024, pixel_quantile=q), stats=st)
        assert st.violations == 0 and log_steps(out, 0.01, color=False, quantile=q) <= 0.1
        counts[q] = st.inserted
    assert counts[0.9] < counts[1.0]


def test_config_validation_and_bad_input():
    with pytest.raises(ConfigError, match="interpolate.max_log_step"):
        InterpolateConfig(max_log_step=0)
    with pytest.raises(ConfigError, match="interpolate.method"):
        from_dict(InterpolateConfig, {"method": "spline"}, "interpolate")
    with pytest.raises(ConfigError, match="interpolate.bogus"):
        from_dict(InterpolateConfig, {"bogus": 1}, "interpolate")
    with pytest.raises(ConfigError, match="interpolate.max_upsample"):
        InterpolateConfig(max_upsample=0)
    ims = np.zeros((2, 8, 8), np.float32)
    with pytest.raises(ValidationError):
        upsample_all(ims, np.array([5, 5]))
    with pytest.raises(ValidationError):
        upsample_all(ims, np.array([0.0, 1.5]))


def _edge_scene(n=3, shift_px=4.0, h=32, w=48):
    """A sharp black/white edge moving right: the dark pixels beside it need ~1,000 steps
    per pixel of motion to keep |delta log(Y + 0.01)| under 0.1 (the strict bound fails at
    any reasonable max_upsample)."""
    x = np.arange(w, dtype=np.float32)
    frames = []
    for i in range(n):
        edge = 16.0 + shift_px * i
        frames.append(np.broadcast_to(np.clip(x - edge + 0.5, 0, 1), (h, w)))
    return np.stack(frames).astype(np.float32), np.arange(n, dtype=np.int64) * 4167


def _steps(out, eps=0.01):
    return np.abs(np.diff(np.log(out.astype(np.float32) + np.float32(eps)), axis=0))


def test_capped_bound_is_reported_and_warned(caplog):
    ims, t = _edge_scene()
    st = UpsampleStats()
    cfg = InterpolateConfig(max_log_step=0.1, max_upsample=8)
    with caplog.at_level("WARNING", logger="rdnet.sim.interpolate"):
        out, _ = upsample_all(ims, t, cfg, log_eps=0.01, stats=st)
    d = _steps(out)
    assert st.violations == 2 and st.pairs == 2 and st.filled == 0
    assert st.pixel_steps == d.size and st.pixel_steps_over == int((d > 0.1).sum())
    assert 0 < st.over_bound_fraction < 0.1
    assert st.strict_max_log_step == pytest.approx(float(d.max()), rel=1e-6) and st.strict_max_log_step > 1.0
    assert st.needed_upsample > 8
    assert "exceeded in 2 of 2 frame pairs" in caplog.text
    summary = st.as_dict()
    assert summary["upsample_violations"] == 2 and summary["log_step_over_fraction"] == pytest.approx(st.over_bound_fraction, rel=1e-5)


@pytest.mark.parametrize("color", [False, True])
def test_fill_log_guarantees_the_bound_for_every_pixel(color, caplog):
    ims, t = _edge_scene()
    if color:
        ims = np.stack([ims, 0.5 * ims, 0.2 + 0.8 * ims], -1).astype(np.float32)
    st = UpsampleStats()
    cfg = InterpolateConfig(max_log_step=0.1, max_upsample=8, fill_log=True)
    with caplog.at_level("WARNING", logger="rdnet.sim.interpolate"):
        out, tu = upsample_all(ims, t, cfg, log_eps=0.01, stats=st)
    assert log_steps(out, 0.01, color=color) <= 0.1          # every pixel, every step
    assert st.violations == 0 and st.pixel_steps_over == 0 and st.strict_max_log_step <= 0.1
    assert st.filled > 0 and out.shape[0] == 3 + st.inserted and np.all(np.diff(tu) > 0)
    np.testing.assert_array_equal(out[np.searchsorted(tu, t)], ims)   # inputs kept
    assert "exceeded" not in caplog.text


def test_fill_log_is_what_the_sensor_assumes_between_frames():
    """Log-linear fill frames do not change the ideal sensor's events (up to the
    microsecond rounding): the simulator interpolates log intensity linearly anyway."""
    from rdnet.sim.pair import simulate
    ims, t = _edge_scene()
    plain, tp = upsample_all(ims, t, InterpolateConfig(max_log_step=0.1, max_upsample=8))
    filled, tf = upsample_all(ims, t, InterpolateConfig(max_log_step=0.1, max_upsample=8, fill_log=True))
    assert filled.shape[0] > 2 * plain.shape[0]
    a, b = simulate(plain, tp), simulate(filled, tf)
    assert len(a) > 100
    np.testing.assert_array_equal(a.count_per_pixel(1), b.count_per_pixel(1))
    np.testing.assert_array_equal(a.count_per_pixel(0), b.count_per_pixel(0))
    ka = np.lexsort((a.t, a.x, a.y, a.p))
    kb = np.lexsort((b.t, b.x, b.y, b.p))
    assert np.abs(a.t[ka] - b.t[kb]).max() <= 1


def test_occlusion_weights_keep_frames_continuous_at_the_ends(texture):
    """A textured square moving over another texture: occlusion masks are active, and
    the interpolated frame still tends to the inputs at t -> 0 and t -> 1."""
    from rdnet.sim.interpolate import PairInterpolator
    bg = _translated(texture, [(0, 0)])[0] * 0.8 + 0.1
    fg = procedural_texture("checkerboard", 64, 64, np.random.default_rng(1))[..., 0]
    frames = []
    for dx in (0, 7):
        f = bg.copy()
        f[20:40, 14 + dx:34 + dx] = fg[20:40, 14:34] * 0.9 + 0.05
        frames.append(f)
    pi = PairInterpolator(frames[0], frames[1], InterpolateConfig(method="flow"))
    _, _, o0, o1, _ = pi._prepare()
    assert o0.sum() > 10 and o1.sum() > 10
    for t, ref in ((1e-3, frames[0]), (1 - 1e-3, frames[1])):
        assert np.abs(pi.frame(t) - ref).max() < 0.02


def test_streamed_upsampling_collects_stats_once_per_pair(caplog):
    """frame_chunks (simulate's path) streams Frames chunks through upsample: the stats
    cover every pair once and the bound warning is logged once."""
    from rdnet.events.recording import Frames
    from rdnet.sim.pair import frame_chunks
    ims, t = _edge_scene(n=5, shift_px=2.0)
    cfg = InterpolateConfig(max_log_step=0.1, max_upsample=4)
    whole = UpsampleStats()
    upsample_all(ims, t, cfg, log_eps=0.01, stats=whole, warn=False)
    st = UpsampleStats()
    parts = [Frames(ims[i:i + 2], t[i:i + 2], np.zeros(len(t[i:i + 2]), np.int64)) for i in range(0, 5, 2)]
    with caplog.at_level("WARNING", logger="rdnet.sim.interpolate"):
        steps = sum(len(c[1]) for c in frame_chunks(parts, interpolate=cfg, log_eps=0.01, chunk=7, stats=st))
    assert st.pairs == whole.pairs == 4 and steps == 5 + st.inserted
    assert (st.pixel_steps, st.pixel_steps_over, st.violations) == (whole.pixel_steps, whole.pixel_steps_over, whole.violations)
    assert caplog.text.count("exceeded") == 1


def test_occlusion_norms_equal_the_axis_sum():
    """The forward-backward check's squared norms, written out per component, are the
    float32 sums over the last axis bit for bit, and so is the occlusion mask."""
    from rdnet.sim import interpolate as ip

    rng = np.random.default_rng(5)
    f01 = (rng.standard_normal((40, 50, 2)) * 3).astype(np.float32)
    f10 = (-f01 + rng.standard_normal((40, 50, 2)).astype(np.float32) * 0.5).astype(np.float32)
    f01[0, 0] = [1e-20, -1e18]
    assert np.array_equal(ip._sq_norm(f01), (f01 * f01).sum(-1))
    grid = ip._grid(40, 50)
    back = ip._remap(f10, ip._warp_map(grid, f01))
    d = f01 + back
    ref = ((d * d).sum(-1) > ip._FB_ALPHA1 * ((f01 * f01).sum(-1) + (back * back).sum(-1))
           + ip._FB_ALPHA2).astype(np.float32)
    occ = ip._occluded(f01, f10, grid)
    assert np.array_equal(occ, ref) and 0 < occ.sum() < occ.size


@pytest.mark.parametrize("preset,finest", [("medium", None), ("fast", None), ("medium", 2)])
def test_reused_dis_equals_a_fresh_one(texture, preset, finest):
    """The cached DIS instance gives a fresh instance's flow bit for bit, also on frames so
    small that DIS rewrites its own parameters inside calc (36 x 40) and after them."""
    from rdnet.sim.interpolate import _DIS_PRESETS, _dis
    ok = []
    for h, w in [(36, 40), (96, 120), (36, 40), (64, 64)]:
        a = (texture[:h, :w] * 255).astype(np.uint8)
        b = (texture[1:h + 1, 2:w + 2] * 255).astype(np.uint8)
        fresh = cv2.DISOpticalFlow_create(_DIS_PRESETS[preset])
        if finest is not None:
            fresh.setFinestScale(finest)
        ok.append(np.array_equal(_dis(preset, finest).calc(a, b, None), fresh.calc(a, b, None)))
    assert all(ok)


def test_flow_too_small_is_a_clear_error_and_upsample_blends(caplog):
    from rdnet.sim.interpolate import MIN_FLOW_SIDE, PairInterpolator
    f0 = np.full((4, 5), 0.2, np.float32)
    f1 = np.full((4, 5), 0.4, np.float32)
    with pytest.raises(ValidationError, match=f">= {MIN_FLOW_SIDE} px"):
        PairInterpolator(f0, f1, InterpolateConfig(method="flow")).frame(0.5)
    ims, ts = upsample_all(np.stack([f0, f1]), np.array([0, 1000]), InterpolateConfig(method="flow", max_upsample=4))
    assert "too small for the optical flow" in caplog.text
    lin, _ = upsample_all(np.stack([f0, f1]), np.array([0, 1000]), InterpolateConfig(method="linear", max_upsample=4))
    np.testing.assert_array_equal(ims, lin)
    assert ims.shape[0] > 2


@pytest.mark.parametrize("color", [False, True])
def test_stats_without_inserted_frames_are_the_pair_steps(texture, color):
    """max_upsample 1 (nothing inserted): the per-pair stats use the log of the last pair's
    second frame; they equal the criterion measured on each pair."""
    from rdnet.sim.interpolate import criterion, step_sizes
    frames = _translated(texture, [(0.7 * k, 0.3 * k) for k in range(6)])
    if color:
        frames = np.stack([frames, frames * 0.8, frames * 0.6], axis=-1)
    t = np.arange(6, dtype=np.int64) * 1000
    cfg = InterpolateConfig(max_upsample=1, pixel_quantile=0.99)
    st = UpsampleStats()
    ims, ts = upsample_all(frames, t, cfg, stats=st, warn=False)
    np.testing.assert_array_equal(ims, frames)
    steps = [step_sizes(frames[i:i + 2], 0.01, color=color) for i in range(5)]
    crits = [criterion(s, 0.99) for s in steps]
    assert st.pairs == 5 and st.inserted == 0 and st.per_pair == [0] * 5
    assert st.max_log_step == pytest.approx(max(crits), rel=1e-6)
    assert st.violations == sum(c > cfg.max_log_step for c in crits)
    # the batched path gives exactly numpy's quantile and the exact per-step counts
    assert st.max_log_step == max(float(np.quantile(s[0], 0.99)) for s in steps)
    assert st.strict_max_log_step == max(float(s.max()) for s in steps)
    assert st.pixel_steps_over == sum(int(np.count_nonzero(s > cfg.max_log_step)) for s in steps)
    assert len(list(upsample(frames, t, cfg, warn=False))) == 1   # nothing inserted: one chunk


def test_quantile_exact_is_numpys_quantile_bit_for_bit():
    from rdnet.sim.interpolate import quantile_exact
    rng = np.random.default_rng(3)
    cases = [rng.random(50_000, dtype=np.float32),
             (np.abs(rng.standard_normal(89_960)) * 0.05).astype(np.float32),
             np.round(rng.random(20_000) * 8).astype(np.float32) / 8,       # many ties
             np.sort(rng.exponential(size=30_001)).astype(np.float32)[::-1].copy(),  # sorted, descending
             np.full(5_000, 0.25, np.float32),
             rng.random(100, dtype=np.float32)]                           # small: np.quantile itself
    withnan = rng.random(40_000, dtype=np.float32)
    withnan[7] = np.nan
    cases.append(withnan)
    for v in cases:
        before = v.copy()
        for q in (0.5, 0.9, 0.99, 0.999, 0.987654, 1.0):
            want, got = np.quantile(v, q), quantile_exact(v, q)
            assert np.asarray(got).tobytes() == np.asarray(want).tobytes(), (v.size, q, got, want)
        np.testing.assert_array_equal(v, before)   # input untouched


@pytest.mark.parametrize("flow", ["dis", "farneback"])
def test_pair_flows_in_two_threads_equal_the_sequential_flows(texture, flow, monkeypatch):
    """The backward flow of a pair runs in a pool thread (its own DIS instance) while the
    caller computes the forward one: the same flows bit for bit."""
    import threading

    import rdnet.sim.interpolate as itp
    a, b = _translated(texture, [(0.0, 0.0), (5.0, 1.5)])
    cfg = InterpolateConfig(method="flow", flow=flow)
    names = []
    real = itp._flow_of_u8

    def recorded(ua, ub, c):
        names.append(threading.current_thread().name)
        return real(ua, ub, c)

    monkeypatch.setattr(itp, "_flow_of_u8", recorded)
    f01, f10 = itp.PairInterpolator(a, b, cfg)._prepare()[:2]
    assert len(names) == 2 and threading.current_thread().name in names
    assert any(n.startswith("rdnet-flow") for n in names)
    ua, ub = itp._flow_u8(a), itp._flow_u8(b)
    assert np.array_equal(f01, real(ua, ub, cfg)) and np.array_equal(f10, real(ub, ua, cfg))
    assert not np.array_equal(f01, -f10)   # two different flows were computed
