"""The reliability table of benchmarks/calib_reliability.py on hand-made inputs with known answers."""
from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path

import pytest

from rdnet.errors import FormatError

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("calib_reliability", ROOT / "benchmarks" / "calib_reliability.py")
rel = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rel)


def _effect(name, confidence, missing=False, evaluated=True):
    return {"name": name, "confidence": confidence, "missing": missing,
            "evidence": "held-out ..." if evaluated else "not evaluated"}


def test_table_bins_ece_and_brier_known_values():
    # bin 0-0.5: 0.1, 0.1 (none right) -> mean 0.1, fraction 0; bin 0.5-1: 0.9, 0.9 (one right) -> 0.9, 0.5
    t = rel.reliability_table([0.1, 0.9, 0.1, 0.9], [False, True, False, False], n_bins=2)
    assert [b["count"] for b in t["bins"]] == [2, 2]
    assert [b["right"] for b in t["bins"]] == [0, 1]
    assert t["bins"][0]["mean_confidence"] == pytest.approx(0.1)
    assert t["bins"][1]["fraction_right"] == pytest.approx(0.5)
    assert t["ece"] == pytest.approx(0.5 * 0.1 + 0.5 * 0.4)
    assert t["brier"] == pytest.approx((0.01 + 0.01 + 0.01 + 0.81) / 4)
    assert (t["count"], t["right"]) == (4, 1)


def test_table_edges_empty_bins_and_perfect_calibration():
    # c = 1.0 belongs to the last bin, 0.2 to the second of five; empty bins have no mean
    t = rel.reliability_table([0.0, 0.2, 1.0, 1.0], [False, False, True, True], n_bins=5)
    assert [b["count"] for b in t["bins"]] == [1, 1, 0, 0, 2]
    assert t["bins"][2]["mean_confidence"] is None and t["bins"][2]["fraction_right"] is None
    assert t["bins"][4]["range"] == [0.8, 1.0]
    # bin 1 (0.2, wrong) is off by 0.2 with weight 1/4; the rest exact
    assert t["ece"] == pytest.approx(0.05)
    assert rel.reliability_table([], [])["ece"] is None
    with pytest.raises(ValueError):
        rel.reliability_table([1.2], [True])
    with pytest.raises(ValueError):
        rel.reliability_table([0.5, 0.5], [True])


def test_candidate_rows_truth_and_null():
    report = {"effects": [_effect("latency", 0.99, missing=True), _effect("bandwidth", 0.3),
                          _effect("leak_events", 0.0, evaluated=False)]}
    before = copy.deepcopy(report)
    rows = rel.candidate_rows(report, "latency", block="b", case="c")
    assert [(r["effect"], r["right"], r["named"], r["evaluated"]) for r in rows] == [
        ("latency", True, True, True), ("bandwidth", False, False, True), ("leak_events", False, False, False)]
    assert all(r["block"] == "b" and r["case"] == "c" for r in rows)
    # in a null case naming anything is wrong
    assert not any(r["right"] for r in rel.candidate_rows(report, None))
    assert report == before


def test_load_rows_reads_every_block(tmp_path):
    def case(folder, name, true_effect, effects):
        (folder / name).mkdir(parents=True)
        (folder / name / "report.json").write_text(json.dumps({"effects": effects}))
        return {"case": name, "true_effect": true_effect}

    top = [case(tmp_path, "lat", "latency", [_effect("latency", 0.9, True), _effect("jitter", 0.1)]),
           case(tmp_path, "null", None, [_effect("latency", 0.7, True)])]
    (tmp_path / "proof.json").write_text(json.dumps({"cases": top}))
    sub = tmp_path / "circuit"
    (sub / "proof.json").parent.mkdir()
    (sub / "proof.json").write_text(json.dumps({"cases": [case(sub, "bw", "bandwidth", [_effect("bandwidth", 0.2)])]}))
    (tmp_path / "figures").mkdir()                    # a subfolder without proof.json is no block
    rows = rel.load_rows(tmp_path)
    assert sorted({r["block"] for r in rows}) == ["circuit", "rdnet"]
    s = rel.summarise(rows, 5)
    assert (s["cases"], s["null_cases"]) == (3, 1)
    assert [(r["case"], r["effect"]) for r in s["named_wrong"]] == [("null", "latency")]
    assert [(r["case"], r["effect"]) for r in s["missed"]] == [("bw", "bandwidth")]
    assert (s["named_only"]["count"], s["named_only"]["right"]) == (2, 1)
    assert "null" in rel.markdown({"proof": "p", "overall": s, "blocks": {"rdnet": s}})
    (tmp_path / "null" / "report.json").unlink()
    with pytest.raises(FormatError):
        rel.load_rows(tmp_path)


def test_no_proof_json_is_a_format_error(tmp_path):
    with pytest.raises(FormatError):
        rel.proof_blocks(tmp_path)
