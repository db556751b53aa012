"""How 'flow' and 'selected' resample their warped frames (``interpolate.warp``), and the
calibration's own setting of it (``calibrate.warp``)."""
import dataclasses

import cv2
import numpy as np
import pytest

from rdnet.calib.calibrate import calibration_interpolation, interpolation_configs
from rdnet.calib.settings import CalibrateConfig
from rdnet.config import from_dict
from rdnet.errors import ConfigError
from rdnet.sim.interpolate import (InterpolateConfig, PairFlowCache, PairInterpolator, _grid, _remap, _warp_map,
                                   interpolate_pair)

INNER = (slice(8, -8), slice(8, -8))


def _periodic_texture(n=64, sigma_px=1.0, seed=0) -> np.ndarray:
    """Band-limited periodic noise in [0.1, 0.9] (a Gaussian low-pass of white noise)."""
    rng = np.random.default_rng(seed)
    k = np.fft.fftfreq(n)
    kk = k[:, None] ** 2 + k[None, :] ** 2
    img = np.real(np.fft.ifft2(np.fft.fft2(rng.random((n, n))) * np.exp(-2 * (np.pi * sigma_px) ** 2 * kk)))
    return ((img - img.min()) / (img.max() - img.min()) * 0.8 + 0.1).astype(np.float32)


def _shifted(img: np.ndarray, dx: float) -> np.ndarray:
    """``img`` translated right by ``dx`` px, exactly (a phase ramp: the truth at any sub-pixel shift)."""
    k = np.fft.fftfreq(img.shape[1])
    return np.real(np.fft.ifft2(np.fft.fft2(img) * np.exp(-2j * np.pi * k[None, :] * dx))).astype(np.float32)


def test_bicubic_warp_keeps_the_contrast_a_bilinear_warp_loses():
    """A texture moving 1 px per frame, the frame half-way: a bilinear warp by half a pixel
    averages neighbours (a low-pass), so the texture's contrast dips mid-interval and
    comes back at the next frame; bicubic keeps it within 2 % of the exact frame."""
    tex = _periodic_texture()
    f0, f1, truth = _shifted(tex, 0.0), _shifted(tex, 1.0), _shifted(tex, 0.5)
    mid = {w: interpolate_pair(f0, f1, 1, InterpolateConfig(method="flow", warp=w))[0] for w in ("bilinear", "bicubic")}
    err = {w: float(np.sqrt(np.mean((m[INNER] - truth[INNER]) ** 2))) for w, m in mid.items()}
    std = {w: float(m[INNER].std()) for w, m in mid.items()}
    s = float(truth[INNER].std())
    assert std["bilinear"] < 0.96 * s                      # measured 0.936 x
    assert abs(std["bicubic"] / s - 1) < 0.02              # measured 1.010 x
    assert err["bicubic"] < 0.5 * err["bilinear"], err     # measured 0.0040 against 0.0142


def test_the_clamped_bicubic_warp_keeps_the_contrast_too():
    """The same half-way frame with 'bicubic_clamped': on a smooth texture the clamp rarely
    acts, so the contrast stays within 1 % of the exact frame and the error near bicubic's."""
    tex = _periodic_texture()
    f0, f1, truth = _shifted(tex, 0.0), _shifted(tex, 1.0), _shifted(tex, 0.5)
    mid = interpolate_pair(f0, f1, 1, InterpolateConfig(method="flow", warp="bicubic_clamped"))[0]
    assert abs(float(mid[INNER].std()) / float(truth[INNER].std()) - 1) < 0.01          # measured 1.001 x
    assert float(np.sqrt(np.mean((mid[INNER] - truth[INNER]) ** 2))) < 0.006            # measured 0.0048


def test_the_clamp_removes_the_bicubic_overshoot_at_a_sharp_edge():
    """A 90:1 step warped by 0.4 px: bicubic rings (below the dark side, even below zero, and
    above the bright side); clamped to the 2 x 2 source pixels, every sample lies inside the
    range of the pixels bilinear reads, and the edge pixel keeps bicubic's value."""
    img = np.repeat(np.where(np.arange(32)[None, :] < 16, 0.9, 0.01).astype(np.float32), 8, axis=0)
    flow = np.zeros(img.shape + (2,), np.float32)
    flow[..., 0] = 0.4
    m = _warp_map(_grid(*img.shape), flow)
    ringing = _remap(img, m, cv2.INTER_CUBIC)
    clamped = _remap(img, m, cv2.INTER_CUBIC, clamp=True)
    assert ringing.min() < 0.0 and ringing.max() > 0.95                     # measured -0.086, 0.964
    assert clamped.min() == pytest.approx(0.01) and clamped.max() == pytest.approx(0.9)
    np.testing.assert_array_equal(clamped[:, 15], ringing[:, 15])          # inside its block's range
    np.testing.assert_array_equal(clamped[:, 14], img[:, 14])              # the overshoot, clipped to 0.9
    assert np.array_equal(_remap(img, m, cv2.INTER_LINEAR, clamp=True), _remap(img, m))


