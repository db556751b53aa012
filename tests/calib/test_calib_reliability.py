"""The reliability table of rdnet.calib.reliability (the calibration_proof stage's metrics and
benchmarks/calib_reliability.py) on hand-made inputs with known answers."""
from __future__ import annotations

import copy
import json

import pytest

from rdnet.calib import reliability as rel
from rdnet.errors import FormatError, ValidationError


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
    with pytest.raises(ValidationError):
        rel.reliability_table([1.2], [True])
    with pytest.raises(ValidationError):
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
    assert "null" in rel.markdown({"bins": 5, "overall": s, "blocks": {"rdnet": s}}, "p")
    (tmp_path / "null" / "report.json").write_text("{not json")
    with pytest.raises(FormatError, match="report.json"):
        rel.load_rows(tmp_path)
    (tmp_path / "null" / "report.json").write_text(json.dumps({"effects": [{"confidence": 0.5}]}))
    with pytest.raises(FormatError, match="effects"):       # an effect without its name
        rel.load_rows(tmp_path)
    (tmp_path / "null" / "report.json").unlink()
    with pytest.raises(FormatError):
        rel.load_rows(tmp_path)
    (tmp_path / "proof.json").write_text(json.dumps({"cases": [{"case": "x"}]}))
    with pytest.raises(FormatError, match="cases"):
        rel.load_rows(tmp_path)


def test_no_proof_json_is_a_format_error(tmp_path):
    with pytest.raises(FormatError):
        rel.proof_blocks(tmp_path)


def _write_case(folder, name, effects):
    (folder / name).mkdir(parents=True)
    (folder / name / "report.json").write_text(json.dumps({"effects": effects}))


def test_stage_reliability_of_known_blocks(tmp_path):
    """What the calibration_proof stage computes from the blocks it ran (in-memory proof
    metrics, reports on disk): known bins, counts, fractions right and ECE."""
    a, b = tmp_path / "a", tmp_path / "b"
    # block a: a concealed latency named at 0.95 (right), jitter at 0.05 (wrong);
    #          a null case with latency named at 0.85 (wrong)
    _write_case(a, "lat", [_effect("latency", 0.95, True), _effect("jitter", 0.05)])
    _write_case(a, "null", [_effect("latency", 0.85, True), _effect("jitter", 0.15)])
    # block b: a concealed bandwidth missed at 0.25 (right answer, low confidence), latency 0.05
    _write_case(b, "bw", [_effect("bandwidth", 0.25), _effect("latency", 0.05, evaluated=False)])
    pa = {"cases": [{"case": "lat", "true_effect": "latency"}, {"case": "null", "true_effect": None}]}
    pb = {"cases": [{"case": "bw", "true_effect": "bandwidth"}]}
    rows = rel.block_rows(a, pa, "a") + rel.block_rows(b, pb, "b")
    result = rel.reliability(rows, n_bins=2)
    t = result["overall"]["all_candidates"]
    # bin [0, 0.5): 0.05, 0.15, 0.25 (right), 0.05 -> mean 0.125, fraction 0.25
    # bin [0.5, 1]: 0.95 (right), 0.85 -> mean 0.9, fraction 0.5
    assert [(x["count"], x["right"]) for x in t["bins"]] == [(4, 1), (2, 1)]
    assert t["bins"][0]["mean_confidence"] == pytest.approx(0.125)
    assert t["bins"][1]["fraction_right"] == pytest.approx(0.5)
    assert t["ece"] == pytest.approx(4 / 6 * 0.125 + 2 / 6 * 0.4)
    named = result["overall"]["named_only"]
    assert (named["count"], named["right"]) == (2, 1) and named["ece"] == pytest.approx(0.4)
    assert list(result["blocks"]) == ["a", "b"]
    # block b alone: 0.25 (right) and 0.05 share bin 0 -> mean 0.15, fraction 0.5
    assert result["blocks"]["b"]["all_candidates"]["ece"] == pytest.approx(0.35)
    m = rel.compact(result)
    assert m["all_candidates"] == t and (m["named_wrong"], m["missed"]) == (1, 1)
    assert m["blocks"]["a"] == {"cases": 2, "candidates": 4, "ece": result["blocks"]["a"]["all_candidates"]["ece"],
                                "brier": result["blocks"]["a"]["all_candidates"]["brier"]}
    md = rel.markdown(result, "proof")
    assert "| 0.0-0.5 | 4 | 1 | 0.125 | 0.250 |" in md and "| 0.5-1.0 | 2 | 1 | 0.900 | 0.500 |" in md
    assert f"ECE {t['ece']:.3f}" in md and "a/null: latency (0.850)" in md
    # a case of the metrics without its report on disk
    with pytest.raises(FormatError):
        rel.block_rows(b, {"cases": [{"case": "gone", "true_effect": None}]}, "b")
