"""Method 'selected' of rdnet.sim.interpolate: flow where the sequence's own frames say it
predicts better than a cross-fade, linear elsewhere (flow_weight)."""
import dataclasses

import cv2
import numpy as np
import pytest

from rdnet.errors import ConfigError, ValidationError
from rdnet.sim.interpolate import InterpolateConfig, PairInterpolator, flow_weight, select_centres, upsample_all
from rdnet.sim.scenes import procedural_texture


@pytest.fixture(scope="module")
def texture():
    tex = procedural_texture("noise", 128, 160, np.random.default_rng(3))[..., 1]
    return np.ascontiguousarray(cv2.GaussianBlur(tex, (0, 0), 1.5)) * 0.8 + 0.1


def _moving(tex, n, step_px, h=64, w=64, margin=24):
    out = []
    for i in range(n):
        m = np.float32([[1, 0, margin + step_px * i], [0, 1, margin]])
        out.append(cv2.warpAffine(tex, m, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP))
    return np.stack(out).astype(np.float32)


def test_weights_pure_flow_and_pure_spline_frames(texture):
    """Weight 1: the flow frame; weight 0: the log-intensity spline of method 'cubic' through
    the same four frames (the linear cross-fade before session 34)."""
    f = _moving(texture, 4, 3.0)
    for w, method in ((1.0, "flow"), (0.0, "cubic")):
        sel = PairInterpolator(f[1], f[2], InterpolateConfig(method="selected"), np.full(f[1].shape, w, np.float32),
                               before=f[0], after=f[3])
        ref = PairInterpolator(f[1], f[2], InterpolateConfig(method=method), before=f[0], after=f[3])
        for t in (0.25, 0.5):
            np.testing.assert_array_equal(sel.frame(t), ref.frame(t))
    f0, f1 = f[:2]
    # no weight given: flow everywhere
    np.testing.assert_array_equal(PairInterpolator(f0, f1, InterpolateConfig(method="selected")).frame(0.3),
                                  PairInterpolator(f0, f1, InterpolateConfig(method="flow")).frame(0.3))


def test_translation_chooses_flow_and_a_brightness_ramp_chooses_the_spline(texture):
    moving = _moving(texture, 6, 3.0)
    t = np.arange(6, dtype=np.int64) * 10_000
    w = flow_weight(moving, t, InterpolateConfig(method="selected"))
    assert w.shape == moving.shape[1:] and w.dtype == np.float32
    assert 0.0 <= w.min() and w.max() <= 1.0
    assert w[8:-8, 8:-8].mean() > 0.9               # the texture moves: flow predicts it
    # a still scene whose log brightness ramps linearly: the spline ('cubic', what 'selected'
    # uses where flow does not win) is exact, flow (a cross-fade where nothing moves) is not
    # (16 frames: the spline's knots run out at the ends, where it is not exact)
    gain = np.exp(np.linspace(np.log(0.2), 0.0, 16)).astype(np.float32)
    still = moving[0][None] * gain[:, None, None]
    t16 = np.arange(16, dtype=np.int64) * 10_000
    assert flow_weight(still, t16, InterpolateConfig(method="selected", log_eps=0.01)).max() < 0.5
    # fewer than 3 frames: nothing to compare, flow everywhere
    np.testing.assert_array_equal(flow_weight(moving[:2], t[:2], InterpolateConfig()), np.ones((64, 64), np.float32))


def test_a_still_shadow_edge_stays_put_while_the_texture_moves():
    """The proof's scene B (a texture drifting under a still illumination edge), rendered at
    100 and 400 fps: upsampled from 100 fps, 'selected' is closer to the 400 fps frames than
    linear (which fades the texture) and than flow (which drags the edge)."""
    from rdnet.calib.proof import SCENE_B
    from rdnet.calib.scene import SceneSpec, render
    spec = dataclasses.replace(SceneSpec(), duration_us=200_000, **dict(SCENE_B))
    rng = np.random.default_rng(0)
    coarse, tex = render(spec, rng)
    fine, _ = render(spec, rng, fps_hz=spec.fps_hz * 4, texture=tex)
    err = {}
    for method in ("linear", "flow", "selected"):
        im, t = upsample_all(coarse.images, coarse.t_us, InterpolateConfig(method=method), 0.01, warn=False)
        common, i_up, i_fine = np.intersect1d(t, fine.t_us, return_indices=True)
        between = np.isin(common, coarse.t_us, invert=True)
        assert between.sum() > 5
        d = np.log(im[i_up][between] + 0.01) - np.log(fine.images[i_fine][between] + 0.01)
        err[method] = float(np.sqrt(np.mean(d ** 2)))
    assert err["selected"] < 0.8 * err["linear"], err
    assert err["selected"] < 0.5 * err["flow"], err


