"""Hot-pixel polarity (``degrade.hot_pixel_on_fraction`` m, ``hot_pixel_polarity_concentration``
k): each hot pixel fires ON with probability q_i ~ Beta(k m, k (1 - m)); k = 0 is one
polarity per pixel, ON with probability m (the model before these keys existed)."""
import numpy as np
import pytest

from rdnet.errors import ConfigError
from rdnet.sim import effects
from rdnet.sim.settings import DegradeConfig

H, W = 100, 100


def _events(d: DegradeConfig, seed: int = 0):
    rng = np.random.default_rng(seed)
    idx, on = effects.hot_pixels(H, W, d, rng)
    return idx, on, effects.hot_pixel_events(idx, on, d.hot_pixel_hz, 0, 1_000_000, W, rng)


def _per_pixel_on_share(ev) -> np.ndarray:
    flat = ev["y"].astype(np.int64) * W + ev["x"]
    pix, inv = np.unique(flat, return_inverse=True)
    return np.bincount(inv, weights=ev["p"].astype(float)) / np.bincount(inv)


def test_default_is_one_polarity_per_pixel_half_of_them_on():
    d = DegradeConfig(hot_pixel_fraction=0.2, hot_pixel_hz=50.0)
    idx, on, ev = _events(d)
    assert idx.size == 2000 and set(np.unique(on)) == {0.0, 1.0}
    assert abs(on.mean() - 0.5) < 0.05
    share = _per_pixel_on_share(ev)
    assert set(np.unique(share)) == {0.0, 1.0}          # every pixel fires one polarity


def test_the_default_draws_what_a_fixed_half_split_draws():
    """k = 0, m = 0.5 takes the same random numbers as the one-polarity model (pixel
    choice, one uniform per pixel < 0.5, Poisson counts, times): the study's data do not
    change with these keys."""
    d = DegradeConfig(hot_pixel_fraction=0.01, hot_pixel_hz=300.0)
    idx, on, ev = _events(d, seed=5)
    rng = np.random.default_rng(5)
    ref_idx = np.sort(rng.choice(H * W, size=100, replace=False))
    ref_pol = rng.random(100) < 0.5
    counts = rng.poisson(np.full(100, 300.0))
    assert np.array_equal(idx, ref_idx) and np.array_equal(on.astype(bool), ref_pol)
    assert np.array_equal(ev["p"], np.repeat(ref_pol, counts).astype(np.uint8))


@pytest.mark.parametrize("m", [0.0, 1.0])
def test_on_fraction_zero_or_one_gives_one_polarity(m):
    for k in (0.0, 3.0):
        d = DegradeConfig(hot_pixel_fraction=0.05, hot_pixel_hz=40.0, hot_pixel_on_fraction=m,
                          hot_pixel_polarity_concentration=k)
        _, _, ev = _events(d)
        assert ev.size > 0 and np.all(ev["p"] == int(m))


def test_concentration_mixes_polarities_with_the_beta_spread():
    m, k = 0.7, 3.0
    d = DegradeConfig(hot_pixel_fraction=0.2, hot_pixel_hz=2000.0, hot_pixel_on_fraction=m,
                      hot_pixel_polarity_concentration=k)
    _, on, ev = _events(d)
    assert abs(ev["p"].mean() - m) < 0.02
    share = _per_pixel_on_share(ev)
    # both polarities in most pixels; the spread of the shares is the Beta's,
    # m (1 - m) / (k + 1) = 0.0525 (plus 0.0001 of binomial noise at 2000 events)
    assert np.mean((share > 0.02) & (share < 0.98)) > 0.8
    assert 0.04 < share.var() < 0.065
    assert abs(on.mean() - m) < 0.02


def test_large_concentration_gives_every_pixel_the_same_share():
    d = DegradeConfig(hot_pixel_fraction=0.05, hot_pixel_hz=2000.0, hot_pixel_on_fraction=0.74,
                      hot_pixel_polarity_concentration=1e6)
    _, _, ev = _events(d)
    share = _per_pixel_on_share(ev)
    assert np.all(np.abs(share - 0.74) < 0.05)


def test_same_seed_same_bits():
    d = DegradeConfig(hot_pixel_fraction=0.05, hot_pixel_hz=500.0, hot_pixel_on_fraction=0.6,
                      hot_pixel_polarity_concentration=2.0)
    assert _events(d, 3)[2].tobytes() == _events(d, 3)[2].tobytes()
    assert _events(d, 3)[2].tobytes() != _events(d, 4)[2].tobytes()


@pytest.mark.parametrize("key,value", [("hot_pixel_on_fraction", 1.2), ("hot_pixel_on_fraction", -0.1),
                                       ("hot_pixel_polarity_concentration", -1.0)])
def test_bad_values_name_the_key(key, value):
    with pytest.raises(ConfigError, match=f"degrade.{key}"):
        DegradeConfig(**{key: value})


@pytest.mark.parametrize("m,k", [(0.7, 3.0), (0.3, 10.0), (0.5, 0.0)])
def test_polarity_fit_recovers_the_simulated_on_fraction_and_concentration(m, k):
    from rdnet.sim.effects import fit_hot_pixel_polarity
    d = DegradeConfig(hot_pixel_fraction=0.3, hot_pixel_hz=200.0, hot_pixel_on_fraction=m,
                      hot_pixel_polarity_concentration=k)
    _, _, ev = _events(d, seed=1)
    flat = ev["y"].astype(np.int64) * W + ev["x"]
    _, inv = np.unique(flat, return_inverse=True)
    got_m, got_k = fit_hot_pixel_polarity(np.bincount(inv, weights=ev["p"].astype(float)), np.bincount(inv))
    assert abs(got_m - m) < 0.03
    assert got_k == pytest.approx(k, abs=0.3) if k < 1 else 0.75 * k < got_k < 1.33 * k


def test_polarity_fit_known_values():
    from rdnet.sim.effects import fit_hot_pixel_polarity
    # every pixel at one share, many events: no spread beyond the binomial one -> inf
    m, k = fit_hot_pixel_polarity([700, 702, 698, 701], [1000, 1000, 1000, 1000])
    assert m == pytest.approx(0.70025) and k == float("inf")
    # one polarity per pixel: variance m (1 - m) -> k = 0
    m, k = fit_hot_pixel_polarity([0, 100, 100, 0], [100, 100, 100, 100])
    assert m == 0.5 and k == pytest.approx(0.0, abs=0.35)
    with pytest.raises(ValueError, match="two hot pixels"):
        fit_hot_pixel_polarity([3], [5])
