"""``pixel_persistence`` (threshold mismatch's own statistic) on counts with known answers:
a per-pixel gain repeats between the two halves of the segments, a global gain and count
noise do not."""
import numpy as np
import pytest

from rdnet.calib import stats as st

S, P = 6, 4000


def _counts(gain: np.ndarray, rng: np.random.Generator, ref_rate: float = 200.0) -> tuple[np.ndarray, np.ndarray]:
    """(S, P) Poisson counts of pixels firing ``gain`` x the reference's mean, and that mean."""
    ref = np.full((S, P), ref_rate)
    return rng.poisson(ref * gain[None, :]).astype(np.float64), ref


def _persistence(pix, ref, moving=None):
    moving = np.ones(P, bool) if moving is None else moving
    return st._persistence(pix, ref, range(0, S, 2), range(1, S, 2), moving)


def test_a_per_pixel_gain_persists_by_its_log_variance():
    rng = np.random.default_rng(0)
    sigma = 0.2                                   # log-normal per-pixel gain
    pix, ref = _counts(np.exp(sigma * rng.standard_normal(P)), rng)
    # the covariance of each pixel's log excess between the halves is var(log gain),
    # a little less after the 2 % trim of the most extreme pixels
    assert _persistence(pix, ref) == pytest.approx(sigma ** 2, rel=0.2)


def test_count_noise_and_a_global_gain_do_not_persist():
    rng = np.random.default_rng(1)
    for gain in (1.0, 2.0):                       # the reference itself, or every pixel x2
        pix, ref = _counts(np.full(P, gain), rng)
        assert abs(_persistence(pix, ref)) < 2e-4


def test_persistence_grows_with_the_spread_and_needs_enough_pixels():
    rng = np.random.default_rng(2)
    z = rng.standard_normal(P)
    values = [_persistence(*_counts(np.exp(s * z), rng)) for s in (0.05, 0.1, 0.2)]
    assert values[0] < values[1] < values[2]
    pix, ref = _counts(np.exp(0.2 * z), rng)
    few = np.zeros(P, bool)
    few[:10] = True                               # fewer than 20 moving pixels: no estimate
    assert np.isnan(_persistence(pix, ref, few))
