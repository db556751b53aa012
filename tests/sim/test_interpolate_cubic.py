"""Method 'cubic' of rdnet.sim.interpolate: a Catmull-Rom spline of log(I + eps) through four
frames, so that a pixel's trajectory turns between the frames, not at them."""
import dataclasses

import numpy as np
import pytest

from rdnet.errors import ValidationError
from rdnet.sim.interpolate import InterpolateConfig, PairInterpolator, pair_interpolator, upsample_all

EPS = 0.01
CUBIC = InterpolateConfig(method="cubic", log_eps=EPS)


def _from_log(values, shape=(4, 5)):
    """Frames whose log(I + EPS) is ``values[k]`` at every pixel."""
    return np.stack([np.full(shape, np.exp(v) - EPS, np.float32) for v in values])


def test_exact_on_a_sequence_linear_in_log():
    f = _from_log([-2.0, -1.5, -1.0, -0.5])
    pi = PairInterpolator(f[1], f[2], CUBIC, before=f[0], after=f[3])
    ends = PairInterpolator(f[1], f[2], CUBIC)     # a sequence's ends: the missing knots extrapolated
    for t in (0.0, 0.3, 0.5, 1.0):
        np.testing.assert_allclose(np.log(pi.frame(t) + EPS), -1.5 + 0.5 * t, atol=2e-6)
        np.testing.assert_allclose(np.log(ends.frame(t) + EPS), -1.5 + 0.5 * t, atol=2e-6)


def test_turns_between_the_frames():
    """log values 0, 1, 1, 0: the spline peaks at 1 + t (1 - t) / 2 between the two middle
    frames (1.125 at t = 0.5); a cross-fade stays flat there and turns only at the frames."""
    f = _from_log([0.0, 1.0, 1.0, 0.0], shape=(2, 2))
    pi = PairInterpolator(f[1], f[2], CUBIC, before=f[0], after=f[3])
    for t in (0.25, 0.5):
        np.testing.assert_allclose(np.log(pi.frame(t) + EPS), 1 + t * (1 - t) / 2, atol=2e-6)
    flat = PairInterpolator(f[1], f[2], dataclasses.replace(CUBIC, method="linear"))
    np.testing.assert_allclose(flat.frame(0.5), f[1], rtol=1e-6)


def test_ends_and_neighbours_of_a_sequence():
    """The upsampled sequence passes through its frames; inner pairs use the frames around
    them, the first and last pair repeat their own end (pair_interpolator)."""
    rng = np.random.default_rng(0)
    f = rng.uniform(0.05, 0.9, (4, 6, 7)).astype(np.float32)
    t = np.arange(4, dtype=np.int64) * 1000
    cfg = dataclasses.replace(CUBIC, max_upsample=4, verify=False, max_log_step=1e-3)
    out, tt = upsample_all(f, t, cfg, log_eps=EPS)
    idx = np.searchsorted(tt, t)
    np.testing.assert_array_equal(out[idx], f)
    mid = out[idx[1] + 2]                                 # t = 1500: pair 1 at s = 0.5
    inner = PairInterpolator(f[1], f[2], cfg, before=f[0], after=f[3])
    np.testing.assert_allclose(mid, inner.frame(0.5), rtol=1e-6)
    assert not np.allclose(mid, PairInterpolator(f[1], f[2], cfg).frame(0.5), rtol=1e-3)
    first = pair_interpolator(f, 0, f[0], f[1], cfg, None, None, EPS)
    np.testing.assert_allclose(first.frame(0.5), PairInterpolator(f[0], f[1], cfg, after=f[2]).frame(0.5))


def test_sampled_grid_equals_the_full_frame_sampled():
    rng = np.random.default_rng(1)
    f = rng.uniform(0.05, 0.9, (4, 9, 8)).astype(np.float32)
    pi = PairInterpolator(f[1], f[2], CUBIC, before=f[0], after=f[3])
    full = pi.frame(0.4)
    with pi.on_grid(2):
        sampled = pi.frame(0.4)
    np.testing.assert_array_equal(sampled, full[::2, ::2])
    np.testing.assert_array_equal(pi.frame(0.4), full)


def _spline(f, t):
    """The Catmull-Rom expression of ``PairInterpolator.cubic``, written out in float32."""
    p0, p1, p2, p3 = (np.log(x + np.float32(EPS)) for x in f)
    t = np.float32(t)
    v = p1 + np.float32(0.5) * t * ((p2 - p0) + t * ((2 * p0 - 5 * p1 + 4 * p2 - p3) + t * (3 * (p1 - p2) + p3 - p0)))
    return np.maximum(np.exp(v) - np.float32(EPS), 0).astype(np.float32)


def test_the_terms_free_of_t_are_kept_per_grid():
    """The spline's terms that do not depend on t are computed once per grid of ``on_grid``
    and the frame is assembled in place: every frame equals the expression written out, bit
    for bit, on the full grid, on two sampled grids, and on the full grid again after them."""
    rng = np.random.default_rng(4)
    f = rng.uniform(0.0, 0.9, (4, 11, 13)).astype(np.float32)
    pi = PairInterpolator(f[1], f[2], CUBIC, before=f[0], after=f[3])
    ts = (0.1, 0.5, 0.83)
    for s in (1, 2, 3, 1, 2):
        with pi.on_grid(s):
            for t in ts:
                got = pi.frame(t)
                assert got.dtype == np.float32 and got.flags.writeable
                np.testing.assert_array_equal(got, _spline(f[:, ::s, ::s], t))
    got = pi.frame(0.5)
    got[:] = -1                                          # a caller's change to a frame ...
    np.testing.assert_array_equal(pi.frame(0.5), _spline(f, 0.5))    # ... stays out of the next


def test_non_negative_and_bad_neighbour_shape():
    """An overshoot below black is clipped at 0 (linear intensity); a neighbour of another
    shape is refused by name."""
    f = np.stack([np.full((3, 3), v, np.float32) for v in (0.9, 0.0, 0.0, 0.9)])
    pi = PairInterpolator(f[1], f[2], CUBIC, before=f[0], after=f[3])
    assert pi.frame(0.5).min() >= 0.0
    with pytest.raises(ValidationError, match="before"):
        PairInterpolator(f[1], f[2], CUBIC, before=np.zeros((2, 3), np.float32))
