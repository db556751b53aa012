"""A null case (only the thresholds and a configured effect's value are off): the
calibration re-fits them and names no missing effect."""
import pytest

from rdnet.calib.calibrate import calibrate, finding
from rdnet.sim.settings import DegradeConfig

import calib_cases
from calib_cases import CFG, INTERP, NULL, SENSOR


def test_null_case_names_nothing():
    rec, truth = calib_cases.null_recording()
    cal = calibrate(rec, SENSOR, DegradeConfig(**NULL.base), CFG, seed=0, interpolate=INTERP, source="null")
    r = cal.report
    assert [e["name"] for e in r["effects"] if e["missing"]] == []
    assert len(r["effects"]) == 9                      # every left-out effect was tested
    assert all(e["confidence"] < 0.5 for e in r["effects"])
    # the wrong thresholds are re-fitted instead (truth: x1.3)
    assert r["basic_refit"]["threshold_scale"] == pytest.approx(truth["threshold_scale"], rel=0.1)
    assert r["discrepancy"]["heldout_after"] < r["discrepancy"]["heldout_before"]
    assert r["fitted_config"]["sensor"]["threshold_on"] == pytest.approx(0.2 * r["basic_refit"]["threshold_scale"])
    assert finding(r).startswith("No missing effect")
