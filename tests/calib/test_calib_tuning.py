"""The bandwidth's tuning parameter (the dark-current floor): its search coordinates and
the rule that keeps the declared floor unless a free one fits clearly better."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from rdnet.calib.effects import EFFECTS
from rdnet.calib.fit import _bandwidth_coordinates, _fit_tuning
from rdnet.calib.settings import CalibrateConfig
from rdnet.sim.settings import DegradeConfig

BW = EFFECTS["bandwidth"]
EPS = 0.01
I_D, I_B = 0.04, 0.6            # upper edge of the darkest bin, lower edge of the brightest


def fake_objective(**cfg):
    edges = np.log(np.array([0.0, I_D, 0.1, 0.2, 0.3, I_B, 1.0]) + EPS)
    ctx = SimpleNamespace(intensity_edges=edges, log_eps=EPS, cfg=CalibrateConfig(**cfg))
    return SimpleNamespace(ctx=ctx, degrade=DegradeConfig())


def cutoff(v, i):
    b = v.get("cutoff_floor", DegradeConfig().cutoff_floor)
    return v["cutoff_hz"] * (i + b) / (1 + b)


def test_each_coordinate_moves_one_end_of_the_intensity_range_only():
    obj = fake_objective()
    (dark, dark_at), (bright, bright_at) = _bandwidth_coordinates(obj, BW)
    v = {"cutoff_hz": 100.0, "cutoff_floor": 0.05, "threshold_scale": 1.3}
    assert dark_at(v) == pytest.approx(100 * 0.09 / 1.05)
    assert bright_at(v) == pytest.approx(100 * 0.65 / 1.05)
    w = dark(v, 6.0)
    assert cutoff(w, I_D) == pytest.approx(6.0) and cutoff(w, I_B) == pytest.approx(cutoff(v, I_B))
    assert w["threshold_scale"] == 1.3 and v["cutoff_floor"] == 0.05      # other keys kept, input not mutated
    w = bright(v, 80.0)
    assert cutoff(w, I_B) == pytest.approx(80.0) and cutoff(w, I_D) == pytest.approx(cutoff(v, I_D))
    # f(I) = k (I + b): from the two cutoffs, b = f_d / k - I_d exactly
    w = dark(v, 5.0)
    k = (cutoff(v, I_B) - 5.0) / (I_B - I_D)
    assert w["cutoff_floor"] == pytest.approx(5.0 / k - I_D) and 0.009 < w["cutoff_floor"] < 0.0095


def test_a_floor_outside_its_range_is_clipped_keeping_the_bright_cutoff():
    obj = fake_objective()
    (dark, _), _ = _bandwidth_coordinates(obj, BW)
    v = {"cutoff_hz": 100.0, "cutoff_floor": 0.05}
    lo = BW.tuning[0].lo
    w = dark(v, 0.1)                      # slower than any floor >= lo allows
    assert w["cutoff_floor"] == lo
    assert cutoff(w, I_B) == pytest.approx(cutoff(v, I_B))


def landscape(target: dict, *, floor_matters: bool = True, held: float = 1.0):
    """A fit discrepancy that is zero at ``target``: squared log errors of the cutoffs at
    both ends (or of the cutoff at I = 1 only); the held-out discrepancy moves ``held``
    times as much."""
    def f(v):
        if floor_matters:
            r = sum(math.log(cutoff(v, i) / cutoff(target, i)) ** 2 for i in (I_D, I_B))
        else:
            r = math.log(v["cutoff_hz"] / target["cutoff_hz"]) ** 2
        return SimpleNamespace(values=dict(v), fit_mean=1.0 + r, held_mean=1.0 + held * r)
    return f


def test_the_floor_is_found_when_the_data_show_it():
    obj = fake_objective()
    truth = {"cutoff_hz": 100.0, "cutoff_floor": 0.01}
    start = {"cutoff_hz": 60.0}           # fitted at the declared floor 20/255
    v, free = _fit_tuning(landscape(truth), obj, start, BW)
    assert [p.key for p in free] == ["cutoff_floor"]
    assert v["cutoff_hz"] == pytest.approx(100.0, rel=0.1)
    assert v["cutoff_floor"] == pytest.approx(0.01, rel=0.3)
    assert start == {"cutoff_hz": 60.0}


def test_the_declared_floor_stays_when_a_free_one_does_not_fit_clearly_better():
    obj = fake_objective()
    truth = {"cutoff_hz": 100.0, "cutoff_floor": 0.01}
    v, free = _fit_tuning(landscape(truth, floor_matters=False), obj, {"cutoff_hz": 60.0}, BW)
    assert free == [] and "cutoff_floor" not in v
    assert v["cutoff_hz"] == pytest.approx(100.0, rel=0.1)      # the own parameter is still refined
    # a real but small improvement (below calibrate.min_relative_gain) keeps it declared too
    v, free = _fit_tuning(landscape(truth), fake_objective(min_relative_gain=0.99), {"cutoff_hz": 60.0}, BW)
    assert free == [] and "cutoff_floor" not in v
    # a floor that fits the fit segments but not the held-out ones (nuisance) stays declared
    v, free = _fit_tuning(landscape(truth, held=0.0), fake_objective(), {"cutoff_hz": 60.0}, BW)
    assert free == [] and "cutoff_floor" not in v


def test_only_the_bandwidth_has_tuning_coordinates():
    assert [e.name for e in EFFECTS.values() if e.tuning] == ["bandwidth"]
    with pytest.raises(ValueError, match="latency"):
        _bandwidth_coordinates(fake_objective(), EFFECTS["latency"])