def test_select_centres_known_values():
    np.testing.assert_array_equal(select_centres(2, 16), [])                  # no inner frame
    np.testing.assert_array_equal(select_centres(10, 0), np.arange(1, 9))     # 0: every inner frame
    np.testing.assert_array_equal(select_centres(10, 8), np.arange(1, 9))     # as many as there are
    np.testing.assert_array_equal(select_centres(10, 50), np.arange(1, 9))
    np.testing.assert_array_equal(select_centres(10, 3), [1, 4, 8])           # linspace(1, 8, 3), rounded
    np.testing.assert_array_equal(select_centres(10, 1), [1])
    c = select_centres(59, 16)                                                # DAVIS346 road: 59 frames
    assert len(c) == 16 and c[0] == 1 and c[-1] == 57 and np.all(np.diff(c) >= 3)


def test_select_frames_predicts_only_the_chosen_frames(texture, monkeypatch):
    """``select_frames`` bounds the work (two flows per predicted frame) and, on a uniform
    translation, makes the same choice as every frame; at least the inner frames' number is
    every frame, bit for bit."""
    import rdnet.sim.interpolate as ip
    moving = _moving(texture, 12, 2.0)
    t = np.arange(12, dtype=np.int64) * 10_000
    calls = []
    real = ip._flow_of_u8
    monkeypatch.setattr(ip, "_flow_of_u8", lambda a, b, cfg: calls.append(1) or real(a, b, cfg))
    every = flow_weight(moving, t, InterpolateConfig(method="selected", select_frames=0))
    assert len(calls) == 2 * 10
    calls.clear()
    three = flow_weight(moving, t, InterpolateConfig(method="selected", select_frames=3))
    assert len(calls) == 2 * 3
    np.testing.assert_array_equal(flow_weight(moving, t, InterpolateConfig(method="selected", select_frames=10)), every)
    assert every[8:-8, 8:-8].mean() > 0.9 and three[8:-8, 8:-8].mean() > 0.9


