import numpy as np
import pytest

from _synth_scene import psnr, translating_scene
from rdnet.baselines.edi import edi_deblur, edi_from_voxel
from rdnet.errors import ValidationError
from rdnet.events import voxel_grid

C_TRUE = 0.2


@pytest.fixture(scope="module")
def scene():
    return translating_scene(seed=4, C=C_TRUE, shift_px=12.0)


def test_edi_with_true_threshold_is_near_exact(scene):
    blurry, sharp, ev, T = scene
    out, c = edi_deblur(blurry, ev, 0, T, c=C_TRUE)
    assert c == C_TRUE
    # measured 38.4 dB vs 25.0 dB blurry: the residual is the threshold quantisation
    assert psnr(out, sharp) > psnr(blurry, sharp) + 12


def test_edi_search_recovers_threshold_and_deblurs(scene):
    blurry, sharp, ev, T = scene
    out, c = edi_deblur(blurry, ev, 0, T)
    assert abs(c - C_TRUE) / C_TRUE < 0.3          # measured c = 0.207 (seeds 5-7: 0.18-0.22)
    gain = psnr(out, sharp) - psnr(blurry, sharp)  # measured +13.0 dB (25.0 -> 38.0)
    assert gain > 8
    assert out.dtype == np.float32 and out.shape == blurry.shape


def test_edi_from_voxel_bin_resolution(scene):
    blurry, sharp, ev, T = scene
    vox = voxel_grid(ev, 10, 0, T)
    out, c = edi_from_voxel(blurry, vox)
    assert abs(c - C_TRUE) / C_TRUE < 0.3          # measured c = 0.214
    assert psnr(out, sharp) > psnr(blurry, sharp) + 8   # measured +12.2 dB
    # pairs layout (C, H, W) in -> same layout out, same values
    out_chw, c2 = edi_from_voxel(blurry[None], vox)
    assert out_chw.shape == (1,) + blurry.shape and c2 == c
    np.testing.assert_array_equal(out_chw[0], out)


def test_edi_colour_shares_denominator(scene):
    blurry, sharp, ev, T = scene
    rgb = np.stack([blurry, 0.5 * blurry, 0.25 * blurry], axis=-1)
    out, _ = edi_deblur(rgb, ev, 0, T, c=C_TRUE)
    grey, _ = edi_deblur(blurry, ev, 0, T, c=C_TRUE)
    np.testing.assert_allclose(out[..., 1], 0.5 * grey, rtol=1e-5)


def test_edi_without_events_returns_blurry(scene):
    blurry, _, ev, T = scene
    out, _ = edi_deblur(blurry, ev.slice_time(0, 0), 0, T, c=0.3)
    np.testing.assert_allclose(out, blurry, rtol=1e-6)


def test_edi_reference_time_moves_latent_image(scene):
    blurry, _, ev, T = scene
    start, _ = edi_deblur(blurry, ev, 0, T, t_ref_us=0, c=C_TRUE)
    mid, _ = edi_deblur(blurry, ev, 0, T, c=C_TRUE)
    # the texture moves 12 px over the exposure: the start image is the mid one shifted 6 px
    err_shift = np.abs(start[:, 6:] - mid[:, :-6]).mean()
    err_same = np.abs(start - mid).mean()
    assert err_shift < 0.5 * err_same


def test_edi_rejects_bad_input(scene):
    blurry, _, ev, T = scene
    with pytest.raises(ValidationError):
        edi_deblur(blurry, ev, T, 0)
    with pytest.raises(ValidationError):
        edi_deblur(blurry[:10], ev, 0, T)
    with pytest.raises(ValidationError):
        edi_deblur(blurry, ev, 0, T, c_range=(1.0, 0.1))
