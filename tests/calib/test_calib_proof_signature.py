"""The signature-statistic diagnostic of a candidate effect (rdnet.calib.fit.score)."""
import math

import numpy as np
import pytest

from rdnet.calib.effects import EFFECTS
from rdnet.calib.fit import Candidate, Evaluation, score
from rdnet.calib.settings import CalibrateConfig


def evaluation(terms: dict) -> Evaluation:
    held = sum(np.asarray(v, float) for v in terms.values())
    t = {k: np.asarray(v, float) for k, v in terms.items()}
    return Evaluation({}, held, held, t, t)


def test_signature_z_measures_the_effects_own_statistic():
    before = evaluation({"lag": [1.0, 1.1, 0.9], "rate_map": [2.0, 2.2, 1.8]})
    moved = evaluation({"lag": [0.2, 0.3, 0.1], "rate_map": [2.0, 2.2, 1.8]})
    c = score(Candidate(EFFECTS["latency"], {}, moved), before, CalibrateConfig())
    assert c.signature_before == pytest.approx(1.0) and c.signature_after == pytest.approx(0.2)
    assert c.signature_z == pytest.approx(0.8 / 0.1)              # drop / seed std
    # the same total gain from another statistic: the signature does not move
    other = evaluation({"lag": [1.0, 1.1, 0.9], "rate_map": [1.2, 1.4, 1.0]})
    c2 = score(Candidate(EFFECTS["latency"], {}, other), before, CalibrateConfig())
    assert c2.gain == pytest.approx(c.gain)
    assert c2.signature_z == pytest.approx(0.0)


def test_signature_z_takes_the_smaller_drop_against_the_ablated_fit():
    before = evaluation({"iei": [1.0, 1.1, 0.9]})
    ablated = evaluation({"iei": [0.5, 0.6, 0.4]})
    after = evaluation({"iei": [0.4, 0.5, 0.3]})
    c = score(Candidate(EFFECTS["refractory_period"], {}, after), before, CalibrateConfig(), ablated=ablated)
    assert c.signature_z == pytest.approx(0.1 / 0.1)


def test_signature_missing_statistic_stays_nan():
    before = evaluation({"lag": [1.0, 1.1, 0.9]})
    c = score(Candidate(EFFECTS["hot_pixels"], {}, evaluation({"lag": [0.5, 0.6, 0.4]})), before, CalibrateConfig())
    assert math.isnan(c.signature_z)


def test_signature_gate_vetoes_a_gain_that_comes_from_other_statistics():
    cfg = CalibrateConfig()
    before = evaluation({"static_on_fraction": [0.10, 0.11, 0.09], "rate_map": [3.0, 3.1, 2.9]})
    # a large, significant held-out gain, but all of it in rate_map: leak's own statistic is flat
    elsewhere = evaluation({"static_on_fraction": [0.10, 0.11, 0.09], "rate_map": [2.0, 2.1, 1.9]})
    c = score(Candidate(EFFECTS["leak_events"], {}, elsewhere), before, cfg)
    assert c.z > cfg.significance and c.relative > cfg.min_relative_gain
    assert c.vetoed and not c.significant
    assert c.confidence <= 0.25
    # the same gain with the signature moving too is named
    own = evaluation({"static_on_fraction": [0.02, 0.03, 0.01], "rate_map": [2.08, 2.18, 1.98]})
    c2 = score(Candidate(EFFECTS["leak_events"], {}, own), before, cfg)
    assert c2.significant and not c2.vetoed and c2.confidence > 0.5
    # an insignificant gain is not "vetoed" (the gate only removes what the gain would name)
    tiny = evaluation({"static_on_fraction": [0.10, 0.11, 0.09], "rate_map": [2.99, 3.09, 2.89]})
    c3 = score(Candidate(EFFECTS["leak_events"], {}, tiny), before, cfg)
    assert not c3.significant and not c3.vetoed
