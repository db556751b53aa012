"""The round-1 screen that the frame-interpolation choice reads (``screen_gains``): the
best effects' gains are measured between their grid points, not only at them, and more
than the single best one is fitted (``calibrate.screen_refine``)."""
import math
from types import SimpleNamespace

import pytest

from rdnet.calib.effects import EFFECTS
from rdnet.calib.fit import first_fit, screen, screen_gains
from rdnet.calib.settings import CalibrateConfig
from rdnet.sim.settings import DegradeConfig

TRUE_US = 2000.0        # between the grid points 1000 and 7071 us of [20, 50000], 5 points
BASE_FIT = 3.0          # the fit discrepancy without the effect


class Landscape:
    """An objective whose fit discrepancy is lowest at refractory_us = TRUE_US (squared log
    error), counting its evaluations; the simulated count always matches the recording, so
    the count-matched thresholds never move."""

    def __init__(self):
        self.ctx = SimpleNamespace(cfg=CalibrateConfig(candidates=["refractory_period"]))
        self.degrade = DegradeConfig()
        self.real_fit_count = 1000.0
        self.calls = []

    def __call__(self, values):
        self.calls.append(dict(values))
        r = values.get("refractory_us", 0.0)
        fit = BASE_FIT if r <= 0 else 1.0 + math.log(r / TRUE_US) ** 2
        return SimpleNamespace(values=dict(values), fit_mean=fit, held_mean=fit, fit_count=self.real_fit_count)


def test_the_reach_is_measured_between_grid_points():
    obj = Landscape()
    evs, grid, keep = screen(obj, {}, EFFECTS["refractory_period"], 5, 1.0)
    assert grid[2] == pytest.approx(1000.0) and grid[3] == pytest.approx(7071.07, rel=1e-4)
    at_grid = (BASE_FIT - min(e.fit_mean for e in evs)) / BASE_FIT
    assert at_grid == pytest.approx((2.0 - math.log(2.0) ** 2) / 3.0)         # at 1000 us
    gains, points = screen_gains(obj, obj, {}, 1.0)
    v = first_fit(obj, {}, EFFECTS["refractory_period"], evs, grid, keep, 1.0)
    assert points == {"refractory_period": v}                             # the refined values
    assert 1400.0 < v["refractory_us"] < 2900.0                             # 4 golden steps in [141, 7071]
    assert gains["refractory_period"] == pytest.approx((BASE_FIT - obj(v).fit_mean) / BASE_FIT)
    assert gains["refractory_period"] > at_grid + 0.1


class TwoEffects(Landscape):
    """Refractory period (truth TRUE_US, as in Landscape: 1.48 at its best grid point, 1000
    us) and readout saturation, whose minimum (0.5 at 3000 us) is deeper but steeper, so at
    its best grid point (7071 us: 1.97) it looks worse than refractory: the screen's order
    and the fitted order disagree, as look-alikes' do on a one-seed screen."""

    def __init__(self, refine: int):
        super().__init__()
        self.ctx = SimpleNamespace(cfg=CalibrateConfig(candidates=["refractory_period", "readout_saturation"],
                                                       screen_refine=refine))

    def __call__(self, values):
        r, p = values.get("refractory_us", 0.0), values.get("sample_period_us", 0.0)
        fit = BASE_FIT
        if r > 0:
            fit = min(fit, 1.0 + math.log(r / TRUE_US) ** 2)
        if p > 0:
            fit = min(fit, 0.5 + 2.0 * math.log(p / 3000.0) ** 2)
        self.calls.append(dict(values))
        return SimpleNamespace(values=dict(values), fit_mean=fit, held_mean=fit, fit_count=self.real_fit_count)