@pytest.mark.parametrize("interpolation", [cv2.INTER_LINEAR, cv2.INTER_CUBIC])
@pytest.mark.parametrize("shape", [(37, 53), (21, 30, 3)])
def test_the_two_channel_warp_map_samples_as_separate_x_and_y_maps(interpolation, shape):
    """``_remap`` hands OpenCV one (H, W, 2) map (``_warp_map``: grid + flow in one add); its
    output equals the warp by separate x and y maps, each coordinate added on its own, bit for
    bit, on a random flow that reaches past the borders."""
    rng = np.random.default_rng(11)
    img = rng.random(shape, dtype=np.float32)
    flow = (rng.standard_normal(shape[:2] + (2,)) * 4).astype(np.float32)
    grid = _grid(*shape[:2])
    assert grid.shape == shape[:2] + (2,) and grid[3, 5].tolist() == [5.0, 3.0]
    m = _warp_map(grid, flow)
    gx, gy = np.ascontiguousarray(grid[..., 0]), np.ascontiguousarray(grid[..., 1])
    ref = cv2.remap(img, gx + flow[..., 0], gy + flow[..., 1], interpolation, borderMode=cv2.BORDER_REPLICATE)
    out = _remap(img, m, interpolation)
    assert out.shape == img.shape and np.array_equal(out, ref)


@pytest.mark.parametrize("shape", [(9, 13), (7, 11, 3)])
def test_the_clamp_bounds_are_each_samples_own_2x2_source_pixels(shape):
    """The clamp's per-pair bounds (``_block_bounds``, looked up at each sample) equal the
    min / max of the four pixels around the sample, read directly with the border
    replicated, also for samples far outside the frame; given or computed per call alike."""
    from rdnet.sim.interpolate import _block_bounds
    rng = np.random.default_rng(3)
    img = (rng.random(shape) ** 3).astype(np.float32)
    h, w = shape[:2]
    grid = _grid(h, w)
    gx, gy = grid[..., 0], grid[..., 1]
    flow = (rng.standard_normal((h, w, 2)) * np.array([4.0, 3.0]) * rng.choice([0.1, 1, 5], (h, w, 1))
            ).astype(np.float32)
    flow[0, 0] = (-40.5, -30.25)                         # far beyond the top-left corner
    flow[-1, -1] = (40.5, 30.25)                         # and the bottom-right one
    mx, my = gx + flow[..., 0], gy + flow[..., 1]
    x0, y0 = np.floor(mx).astype(int), np.floor(my).astype(int)
    corners = [img[np.clip(y0 + dy, 0, h - 1), np.clip(x0 + dx, 0, w - 1)] for dy in (0, 1) for dx in (0, 1)]
    want = np.clip(cv2.remap(img, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE),
                   np.min(corners, axis=0), np.max(corners, axis=0))
    m = _warp_map(grid, flow)
    got = _remap(img, m, cv2.INTER_CUBIC, clamp=True)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(_remap(img, m, cv2.INTER_CUBIC, True, _block_bounds(img)), want)
    assert not np.array_equal(got, _remap(img, m, cv2.INTER_CUBIC))   # the clamp acted


def test_warp_settings_are_validated():
    assert InterpolateConfig().warp == "bilinear" and CalibrateConfig().warp == "bicubic"
    assert InterpolateConfig(warp="bicubic_clamped").warp == CalibrateConfig(warp="bicubic_clamped").warp
    with pytest.raises(ConfigError, match="interpolate.warp"):
        from_dict(InterpolateConfig, {"warp": "lanczos"}, "interpolate")
    with pytest.raises(ConfigError, match="calibrate.warp"):
        CalibrateConfig(warp="nearest")
    assert CalibrateConfig(warp=None).warp is None


def test_the_calibration_runs_its_interpolations_with_calibrate_warp():
    given = InterpolateConfig(method="flow", max_upsample=8, dis_preset="fast")
    cfg = CalibrateConfig(interpolation=("flow", "linear"))
    out = interpolation_configs(cfg, given)
    assert [c.method for c in out] == ["flow", "linear"]
    assert all(c.warp == "bicubic" and c.dis_preset == "fast" and c.max_upsample == 8 for c in out)
    # null: the interpolate section's warp
    assert interpolation_configs(dataclasses.replace(cfg, warp=None), given)[0].warp == "bilinear"
    # no candidates: the given config, with the calibration's warp; None stays None without one
    assert interpolation_configs(dataclasses.replace(cfg, interpolation=()), given) == \
        [dataclasses.replace(given, warp="bicubic")]
    assert interpolation_configs(CalibrateConfig(interpolation=(), warp=None), None) == [None]
    # the proof's scenes: the defaults with the calibration's cap and warp
    assert calibration_interpolation(CalibrateConfig(max_upsample=12)) == \
        InterpolateConfig(max_upsample=12, warp="bicubic")
    assert calibration_interpolation(cfg, "selected").method == "selected"


def test_a_shared_pair_cache_keeps_the_frames_of_two_warps_apart():
    tex = _periodic_texture(48, seed=1)
    f0, f1 = _shifted(tex, 0.0), _shifted(tex, 1.5)
    cache = PairFlowCache(users=2)
    shared = {w: PairInterpolator(f0, f1, InterpolateConfig(warp=w), None, cache, 0).frame(0.5)
              for w in ("bilinear", "bicubic", "bicubic_clamped")}
    for w, frame in shared.items():
        np.testing.assert_array_equal(frame, PairInterpolator(f0, f1, InterpolateConfig(warp=w)).frame(0.5))
    assert not np.array_equal(shared["bilinear"], shared["bicubic"])
    assert not np.array_equal(shared["bicubic"], shared["bicubic_clamped"])
