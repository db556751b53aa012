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
    before = evaluation({"lag_smoothed": [1.0, 1.1, 0.9], "rate_map": [2.0, 2.2, 1.8]})
    moved = evaluation({"lag_smoothed": [0.2, 0.3, 0.1], "rate_map": [2.0, 2.2, 1.8]})
    c = score(Candidate(EFFECTS["latency"], {}, moved), before, CalibrateConfig())
    assert c.signature_before == pytest.approx(1.0) and c.signature_after == pytest.approx(0.2)
    assert c.signature_z == pytest.approx(0.8 / 0.1)              # drop / seed std
    # the same total gain from another statistic: the signature does not move
    other = evaluation({"lag_smoothed": [1.0, 1.1, 0.9], "rate_map": [1.2, 1.4, 1.0]})
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


OWN = EFFECTS["hot_pixels"].statistic


def test_own_statistic_names_an_effect_whose_total_gain_is_within_the_seed_spread():
    cfg = CalibrateConfig()
    # the total held-out discrepancy scatters over seeds (a structural term the effect does
    # not touch), but the effect's own statistic drops far beyond its own spread and the
    # total drops in every seed
    before = evaluation({OWN: [0.60, 0.62, 0.58], "rate_map": [1.0, 2.0, 1.5]})
    after = evaluation({OWN: [0.10, 0.12, 0.08], "rate_map": [1.0, 2.0, 1.5]})
    c = score(Candidate(EFFECTS["hot_pixels"], {}, after), before, cfg)
    assert c.z < cfg.significance and c.relative > cfg.min_relative_gain
    assert c.signature_z > cfg.signature_significance
    assert c.by_signature and c.significant and c.confidence > 0.5
    # switched off, the same candidate is not named
    off = CalibrateConfig(signature_significance=0.0)
    c_off = score(Candidate(EFFECTS["hot_pixels"], {}, after), before, off)
    assert not c_off.significant and not c_off.by_signature and c_off.confidence < 0.5
    # one seed that gets worse: not named by the signature
    mixed = evaluation({OWN: [0.10, 0.12, 0.08], "rate_map": [1.0, 2.0, 2.1]})
    c_mixed = score(Candidate(EFFECTS["hot_pixels"], {}, mixed), before, cfg)
    assert c_mixed.signature_z > cfg.signature_significance and not c_mixed.significant
    # a small own drop (below signature_significance seed spreads): not named
    small = evaluation({OWN: [0.55, 0.57, 0.53], "rate_map": [1.0, 2.0, 1.5]})
    c_small = score(Candidate(EFFECTS["hot_pixels"], {}, small), before, cfg)
    assert c_small.signature_z < cfg.signature_significance and not c_small.significant
    # nor when the relative gain is below min_relative_gain
    big = evaluation({OWN: [0.60, 0.62, 0.58], "rate_map": [50.0, 60.0, 55.0]})
    after_big = evaluation({OWN: [0.10, 0.12, 0.08], "rate_map": [50.0, 60.0, 55.0]})
    c_rel = score(Candidate(EFFECTS["hot_pixels"], {}, after_big), big, cfg)
    assert c_rel.relative < cfg.min_relative_gain and not c_rel.significant


def test_next_round_drops_the_added_effect_even_when_a_vetoed_one_ranked_above_it():
    from rdnet.calib.fit import next_round
    before = evaluation({"lag": [1.0, 1.1, 0.9]})
    names = ["bandwidth", "refractory_period", "latency", "shot_noise"]
    cands = [Candidate(EFFECTS[n], {}, before, fitted=(n != "shot_noise"), gain=g)
             for n, g in zip(names, (0.9, 0.5, 0.1, 0.2))]
    cands[0].vetoed = True                       # the top one is skipped: the second is added
    best = next(c for c in cands if not c.vetoed)
    assert best.effect.name == "refractory_period"
    left = next_round([EFFECTS[n] for n in names], cands, best)
    # the vetoed one and the other fitted helper stay; the added one and the unfitted one go
    assert [e.name for e in left] == ["bandwidth", "latency"]


def test_look_alikes_are_the_candidates_the_held_out_data_do_not_separate():
    from rdnet.calib.calibrate import separating_measurement
    from rdnet.calib.fit import look_alikes
    cfg = CalibrateConfig()
    chosen = Candidate(EFFECTS["refractory_period"], {}, evaluation({"iei": [1.00, 1.10, 0.90]}), fitted=True)
    close = Candidate(EFFECTS["readout_saturation"], {}, evaluation({"iei": [1.05, 1.15, 0.95]}), fitted=True)
    far = Candidate(EFFECTS["latency"], {}, evaluation({"iei": [3.0, 3.1, 2.9]}), fitted=True)
    unfitted = Candidate(EFFECTS["shot_noise"], {}, evaluation({"iei": [1.0, 1.1, 0.9]}), fitted=False)
    vetoed = Candidate(EFFECTS["bandwidth"], {}, evaluation({"iei": [1.0, 1.1, 0.9]}), fitted=True)
    vetoed.vetoed = True
    out = look_alikes(chosen, [chosen, close, far, unfitted, vetoed], cfg)
    assert [o.effect.name for o, _, _ in out] == ["readout_saturation"]
    (_, margin, spread), = out
    assert margin == pytest.approx(0.05) and spread == pytest.approx(0.1)
    assert "inter-event-interval" in separating_measurement("readout_saturation", "refractory_period")
    assert "LED" in separating_measurement("latency", "bandwidth")
    assert "flicker" in separating_measurement("threshold_mismatch", "onoff_asymmetry")   # first match
    assert "still scene" in separating_measurement("hot_pixels", "threshold_mismatch")
    # the proof's leak / ON-OFF asymmetry look-alikes: the still pixels already separate them
    assert "ON share of still pixels" in separating_measurement("onoff_asymmetry", "leak_events")
    assert separating_measurement("latency", "hot_pixels").startswith("a recording that drives one")


def test_between_look_alikes_the_surest_gain_is_named():
    """The round's largest gain (bandwidth, 3.76 +- 0.74) and a look-alike whose held-out
    discrepancy the seeds do not separate from it (latency, 3.49 +- 0.30, DAVIS346 seed 2):
    latency's gain stands further above its spread (3.19 against 3.02), so it is named. A
    look-alike that is not significant, or one the held-out data separate, is not."""
    from rdnet.calib.fit import surest
    cfg = CalibrateConfig()

    def cand(name, held, gain, spread, significant=True):
        c = Candidate(EFFECTS[name], {}, evaluation({"iei": held}), fitted=True)
        c.gain, c.spread, c.significant = gain, spread, significant
        return c

    best = cand("bandwidth", [8.0, 8.9, 9.6], 3.76, 0.74)
    alike = cand("latency", [8.3, 9.1, 9.9], 3.49, 0.30)
    assert surest(best, [best, alike], cfg) is alike
    assert surest(best, [best, cand("latency", [8.3, 9.1, 9.9], 3.49, 0.30, significant=False)], cfg) is best
    assert surest(best, [best, cand("latency", [12.0, 12.9, 13.6], 3.49, 0.30)], cfg) is best   # separated
    assert surest(best, [best, cand("latency", [8.3, 9.1, 9.9], 3.49, 0.80)], cfg) is best      # less sure
