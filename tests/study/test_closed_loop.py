"""The closed loop (rdnet.study.closed_loop): the calibrated sensor + degradation reach the
simulation, and the comparison on a recording reports the recording itself as its raw row."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from rdnet.config import load_params
from rdnet.errors import FormatError
from rdnet.events.io import read_events, read_recording, write_recording
from rdnet.sim.pair import simulate_pair
from rdnet.sim.settings import SensorConfig
from rdnet.study import closed_loop as CL
from rdnet.study import data as D

ROOT = Path(__file__).resolve().parents[2]
PACKAGE_IMAGE = ROOT / "rdnet" / "restore" / "models" / "restore_image.pt"


@pytest.fixture(scope="module")
def params():
    p = yaml.safe_load((ROOT / "params.yaml").read_text())
    p["scenes"].update(n_train=1, n_test=1, height=20, width=24, n_frames=16, n_objects=1)
    p["interpolate"].update(max_upsample=2)
    p["study"].update(seeds=[2, 1])
    return load_params(None, base=p)


def _report(path: Path, threshold: float, latency_us: float) -> Path:
    """A calibration report holding only what the closed loop reads (fitted_config)."""
    deg = yaml.safe_load((ROOT / "params.yaml").read_text())["degrade"]
    deg = {k: (1.0 if k == "onoff_ratio" else 0.0) for k in deg}
    deg["latency_us"] = latency_us
    fitted = {"sensor": {"threshold_on": threshold, "threshold_off": threshold, "log_eps": 0.01}, "degrade": deg}
    path.write_text(json.dumps({"fitted_config": fitted}))
    return path


def test_calibrated_params_copy_and_bad_report(params, tmp_path):
    rep = _report(tmp_path / "report.json", 0.3, 1000.0)
    p = CL.calibrated_params(params, rep)
    assert p["study"]["degrade_from"] == str(rep) and params["study"]["degrade_from"] is None
    assert CL.lowest_seed(params).seeds == (1,) and CL.lowest_seed(params).parallel == 1
    (tmp_path / "bad.json").write_text(json.dumps({"fitted_config": {"sensor": {}}}))
    with pytest.raises(FormatError, match="fitted_config"):
        CL.calibrated_params(params, tmp_path / "bad.json")


@pytest.mark.parametrize("scale", [1.0, 2.0])
def test_calibrated_sensor_and_degradation_reach_the_simulation(params, tmp_path, scale):
    """Ideal events at the fitted threshold; the only fitted effect (latency 3 ms) shifts
    every degraded event by exactly scale x 3 ms, in both splits; pairs are written."""
    D.render_scenes(params, tmp_path / "scenes")
    D.interpolate_scenes(params, tmp_path / "scenes", tmp_path / "interp")
    rep = _report(tmp_path / "report.json", 0.3, 3000.0)
    out = CL.simulate_calibrated(params, rep, tmp_path / "scenes", tmp_path / "interp", tmp_path / "work",
                                 scale=scale)
    assert out["active_effects"] == ["latency_us"] and out["sensor"]["threshold_on"] == 0.3
    for split in ("train", "test"):
        path = tmp_path / "work" / "events" / split / "seq_000.h5"
        ideal, degraded = read_events(path, "events_ideal"), read_events(path, "events")
        interp = read_recording(tmp_path / "interp" / split / "seq_000.h5")
        expect, _ = simulate_pair(interp.frames, None, SensorConfig(0.3, 0.3, 0.01), None,
                                  np.random.default_rng(0))
        assert len(ideal) > 0 and np.array_equal(ideal.array, expect.array)
        assert np.array_equal(degraded.t, ideal.t + int(3000 * scale))
        assert np.array_equal(degraded.x, ideal.x) and np.array_equal(degraded.p, ideal.p)
        assert json.loads(read_recording(path).attrs["degrade_json"])["latency_us"] == 3000.0 * scale
        assert (tmp_path / "work" / "pairs" / f"{split}.h5").is_file()
    assert out["events"]["test"]["ideal_events"] == out["events"]["test"]["degraded_events"]


def test_compare_on_recording_raw_row_is_the_recording(params, tmp_path, make_recording):
    rec = make_recording(n_events=3000, n_frames=4, width=32, height=24)
    write_recording(tmp_path / "r.h5", rec)
    res = CL.compare_on_recording(params, tmp_path / "r.h5", {"generic": PACKAGE_IMAGE}, tmp_path / "out",
                                  latency_us=2500.4)
    assert set(res["rows"]) == {"raw", "latency_corrected", "generic", "generic_latency"}
    assert res["events_in"] == 3000
    shifted = read_events(tmp_path / "out" / "latency_corrected.h5")
    keep = rec.events.t >= 2500                    # events that would fall before 0 are dropped
    assert 0 < keep.sum() <= 3000
    assert np.array_equal(shifted.t, rec.events.t[keep] - 2500) and np.array_equal(shifted.x, rec.events.x[keep])
    assert res["rows"]["latency_corrected"]["method"] == "raw - 2500 us"
    assert res["rows"]["latency_corrected"]["count_ratio"] == keep.mean()      # of the 3,000 recorded
    assert res["rows"]["generic_latency"]["method"] == "rdnet-image - 2500 us"
    raw, gen = res["rows"]["raw"], res["rows"]["generic"]
    assert set(raw) == set(CL.ROW_KEYS) and raw["method"] == "raw" and raw["checkpoint"] is None
    assert raw["events_out"] == 3000 and raw["count_ratio"] == 1.0
    assert np.array_equal(read_events(tmp_path / "out" / "raw.h5").array, rec.events.array)
    assert gen["method"] == "rdnet-image" and gen["checkpoint"] == str(PACKAGE_IMAGE)
    assert gen["count_ratio"] == gen["events_out"] / 3000
    assert gen["events_out"] == len(read_events(tmp_path / "out" / "generic.h5"))
    assert raw["esr"] is not None and raw["consistency_r2"] is not None
    md = CL.summary_markdown({"recording": res})
    assert md.count("\n| raw | raw | - | 3,000 | 1.000x | 0.0 % |") == 1 and "| generic | rdnet-image |" in md
    assert raw["not_recorded"] == 0.0 and 0.0 <= gen["not_recorded"] <= 1.0
    assert "| latency_corrected | raw - 2500 us |" in md and "(2.50 ms)" in md
    assert CL.summary_figure({"recording": res}, tmp_path / "s.png").stat().st_size > 0


def test_frame_pair_restorer_runs_again_with_its_guide_at_the_fitted_threshold(params, tmp_path, make_recording):
    rec = make_recording(n_events=2000, n_frames=5, width=32, height=24)
    write_recording(tmp_path / "r.h5", rec)
    frames = ROOT / "rdnet" / "restore" / "models" / "restore_frames.pt"
    res = CL.compare_on_recording(params, tmp_path / "r.h5", {"generic": PACKAGE_IMAGE, "frames": frames},
                                  tmp_path / "out", latency_us=1000.0, guide_threshold=0.4)
    # only the frame-pair restorer has a guide threshold to set
    assert set(res["rows"]) == {"raw", "latency_corrected", "generic", "generic_latency", "frames", "frames_latency",
                                "frames_threshold", "frames_threshold_latency"}
    assert res["guide_threshold"] == 0.4
    assert res["rows"]["frames"]["method"] == "rdnet-frames"
    assert res["rows"]["frames_threshold"]["method"] == "rdnet-frames guide at 0.4"
    assert res["rows"]["frames_threshold_latency"]["method"] == "rdnet-frames guide at 0.4 - 1000 us"
    for name in ("frames", "frames_threshold", "frames_threshold_latency"):
        assert res["rows"][name]["events_out"] == len(read_events(tmp_path / "out" / f"{name}.h5"))
    md = CL.summary_markdown({"recording": res})
    assert "| frames_threshold | rdnet-frames guide at 0.4 |" in md
    assert "`frames_threshold`: at the fitted 0.4" in md
