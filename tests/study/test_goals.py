"""Issue 11's goals table (rdnet.study.goals): measured values and statuses from small
hand-made metrics, with the issue's thresholds."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from rdnet.errors import FormatError
from rdnet.study.goals import MissingMetric, circuit_rows, goals_table, held_out_rows, real_rows

ROOT = Path(__file__).resolve().parents[2]


def _events(f1, l1, ratio):
    return {"events": {"f1": f1, "voxel_l1_all": l1, "count_ratio": ratio}}


def restoration(rdnet=(0.60, 0.30, 1.0), alone=(0.58, 0.32, 0.9), events=(0.57, 0.31, 1.1)):
    return {"rdnet": _events(*rdnet), "restore_image": _events(*alone), "restore_events": _events(*events),
            "degraded": _events(0.45, 0.50, 0.5), "baf": _events(0.46, 0.49, 0.45),
            "ednccn": _events(0.47, 0.48, 0.42)}


def _method(**kw):
    base = {"consistency_r2": None, "esr": 1.0, "events_out": 100, "regions": None}
    return {**base, **kw}


def real(davis=0.36, davis_out=90, act=0.8, bg=0.1, hot=0.0, baf_bg=0.2, baf_hot=0.0):
    return {"recordings": {
        "davis346_road": {"events": 100, "methods": {
            "raw": _method(consistency_r2=0.35, esr=2.0, events_out=100),
            "rdnet": _method(consistency_r2=davis, esr=2.5, events_out=davis_out),
            "stcf": _method(consistency_r2=0.34, esr=2.2)}},
        "dvxplorer_person": {"events": 100, "methods": {
            "raw": _method(regions={"activity": 1.0, "background": 1.0, "hot_pixels": 1.0}),
            "rdnet": _method(esr=1.3, regions={"activity": act, "background": bg, "hot_pixels": hot}),
            "baf": _method(esr=1.2, regions={"activity": 0.79, "background": baf_bg, "hot_pixels": baf_hot})}}}}


def _status(rows, start):
    """The status of the row whose goal starts with ``start``, without its note."""
    return next(s.split(" (")[0] for g, _, s in rows if g.startswith(start))


def test_every_goal_met_reads_met_with_the_measured_values():
    rows = held_out_rows(restoration()) + real_rows(real())
    assert [s.split(" (")[0] for _, _, s in rows] == ["met"] * 9
    g, m, s = rows[1]                     # the L1 row: raw 0.50, so at most 0.35
    assert "0.5000, so <= 0.3500" in g and "fine-tuned 0.3000 (-40.0 %)" in m
    assert rows[0][2] == "met (best baseline: EDnCNN-style)"
    assert "image-guided 0.360" in rows[3][1] and "90 (0.90x)" in rows[4][1]


@pytest.mark.parametrize("kwargs, start", [
    ({"rdnet": (0.46, 0.30, 1.0)}, "test F1"),            # not above EDnCNN-style's 0.47
    ({"alone": (0.58, 0.36, 0.9)}, "test all-voxel L1"),   # -28 %, not -30 %
    ({"events": (0.57, 0.31, 1.16)}, "test count ratio"),
])
def test_one_restorer_missing_a_test_goal_fails_it(kwargs, start):
    assert _status(held_out_rows(restoration(**kwargs)), start) == "**not met**"


@pytest.mark.parametrize("kwargs, start", [
    ({"davis": 0.349}, "DAVIS346: event-frame"),
    ({"davis_out": 201}, "DAVIS346: restored count"),
    ({"davis_out": 49}, "DAVIS346: restored count"),
    ({"act": 0.74}, "DVXplorer: activity"),
    ({"bg": 0.16}, "DVXplorer: background"),
    ({"hot": 0.06}, "DVXplorer: hot"),
    ({"bg": 0.14, "baf_bg": 0.14}, "DVXplorer: better than BAF"),   # as much background as BAF
    ({"hot": 0.01}, "DVXplorer: better than BAF"),                 # more hot-pixel events than BAF
])
def test_a_real_recording_goal_missed_reads_not_met(kwargs, start):
    assert _status(real_rows(real(**kwargs)), start) == "**not met**"


def test_the_circuit_generators_metrics_give_the_same_three_goals():
    """metrics/restoration_circuit.json keeps each method's event metrics under events/<method>."""
    study = restoration(alone=(0.58, 0.36, 0.9))
    circuit = {"events": {k: dict(v["events"]) for k, v in study.items()}}
    rows = circuit_rows(circuit)
    assert [m for _, m, _ in rows] == [m for _, m, _ in held_out_rows(study)]
    assert all(g.startswith("circuit generator's test events:") for g, _, _ in rows)
    assert _status(rows, "circuit generator's test events: all-voxel") == "**not met**"
    text = goals_table(study, real(), circuit)
    assert text.count("\n| ") == 12
    del circuit["events"]["restore_events"]["count_ratio"]
    with pytest.raises(MissingMetric, match="c.json: field 'events.restore_events.count_ratio'"):
        goals_table(study, real(), circuit, sources=("r.json", "s.json", "c.json"))


def test_a_recording_that_restore_real_skipped_gives_no_rows():
    r = real()
    del r["recordings"]["dvxplorer_person"]
    rows = real_rows(r)
    assert len(rows) == 2 and all(g.startswith("DAVIS346") for g, _, _ in rows)


