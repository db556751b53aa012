"""The restoration check on the independent circuit generator (rdnet.study.independent)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from rdnet.config import load_params, section
from rdnet.events.io import read_events, read_header, read_recording
from rdnet.study import data as D
from rdnet.study.independent import circuit_file, circuit_restoration, markdown

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A one-sequence test split of the study's data steps (20 x 24 pixels)."""
    tmp = tmp_path_factory.mktemp("study")
    p = yaml.safe_load((ROOT / "params.yaml").read_text())
    p["scenes"].update(n_train=1, n_test=1, height=20, width=24, n_frames=40, n_objects=1)
    p["interpolate"].update(max_upsample=4)
    params = load_params(None, base=p)
    D.render_scenes(params, tmp / "scenes")
    D.interpolate_scenes(params, tmp / "scenes", tmp / "interp")
    D.simulate_sequences(params, tmp / "scenes", tmp / "interp", tmp / "events")
    return params, tmp / "events"


def test_circuit_file_keeps_frames_and_degradation(study, tmp_path):
    params, events = study
    src = events / "test" / "seq_000.h5"
    counts = circuit_file(src, tmp_path / "a.h5", section(params, "sensor"), seed=3)
    a, s = read_recording(tmp_path / "a.h5"), read_recording(src)
    assert read_header(tmp_path / "a.h5")[2] == "rdnet-circuit"
    assert np.array_equal(a.frames.images, s.frames.images) and np.array_equal(a.frames.t_us, s.frames.t_us)
    assert a.attrs["degrade_json"] == s.attrs["degrade_json"]
    ideal, degraded = read_events(tmp_path / "a.h5", "events_ideal"), read_events(tmp_path / "a.h5", "events")
    assert counts["circuit"] == {"undegraded": len(ideal), "degraded": len(degraded)}
    assert counts["simulator"]["undegraded"] == len(read_events(src, "events_ideal"))
    # two ideal pixels at the same thresholds on the same frames, written independently: close counts
    assert abs(len(ideal) / counts["simulator"]["undegraded"] - 1) < 0.25
    assert len(degraded) > 0 and not np.array_equal(ideal.t[:50], degraded.t[:50])
    circuit_file(src, tmp_path / "b.h5", section(params, "sensor"), seed=3)     # same seed, same events
    assert np.array_equal(read_events(tmp_path / "b.h5", "events").array, degraded.array)


def test_circuit_restoration_table_over_draws(study):
    params, events = study
    res = circuit_restoration(params, events, {}, draws=2, seed=0)
    assert res["draws"] == 2 and len(res["sequences"]) == 2
    rows = res["events"]
    assert {"degraded", "baf", "stcf"} <= set(rows)
    for r in rows.values():
        assert 0 <= r["f1"] <= 1 and r["f1_draw_std"] >= 0 and r["voxel_l1_all"] >= 0
    table = markdown(res, {"degraded": {"events": {k: 0.5 for k in ("f1", "precision", "recall", "count_ratio",
                                                                     "voxel_l1_all")}}})
    assert "| degraded |" in table and "(0.500)" in table and "+0.0 %" in table


def test_zero_draws_switch_the_check_off(study):
    params, events = study
    res = circuit_restoration(params, events, {}, draws=0)
    assert res["draws"] == 0 and res["events"] == {} and res["rows"] == {} and res["sequences"] == []
    assert "Not run" in markdown(res)
    from rdnet.errors import ConfigError
    from rdnet.study.config import StudyConfig
    with pytest.raises(ConfigError, match="circuit_draws"):
        StudyConfig(circuit_draws=-1)


def test_the_circuit_uses_the_study_sensor(study, tmp_path):
    """With study.degrade_from the study simulates with a calibration's fitted sensor, and so
    does the circuit check (its nominal thresholds)."""
    import json
    from rdnet.study.data import simulation_configs
    params, _ = study
    assert simulation_configs(params)[0] == section(params, "sensor")
    rep = tmp_path / "report.json"
    rep.write_text(json.dumps({"fitted_config": {"sensor": {"threshold_on": 0.31, "threshold_off": 0.27},
                                                 "degrade": {"latency_us": 100.0}}}))
    fitted = load_params(None, base={**params, "study": {**params["study"], "degrade_from": str(rep)}})
    sensor, degrade = simulation_configs(fitted)
    assert (sensor.threshold_on, sensor.threshold_off, degrade.latency_us) == (0.31, 0.27, 100.0)
