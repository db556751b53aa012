"""Image and restoration metrics: known values."""
import math

import numpy as np
import pytest
import torch

from rdnet.eval.metrics import (by_level, dominant_degradation, evaluate_images, group_means,
                                psnr_ssim, restoration_metrics, to_uint8)


def test_identical_images_have_infinite_psnr_and_unit_ssim():
    rng = np.random.default_rng(0)
    a = rng.random((2, 1, 16, 16)).astype(np.float32)
    m = evaluate_images(a, a.copy())
    assert m["psnr"] == math.inf and m["ssim"] == pytest.approx(1.0) and m["n"] == 2


def test_known_mse_gives_known_psnr_on_the_8bit_scale():
    target = np.zeros((1, 1, 16, 16), np.float32)
    pred = np.full_like(target, 10 / 255)                  # every pixel off by 10 levels
    assert evaluate_images(pred, target)["psnr"] == pytest.approx(10 * math.log10(255 ** 2 / 100))
    # clipping to [0, 1] and rounding to 8 bits happen before the comparison
    assert psnr_ssim(np.full((1, 12, 12), 1.7), np.ones((1, 12, 12)))[0] == math.inf
    assert psnr_ssim(np.full((1, 12, 12), 0.4 / 255), np.zeros((1, 12, 12)))[0] == math.inf
    assert np.array_equal(to_uint8(np.array([-0.2, 0.5 / 255, 1.5 / 255, 2.0])), [0, 0, 2, 255])
    # torch tensors are accepted
    assert evaluate_images(torch.from_numpy(pred), torch.from_numpy(target))["psnr"] == pytest.approx(28.1308, abs=1e-4)


def test_colour_uses_all_channels():
    rng = np.random.default_rng(1)
    grey_t = rng.random((1, 1, 24, 24))
    grey_p = np.clip(grey_t + rng.normal(0, 0.05, grey_t.shape), 0, 1)
    g = evaluate_images(grey_p, grey_t)
    c = evaluate_images(np.repeat(grey_p, 3, 1), np.repeat(grey_t, 3, 1))
    assert c["psnr"] == pytest.approx(g["psnr"]) and c["ssim"] == pytest.approx(g["ssim"])
    # one channel off by 30 levels: MSE = 900 / 3
    t = np.zeros((1, 3, 16, 16))
    p = t.copy()
    p[:, 0] = 30 / 255
    assert evaluate_images(p, t)["psnr"] == pytest.approx(10 * math.log10(255 ** 2 / 300))
    with pytest.raises(ValueError, match="shape"):
        evaluate_images(p[:, :2], t)
    with pytest.raises(ValueError, match="at least 11x11"):
        evaluate_images(p[..., :10], t[..., :10])


def test_ssim_orders_degradations():
    rng = np.random.default_rng(2)
    t = rng.random((1, 1, 32, 32))
    small = np.clip(t + rng.normal(0, 0.02, t.shape), 0, 1)
    large = np.clip(t + rng.normal(0, 0.2, t.shape), 0, 1)
    assert evaluate_images(small, t)["ssim"] > evaluate_images(large, t)["ssim"]


def test_restoration_metrics_known_values():
    u = np.zeros((1, 2, 4, 4), np.float32)
    d = np.zeros_like(u)
    u[0, 0, 1, 1] = 2.0          # a true event
    d[0, 1, 2, 2] = 1.0          # a noise event
    r = u.copy()
    r[0, 0, 1, 1] += 1.0         # error 1 at both response locations
    r[0, 1, 2, 2] = 1.0
    r[0, 1, 3, 3] = 4.0          # error outside the response locations
    m = restoration_metrics(r, u, d)
    assert m["voxel_l1"] == pytest.approx(1.0)
    assert m["voxel_psnr"] == pytest.approx(10 * math.log10(2.0 ** 2 / 1.0))   # peak = max|E_u|
    assert m["voxel_l1_all"] == pytest.approx(6.0 / 32)
    assert m["mask_fraction"] == pytest.approx(2 / 32) and m["n"] == 1
    exact = restoration_metrics(u, u, d)
    assert exact["voxel_l1"] == 0 and exact["voxel_psnr"] == math.inf


def test_by_level_and_group_means():
    vals = {"psnr": [10.0, 20.0, 30.0, 40.0]}
    rows = by_level(vals, [0.0, 0.1, 0.5, 1.0], bins=2)
    assert [(r["level_lo"], r["level_hi"], r["n"], r["psnr"]) for r in rows] == \
        [(0.0, 0.5, 2, 15.0), (0.5, 1.0, 2, 35.0)]
    assert rows[0]["level_bin"] == 0.25
    one = by_level(vals, [0.3] * 4, bins=5)
    assert len(one) == 1 and one[0]["n"] == 4 and one[0]["psnr"] == 25.0
    g = group_means(vals, ["b", "a", "b", "a"])
    assert g == [{"group": "a", "n": 2, "psnr": 30.0}, {"group": "b", "n": 2, "psnr": 20.0}]


def test_dominant_degradation_uses_relative_strength():
    deg = {"refractory_us": [0.0, 100.0, 1000.0, 0.0],
           "shot_noise_hz": [0.0, 2.0, 0.5, 0.0],
           "onoff_ratio": [1.0, 1.0, 1.0, 2.0]}
    assert dominant_degradation(deg).tolist() == ["none", "shot_noise_hz", "refractory_us", "onoff_ratio"]


def test_dominant_degradation_ignores_columns_that_do_not_vary():
    # a shape key held at one value (alphabetically first, so it would win every tie at 1.0)
    deg = {"a_shape": [0.5, 0.5, 0.5, 0.5],
           "refractory_us": [0.0, 100.0, 1000.0, 0.0],
           "shot_noise_hz": [0.0, 2.0, 0.5, 0.0]}
    assert dominant_degradation(deg).tolist() == ["none", "shot_noise_hz", "refractory_us", "none"]
    assert dominant_degradation({"only": [3.0]}).tolist() == ["only"]       # one sample: nothing to compare


def test_samples_without_motion_are_left_out_of_the_image_means():
    from rdnet.eval.metrics import has_motion, image_means, motion_only
    rng = np.random.default_rng(3)
    sharp = rng.integers(0, 250, (3, 1, 12, 12)) / 255     # exact grey levels
    blurry = sharp.copy()
    blurry[0] += 2 / 255                                  # moves by 2 grey levels
    blurry[1, 0, 5, 5] += 1.0 / 255 + 1e-3                # one pixel moves by a grey level
    blurry[2] += 0.1 / 255                                # below 8 bits: no motion
    moving = has_motion(blurry, sharp)
    assert moving.tolist() == [True, True, False]
    per = {"psnr": np.array([30.0, 50.0, math.inf]), "ssim": np.array([0.9, 0.99, 1.0]),
           "voxel_l1": np.array([1.0, 2.0, 3.0])}
    m = image_means(per, moving)
    assert m == {"n_images": 2, "still_excluded": 1, "psnr": 40.0, "ssim": pytest.approx(0.945)}
    g = group_means(motion_only(per, moving), np.array([0, 1, 1]))
    assert g[1]["psnr"] == 50.0 and g[1]["voxel_l1"] == 2.5 and g[1]["n"] == 2
    assert group_means(motion_only(per, moving), np.array([0, 0, 1]))[1]["psnr"] is None
    assert image_means(per, [False] * 3)["psnr"] is None
    with pytest.raises(ValueError):
        has_motion(blurry[:, 0], sharp[:, 0])