def test_sampled_grid_equals_the_full_frame_sampled(texture):
    frames = _moving(texture, 4, 2.5)
    t = np.arange(4, dtype=np.int64) * 10_000
    cfg = InterpolateConfig(method="selected")
    w = flow_weight(frames, t, cfg)
    w[:, :20] = 0.3                                  # a weight that is neither 0 nor 1 somewhere
    pi = PairInterpolator(frames[1], frames[2], cfg, w)
    full = pi.frame(0.4)
    with pi.on_grid(3):
        sampled = pi.frame(0.4)
    np.testing.assert_allclose(sampled, full[::3, ::3], rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(pi.frame(0.4), full)          # restored on leaving


def test_calibration_context_upsamples_selected_on_its_pixel_sample(texture):
    from rdnet.calib.context import upsample_sampled
    frames = _moving(texture, 5, 2.0)
    t = np.arange(5, dtype=np.int64) * 10_000
    cfg = InterpolateConfig(method="selected", max_upsample=4)
    full, tf = upsample_sampled(frames, t, cfg, 0.01, 1)
    sub, ts = upsample_sampled(frames, t, dataclasses.replace(cfg, verify=False), 0.01, 2)
    assert full.shape[1:] == (64, 64) and sub.shape[1:] == (32, 32)
    unverified, tu = upsample_sampled(frames, t, dataclasses.replace(cfg, verify=False), 0.01, 1)
    np.testing.assert_array_equal(ts, tu)
    np.testing.assert_allclose(sub, unverified[:, ::2, ::2], rtol=1e-6, atol=1e-7)


def test_bad_settings_and_weight_shape():
    with pytest.raises(ConfigError, match="select_sigma_px"):
        InterpolateConfig(method="selected", select_sigma_px=0)
    with pytest.raises(ConfigError, match="interpolate.method"):
        InterpolateConfig(method="chosen")
    for bad in (-1, 2.5, True, "16"):
        with pytest.raises(ConfigError, match="interpolate.select_frames"):
            InterpolateConfig(method="selected", select_frames=bad)
    f = np.zeros((16, 16), np.float32)
    with pytest.raises(ValidationError, match="flow_weight"):
        PairInterpolator(f, f, InterpolateConfig(method="selected"), np.ones((8, 8), np.float32))
    from rdnet.calib.settings import CalibrateConfig
    assert CalibrateConfig(interpolation=("selected", "linear")).interpolation == ("selected", "linear")
    with pytest.raises(ConfigError, match="calibrate.interpolation"):
        CalibrateConfig(interpolation=("warp",))


def test_pair_flow_cache_computes_each_pair_once_across_threads(texture, monkeypatch):
    """flow and selected share a pair's flows (rdnet.calib builds both contexts in threads):
    each pair is computed once, and each interpolator gets exactly its own flows."""
    from concurrent.futures import ThreadPoolExecutor

    import rdnet.sim.interpolate as ip
    frames = _moving(texture, 4, 2.0)
    calls = []
    plain = ip._flows_both_ways
    monkeypatch.setattr(ip, "_flows_both_ways", lambda *a: calls.append(1) or plain(*a))
    cache = ip.PairFlowCache(users=2)

    def frames_of(method):
        out = []
        for i in range(3):
            pi = PairInterpolator(frames[i], frames[i + 1], InterpolateConfig(method=method))
            cache.share(i, pi)
            out.append(pi.frame(0.5))
        return out

    with ThreadPoolExecutor(2) as pool:
        shared = list(pool.map(frames_of, ["flow", "selected"]))
    assert len(calls) == 3 and not cache._pending          # once per pair, nothing kept after
    own = [PairInterpolator(frames[i], frames[i + 1], InterpolateConfig(method="flow")).frame(0.5) for i in range(3)]
    for a, b, c in zip(shared[0], shared[1], own):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)                 # no weight: selected is flow


def test_pair_flow_cache_warps_each_frame_once_for_flow_and_selected(texture, monkeypatch):
    """'selected' blends the very flow frame 'flow' uses: with a shared cache each frame
    (pair, grid, time) is warped once across both, the frames equal those warped alone, and
    no frame both asked for is kept."""
    from concurrent.futures import ThreadPoolExecutor

    import rdnet.sim.interpolate as ip
    frames = _moving(texture, 4, 2.0)
    weight = np.full(frames.shape[1:3], 0.5, np.float32)
    warps = []
    plain = ip.PairInterpolator._warped
    monkeypatch.setattr(ip.PairInterpolator, "_warped", lambda self, t: warps.append(1) or plain(self, t))
    cache = ip.PairFlowCache(users=2)

    def frames_of(method):
        out = []
        for i in range(3):
            pi = PairInterpolator(frames[i], frames[i + 1], InterpolateConfig(method=method), weight, cache, i)
            with pi.on_grid(2):
                out.append([pi.frame(t) for t in (0.25, 0.5)])
        return out

    with ThreadPoolExecutor(2) as pool:
        shared = dict(zip(["flow", "selected"], pool.map(frames_of, ["flow", "selected"])))
    assert len(warps) == 3 * 2 and not cache._frames            # 2 times x 3 pairs, once each
    warps.clear()
    for method in ("flow", "selected"):
        for i in range(3):
            pi = PairInterpolator(frames[i], frames[i + 1], InterpolateConfig(method=method), weight)
            with pi.on_grid(2):
                for a, t in zip(shared[method][i], (0.25, 0.5)):
                    np.testing.assert_array_equal(a, pi.frame(t))
    assert len(warps) == 2 * 3 * 2                               # alone: every call warps
    assert not np.array_equal(shared["flow"][0][0], shared["selected"][0][0])   # weight 0.5: a blend