def test_the_table_has_a_row_per_goal_and_the_esr_line():
    text = goals_table(restoration(), real())
    assert text.count("\n| ") == 9 and text.startswith("| goal | measured | status |\n|---|---|---|\n")
    assert "davis346_road 2.000 / 2.500 / 2.200 (stcf)" in text and "dvxplorer_person 1.000 / 1.300 / 1.200 (baf)" in text


def test_a_missing_metric_names_the_file_and_the_field():
    m = restoration()
    del m["restore_events"]
    with pytest.raises(MissingMetric) as e:
        goals_table(m, real(), sources=("metrics/restoration.json", "summary.json"))
    assert isinstance(e.value, FormatError)
    assert "metrics/restoration.json" in str(e.value) and "restore_events.events" in str(e.value)


def test_a_missing_score_of_a_recording_names_its_whole_path():
    r = real()
    del r["recordings"]["dvxplorer_person"]["methods"]["baf"]["regions"]["background"]
    with pytest.raises(MissingMetric, match="summary.json: field 'recordings.dvxplorer_person.methods.baf.regions"
                                            ".background'"):
        goals_table(restoration(), r, sources=("restoration.json", "summary.json"))


def test_a_missing_metrics_file_is_named(tmp_path):
    from rdnet.study.goals import goals_from_files
    good = tmp_path / "summary.json"
    good.write_text(json.dumps(real()))
    with pytest.raises(FormatError, match="restoration.json: no such file"):
        goals_from_files(tmp_path / "restoration.json", good)
    bad = tmp_path / "restoration.json"
    bad.write_text("{not json")
    with pytest.raises(FormatError, match="restoration.json: not readable JSON"):
        goals_from_files(bad, good)


def test_the_stage_exits_2_with_one_line_and_writes_nothing_on_a_bad_file(tmp_path):
    bad = tmp_path / "restoration.json"
    bad.write_text(json.dumps({"rdnet": {}}))
    good = tmp_path / "summary.json"
    good.write_text(json.dumps(real()))
    out = tmp_path / "goals.md"
    r = subprocess.run([sys.executable, str(ROOT / "stages" / "restoration_goals.py"), "--params",
                        str(ROOT / "params.yaml"), "--restoration", str(bad), "--real", str(good), "--out", str(out)],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "field 'rdnet.events'" in r.stderr
    assert not out.exists()


def test_the_frame_pair_restorer_is_scored_when_present_and_named_where_it_alone_meets_a_goal():
    m = restoration(events=(0.57, 0.31, 0.6))               # the events-only restorer misses the count ratio
    m["restore_frames"] = _events(0.55, 0.45, 1.0)          # the frame-pair one meets it, and F1, not L1
    rows = held_out_rows(m)
    assert "frame-pair 0.550" in rows[0][1] and rows[0][2] == "met (best baseline: EDnCNN-style)"
    assert rows[1][2] == "**not met** (met by fine-tuned, alone, events-only)"
    assert rows[2][2] == "**not met** (met by fine-tuned, alone, frame-pair)"
    r = real(davis=0.34)                                     # the image-guided restorer below raw's 0.35
    r["recordings"]["davis346_road"]["methods"]["rdnet_frames"] = _method(consistency_r2=0.37, events_out=130)
    rows = real_rows(r)
    assert rows[0][1] == "image-guided 0.340, frame-pair 0.370" and rows[0][2] == "**not met** (met by frame-pair)"
    assert "frame-pair 130 (1.30x)" in rows[1][1] and rows[1][2] == "met"


def test_the_frame_pair_restorer_at_the_calibrated_threshold_joins_the_davis346_goals():
    """closed_loop's summary: its frames_threshold row is scored against restore_real's raw
    consistency; the latency-corrected pair is a note; a missing value names the file."""
    def loop(c=0.351, out=96, lat=0.401):
        rows = {"frames_threshold": {"consistency_r2": c, "events_out": out},
                "frames_threshold_latency": {"consistency_r2": lat, "events_out": out},
                "latency_corrected": {"consistency_r2": 0.397, "events_out": 100}}
        return {"recording": {"guide_threshold": 0.412, "rows": rows}}
    rows = real_rows(real(), closed_loop=loop())
    assert "frame-pair (calibrated threshold 0.412) 0.351" in rows[0][1]
    assert rows[0][2] == "met (with the calibrated latency undone too, `rdnet restore --calibration`: 0.401 " \
                         "against the corrected raw stream's 0.397)"
    assert "frame-pair (calibrated threshold 0.412) 96 (0.96x)" in rows[1][1]
    assert _status(real_rows(real(), closed_loop=loop(c=0.349)), "DAVIS346: event-frame") == "**not met**"
    assert real_rows(real(), closed_loop={"recording": {"rows": {}}}) == real_rows(real())   # no such rows
    bad = loop()
    del bad["recording"]["rows"]["frames_threshold"]["events_out"]
    with pytest.raises(MissingMetric, match="loop.json: field 'recording.rows.frames_threshold.events_out'"):
        goals_table(restoration(), real(), closed_loop=bad, sources=("r.json", "s.json", None, "loop.json"))