def test_more_than_the_best_screened_effect_is_fitted():
    one, two = TwoEffects(1), TwoEffects(2)
    gains1, points1 = screen_gains(one, one, {}, 1.0)
    gains2, points2 = screen_gains(two, two, {}, 1.0)
    assert list(points1) == ["refractory_period"]                # the screen's best only
    assert list(points2) == ["refractory_period", "readout_saturation"]   # best first
    reach1 = min(one(v).fit_mean for v in points1.values())
    reach2 = min(two(v).fit_mean for v in points2.values())
    assert reach1 > 1.0                       # refractory's floor
    assert reach2 < 0.9                       # readout saturation fitted reaches below it
    assert gains2["readout_saturation"] == pytest.approx((BASE_FIT - reach2) / BASE_FIT)
    assert gains1["refractory_period"] == pytest.approx(gains2["refractory_period"])


def test_a_guess_is_refined_within_a_factor_of_three():
    """A screen point from a data-driven guess (no grid) is refined around the guess, as the
    forward selection's fit does, so neither kind of screen is favoured by the choice."""
    obj = Landscape()
    guess = obj({"refractory_us": 1000.0})
    v = first_fit(obj, {}, EFFECTS["refractory_period"], [guess], None, None, 1.0)
    assert 1000.0 < v["refractory_us"] <= 3000.0
    assert obj(v).fit_mean < guess.fit_mean - 0.3


def _evaluation(fit: float, own: float):
    import numpy as np

    from rdnet.calib.fit import Evaluation
    return Evaluation(values={}, fit=np.array([fit]), held=np.array([fit]),
                      fit_terms={"pixel_persistence": np.array([own])}, held_terms={})


def test_an_effect_searched_on_its_own_statistic_is_screened_on_it_too():
    """Threshold mismatch (fit_own 1) whose best screen point leaves the plain fit
    discrepancy 2 % worse but lowers its own statistic's fit term by 0.3: the score its
    search runs on drops by 0.3 - 0.02, which is what makes it plausible; an effect
    without fit_own has no guided gain."""
    from rdnet.calib.fit import _guided_gain
    current = _evaluation(1.00, 0.40)

    class Current:                   # the objective: the current config's evaluation
        ctx = None

        def __call__(self, values):
            return current

    obj = Current()
    evs = [_evaluation(1.02, 0.10), _evaluation(1.05, 0.35)]
    assert _guided_gain(obj, {}, EFFECTS["threshold_mismatch"], evs) == pytest.approx(0.28)
    assert _guided_gain(obj, {}, EFFECTS["refractory_period"], evs) == -math.inf


def test_costly_effects_are_fitted_by_the_score_that_made_them_plausible():
    """``effects_to_fit`` (step 3): the proof's oversample4 threshold mismatch ``s2B`` screen.
    Its plain drop is negative but its guided one (the fit discrepancy plus its own
    statistic) the largest; ranked by the plain drop, ON/OFF asymmetry and leak took the
    two fits. Every cheap (additive) effect is fitted; nothing at or below screen_gain is."""
    from rdnet.calib.fit import effects_to_fit

    cfg = CalibrateConfig(max_fitted=2, screen_gain=0.02)
    gains = {"latency": 0.211, "onoff_asymmetry": 0.038, "leak_events": 0.024, "readout_saturation": 0.0,
             "threshold_mismatch": 0.52, "hot_pixels": 0.031, "refractory_period": -0.405}
    costly = {n: n not in ("latency", "hot_pixels") for n in gains}
    assert effects_to_fit(gains, costly, cfg) == ["latency", "hot_pixels", "threshold_mismatch", "onoff_asymmetry"]
    # on a level where every effect is simulated (a small scene: search = final sample)
    everything = {n: True for n in gains}
    assert effects_to_fit(gains, everything, cfg) == ["threshold_mismatch", "latency"]
    assert effects_to_fit(gains, everything, CalibrateConfig(max_fitted=5, screen_gain=0.03)) == [
        "threshold_mismatch", "latency", "onoff_asymmetry", "hot_pixels"]
    assert effects_to_fit({"leak_events": 0.02}, {"leak_events": True}, cfg) == []   # strictly above
