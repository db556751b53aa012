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
