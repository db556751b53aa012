"""The proof scene's renderer (rdnet.calib.scene): exact band-limited shifts."""
import numpy as np

from rdnet.calib.scene import SceneSpec, draw_texture, render, shifted_texture


def test_a_band_limited_texture_is_shifted_exactly():
    # two cosines well below the Nyquist frequency: the interpolant is the texture itself,
    # so a shift by any fraction of a pixel is the cosines' own shift
    TW, W = 32, 20
    x = np.arange(TW)
    row = 0.5 + 0.3 * np.cos(2 * np.pi * 3 * x / TW) + 0.1 * np.sin(2 * np.pi * 7 * x / TW + 0.4)
    tex = np.tile(row, (4, 1)).astype(np.float32)
    for o in (0.0, 0.37, 1.5, -2.25, 11.0):
        got = next(shifted_texture(tex, [o], W))
        xs = np.arange(W) - o
        want = 0.5 + 0.3 * np.cos(2 * np.pi * 3 * xs / TW) + 0.1 * np.sin(2 * np.pi * 7 * xs / TW + 0.4)
        np.testing.assert_allclose(got, np.tile(want, (4, 1)), atol=1e-6)


def test_a_whole_pixel_shift_is_the_texture_rolled():
    spec = SceneSpec()
    tex = draw_texture(spec, np.random.default_rng(3))
    got = next(shifted_texture(tex, [5.0], spec.width))
    # equal up to the dropped Nyquist term, which the smoothed texture barely has
    np.testing.assert_allclose(got, np.roll(tex, 5, axis=1)[:, :spec.width], atol=0.01)


def test_the_contrast_does_not_follow_the_subpixel_phase():
    """The linear-interpolation renderer this replaced lowered the moving texture's
    contrast by 6 % at half-pixel shifts (std 0.1417 -> 0.1333 on this texture); a lens
    sees a translating texture at one contrast whatever its phase."""
    spec = SceneSpec()
    tex = draw_texture(spec, np.random.default_rng(0))
    stds = [img.std() for img in shifted_texture(tex, np.arange(10) / 10.0, spec.width)]
    assert max(stds) / min(stds) < 1.005


def test_frames_are_non_negative_and_keep_the_static_band():
    spec = SceneSpec()
    frames, tex = render(spec, np.random.default_rng(1), fps_hz=400.0)
    assert frames.images.min() >= 0.0
    rows = int(round(spec.static_fraction * spec.height))
    gain = np.where(np.arange(spec.width) < spec.width // 2, spec.dark_gain, 1.0).astype(np.float32)
    np.testing.assert_array_equal(frames.images[-1, :rows], tex[:rows, :spec.width] * gain)
