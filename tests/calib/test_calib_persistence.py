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


def test_own_guided_adds_the_own_term_to_the_fit_only():
    """OwnGuided (Effect.fit_own): the effect's own statistic's fit term, times its weight,
    joins every seed's fit discrepancy; the held-out discrepancy and terms are untouched,
    and an effect without fit_own is searched on the discrepancy alone."""
    from rdnet.calib.effects import EFFECTS
    from rdnet.calib.fit import Evaluation, OwnGuided, guided

    ev = Evaluation({"threshold_sigma": 0.1}, np.array([1.0, 2.0]), np.array([3.0, 4.0]),
                    {"pixel_persistence": np.array([0.5, 0.25]), "rate": np.array([1.0, 1.0])},
                    {"pixel_persistence": np.array([0.1, 0.1])}, 10.0)
    inner = type("F", (), {"ctx": "ctx", "__call__": lambda self, v: ev})()
    g = OwnGuided(inner, "pixel_persistence", 2.0)
    out = g({"threshold_sigma": 0.1})
    assert np.allclose(out.fit, [2.0, 2.5]) and out.fit_mean == pytest.approx(2.25)
    assert np.array_equal(out.held, ev.held) and out.held_terms is ev.held_terms and out.values == ev.values
    assert g.ctx == "ctx"
    mismatch = EFFECTS["threshold_mismatch"]
    assert mismatch.statistic == "pixel_persistence" and mismatch.fit_own > 0
    assert isinstance(guided(inner, mismatch), OwnGuided)
    assert guided(inner, EFFECTS["latency"]) is inner           # no fit_own: the discrepancy alone
    assert OwnGuided(inner, "no_such_statistic", 1.0)(None) is ev


def test_screen_start_judges_grid_points_as_the_guided_search_does():
    """The best screen point, where the golden section of threshold mismatch starts, is the
    one with the lowest guided score (discrepancy + own statistic), not the lowest plain
    discrepancy; an effect without ``fit_own`` keeps the plain best point."""
    from rdnet.calib.effects import EFFECTS
    from rdnet.calib.fit import Evaluation, _screen_start

    def ev(sigma, fit, own):
        return Evaluation({"threshold_sigma": sigma, "latency_us": sigma}, np.array([fit, fit]), np.array([0.0, 0.0]),
                          {"pixel_persistence": np.array([own, own])}, {}, 1.0)

    # the plain discrepancy prefers 0.03, the persistence term says 0.08 by far
    screened = [ev(0.03, 1.00, 0.40), ev(0.08, 1.02, 0.05), ev(0.2, 1.10, 0.30)]
    obj = type("O", (), {"ctx": None})()
    i, v = _screen_start(obj, {}, EFFECTS["threshold_mismatch"], screened)
    assert i == 1 and v["threshold_sigma"] == 0.08
    i, v = _screen_start(obj, {}, EFFECTS["latency"], screened)
    assert i == 0 and v["latency_us"] == 0.03


def test_reference_simulations_are_counted_once_per_context():
    """The persistence reference (PERSIST_REF_SEEDS simulations of the declared config) is
    run by the first objective on a context and counted in its ``n_sims``; a second
    objective on the same context reuses it and counts nothing; a candidate's simulations
    count once per seed (memoised)."""
    import calib_cases
    from rdnet.calib.context import build_context
    from rdnet.calib.fit import Objective
    from rdnet.calib.settings import CalibrateConfig
    from rdnet.sim.settings import DegradeConfig

    rec, _ = calib_cases.null_recording()
    ctx = build_context(rec, CalibrateConfig(), calib_cases.SENSOR.log_eps, interpolate=calib_cases.INTERP)
    degrade = DegradeConfig(shot_noise_hz=1.0)
    first = Objective(ctx, calib_cases.SENSOR, degrade, [0, 1])
    assert first.n_sims == len(st.PERSIST_REF_SEEDS) == 4
    second = Objective(ctx, calib_cases.SENSOR, degrade, [0, 1], engine=first.engine)
    assert second.n_sims == 0
    second({})
    second({})                                   # memoised: no new simulation
    assert second.n_sims == 2                    # shot noise draws random numbers: both seeds
