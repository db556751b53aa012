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


@pytest.mark.parametrize("method", ["flow", "linear"])
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
        from_dict(InterpolateConfig, {"method": "cubic"}, "interpolate")
    with pytest.raises(ConfigError, match="interpolate.bogus"):
        from_dict(InterpolateConfig, {"bogus": 1}, "interpolate")
    with pytest.raises(ConfigError, match="interpolate.max_upsample"):
        InterpolateConfig(max_upsample=0)
    ims = np.zeros((2, 8, 8), np.float32)
    with pytest.raises(ValidationError):
        upsample_all(ims, np.array([5, 5]))
    with pytest.raises(ValidationError):
        upsample_all(ims, np.array([0.0, 1.5]))
