"""Embedded scene renderer (rdnet.sim.scenes)."""
import dataclasses

import numpy as np
import pytest

from rdnet.config import from_dict
from rdnet.errors import ConfigError
from rdnet.sim.scenes import (TEST_IMAGES, TEXTURES, TRAIN_IMAGES, SceneSpec, ScenesConfig, load_image,
                              make_specs, procedural_texture, render_sequence, render_split,
                              still_cameras)

SMALL = ScenesConfig(n_train=3, n_test=2, height=32, width=40, n_frames=12, n_objects=2, seed=7)


def test_train_test_images_disjoint_and_available():
    assert not set(TRAIN_IMAGES) & set(TEST_IMAGES)
    for name in TRAIN_IMAGES + TEST_IMAGES:       # all ship with scikit-image (no download)
        im = load_image(name)
        assert im.ndim == 3 and im.shape[2] == 3 and im.dtype == np.float32
        assert 0 <= im.min() and im.max() <= 1 and im.std() > 0.01


def test_specs_use_split_images_only():
    cfg = dataclasses.replace(SMALL, n_train=20, n_test=20, texture_fraction=0.2)
    for split, allowed in (("train", TRAIN_IMAGES), ("test", TEST_IMAGES)):
        specs = make_specs(cfg, split)
        used = [s.background for s in specs] + [o["texture"] for s in specs for o in s.objects]
        for u in used:
            assert u in allowed or u.split(":", 1)[1] in TEXTURES, u
        assert any(u in allowed for u in used)


def test_deterministic_per_seed_and_spec_round_trip():
    a = list(render_split(SMALL, "train"))
    b = list(render_split(SMALL, "train"))
    assert len(a) == 3
    for (sa, fa), (sb, fb) in zip(a, b):
        assert sa == sb
        np.testing.assert_array_equal(fa.images, fb.images)
    spec = SceneSpec.from_json(a[0][0].to_json())
    assert spec == a[0][0]
    np.testing.assert_array_equal(render_sequence(spec).images, a[0][1].images)
    other = list(render_split(dataclasses.replace(SMALL, seed=8), "train"))
    assert not np.array_equal(other[0][1].images, a[0][1].images)


@pytest.mark.parametrize("color", [False, True])
def test_shapes_ranges_timestamps_motion(color):
    cfg = dataclasses.replace(SMALL, color=color, fps_hz=480.0)
    for spec, fr in render_split(cfg, "test"):
        shape = (12, 32, 40, 3) if color else (12, 32, 40)
        assert fr.images.shape == shape and fr.images.dtype == np.float32
        assert fr.images.min() >= 0 and fr.images.max() <= 1
        np.testing.assert_array_equal(fr.t_us, np.rint(np.arange(12) * 1e6 / 480).astype(np.int64))
        assert np.all(fr.exposure_us == 0)
        diffs = np.abs(np.diff(fr.images, axis=0)).reshape(11, -1).mean(1)
        assert np.all(diffs > 1e-3)                 # every frame moves


def test_static_camera_without_objects_is_static():
    cfg = dataclasses.replace(SMALL, speed_px=0, rotation_deg=0, zoom=0, shake_px=0, n_objects=0)
    for _, fr in render_split(cfg, "train"):
        np.testing.assert_allclose(fr.images, np.broadcast_to(fr.images[0], fr.images.shape), atol=1e-6)


def test_pan_geometry_matches_trajectory():
    # pure pan (wobble/shake amplitudes zeroed): frame j(p) = frame 0(p + j v) to sub-pixel accuracy
    import cv2
    cfg = dataclasses.replace(SMALL, height=64, width=64, speed_px=2.0, rotation_deg=0, zoom=0,
                              shake_px=0, n_objects=0, texture_fraction=0.0)
    spec = make_specs(cfg, "train")[0]
    cam = dict(spec.camera)
    for k in ("x", "y"):
        cam[k] = dict(cam[k], a=[0.0] * len(cam[k]["a"]))
    fr = render_sequence(dataclasses.replace(spec, camera=cam))
    v = np.array([cam["x"]["v"], cam["y"]["v"]])
    speed_px = np.hypot(*v)
    assert speed_px == pytest.approx(2.0, abs=1.0)                    # in [1, 3] px per frame

    def err(j, d):
        m = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        w = cv2.warpAffine(fr.images[0], m, (64, 64), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        return float(np.abs(w - fr.images[j])[12:-12, 12:-12].mean())

    for j in (1, 3):
        good = err(j, j * v)
        assert good < 0.5 * err(j, j * v + [0.5, 0]) and good < 0.5 * err(j, j * v + [0, 0.5])
        assert good < 0.2 * err(j, [0, 0])


def test_textures_and_config_errors():
    rng = np.random.default_rng(0)
    for kind in TEXTURES:
        t = procedural_texture(kind, 40, 50, rng)
        assert t.shape == (40, 50, 3) and t.dtype == np.float32 and 0 <= t.min() and t.max() <= 1
        assert t.std() > 0.02
    with pytest.raises(ConfigError, match="scenes.n_frames"):
        ScenesConfig(n_frames=1)
    with pytest.raises(ConfigError, match="scenes.texture_fraction"):
        ScenesConfig(texture_fraction=1.5)
    with pytest.raises(ConfigError, match="scenes.colour"):
        from_dict(ScenesConfig, {"colour": True}, "scenes")
    with pytest.raises(ConfigError):
        procedural_texture("plaid", 8, 8, rng)
    with pytest.raises(ConfigError, match="split"):
        make_specs(SMALL, "val")


def test_static_fraction_stills_cameras_and_leaves_other_draws_alone():
    cfg = dataclasses.replace(SMALL, n_train=12, n_test=6)
    for split in ("train", "test"):
        base = make_specs(cfg, split)
        mixed = make_specs(dataclasses.replace(cfg, static_fraction=0.5), split)
        still = still_cameras(dataclasses.replace(cfg, static_fraction=0.5), split)
        assert 0 < still.sum() < len(still)                                    # a mix at 0.5
        assert not still_cameras(cfg, split).any()                             # default 0: none
        assert still_cameras(dataclasses.replace(cfg, static_fraction=1.0), split).all()
        for b, m, s in zip(base, mixed, still):
            if s:   # same sequence but for a camera held at its start
                assert dataclasses.replace(m, camera=b.camera) == b
                for p in m.camera.values():
                    assert p["v"] == 0 and not any(p["a"])
            else:   # every other sequence is drawn exactly as without the key
                assert m == b


def test_still_camera_only_the_objects_change():
    cfg = dataclasses.replace(SMALL, static_fraction=1.0, n_objects=1, object_speed_px=2.0)
    spec = make_specs(cfg, "train")[0]
    fr = render_sequence(spec)
    changed = np.abs(fr.images - fr.images[0]).max(axis=0) > 1e-6
    assert 0.01 < changed.mean() < 0.9        # the object's path moves, the background does not
    bg = render_sequence(dataclasses.replace(spec, objects=()))
    np.testing.assert_allclose(bg.images, np.broadcast_to(bg.images[0], bg.images.shape), atol=1e-6)
    with pytest.raises(ConfigError, match="scenes.static_fraction"):
        ScenesConfig(static_fraction=-0.1)
