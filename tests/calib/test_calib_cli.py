"""``rdnet calibrate``: exit codes, clear errors on bad input, output files."""
import json
import subprocess
import sys

import pytest

import rdnet.cli as cli
from rdnet.events.core import Events
from rdnet.events.io import write_recording
from rdnet.events.recording import Recording

import calib_cases


@pytest.fixture(autouse=True)
def _registered(monkeypatch):
    if "calibrate" not in cli.COMMANDS:
        monkeypatch.setattr(cli, "COMMANDS", list(cli.COMMANDS) + ["calibrate"])


@pytest.fixture(scope="module")
def rec():
    return calib_cases.hot_recording()[0]


PARAMS = """
sensor: {threshold_on: 0.2, threshold_off: 0.2, log_eps: 0.01}
degrade: {shot_noise_hz: 3.0}
interpolate: {method: linear, max_upsample: 8}
calibrate: {seeds: 3, search_points: 5, refine_steps: 3, candidates: [hot_pixels]}
"""


def _params(tmp_path):
    p = tmp_path / "params.yaml"
    p.write_text(PARAMS)
    return p


def _run(capsys, *argv):
    rc = cli.main(["calibrate", *map(str, argv)])
    return rc, capsys.readouterr()


def test_cli_writes_report(rec, tmp_path, capsys):
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    out = tmp_path / "out"
    rc, cap = _run(capsys, path, "--out", out, "--params", _params(tmp_path), "--seed", 3, "--no-plots")
    assert rc == 0, cap.err
    r = json.loads((out / "report.json").read_text())
    assert r["recording"] == str(path)
    assert [e["name"] for e in r["effects"] if e["missing"]] == ["hot_pixels"]
    assert r["setup"]["seeds"] == [3000, 3001, 3002]
    assert (out / "report.md").read_text().startswith("# Sim-to-real calibration")
    assert "hot pixels" in cap.out
    assert "caveats for" not in cap.out          # nothing flagged


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork")
def test_cli_draws_its_figures_in_forked_workers_and_the_files_are_the_same(rec, tmp_path):
    """``rdnet calibrate`` in its own process, as a user runs it, draws the figures in two
    forked workers (rdnet.runtime.forked_workers); with fork switched off the same
    calibration draws them in process, one after the other: the same files, byte for byte."""
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    args = ["calibrate", str(path), "--params", str(_params(tmp_path)), "--seed", "3", "--no-progress", "--out"]
    forked = subprocess.run([sys.executable, "-m", "rdnet.cli", "-v", *args, str(tmp_path / "forked")],
                            capture_output=True, text=True, timeout=300)
    assert forked.returncode == 0, forked.stderr
    assert "figures drawn by 2 forked workers" in forked.stderr
    here = ("import sys, rdnet.runtime as r\nr.can_fork = lambda: False\nfrom rdnet.cli import main\n"
            "sys.exit(main(sys.argv[1:]))")
    serial = subprocess.run([sys.executable, "-c", here, "-v", *args, str(tmp_path / "here")],
                            capture_output=True, text=True, timeout=300)
    assert serial.returncode == 0, serial.stderr
    assert "forked workers" not in serial.stderr
    pngs = sorted(p.name for p in (tmp_path / "forked").glob("*.png"))
    assert pngs == sorted(p.name for p in (tmp_path / "here").glob("*.png"))
    assert {"mismatch_maps.png", "statistics.png", "effect_hot_pixels.png"} <= set(pngs)
    for name in pngs:
        assert (tmp_path / "forked" / name).read_bytes() == (tmp_path / "here" / name).read_bytes(), name
    assert not list(tmp_path.glob(".forked.*"))          # no staging folder left behind


def _run_edited(rec, tmp_path, capsys, monkeypatch, edit):
    """``rdnet calibrate`` on ``rec`` with the calibration's report passed through ``edit``
    (report dict -> report dict) before the CLI writes and prints it. Returns (rc, captured, out)."""
    import dataclasses

    from rdnet.calib import calibrate as mod
    real = mod.calibrate

    def edited(*a, **k):
        cal = real(*a, **k)
        return dataclasses.replace(cal, report=edit(cal.report))
    monkeypatch.setattr(mod, "calibrate", edited)
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    out = tmp_path / "out"
    rc, cap = _run(capsys, path, "--out", out, "--params", _params(tmp_path), "--no-plots")
    return rc, cap, out


def test_cli_points_to_the_caveats(rec, tmp_path, capsys, monkeypatch):
    """A named effect with a caveat is pointed out on the console (the report has the text)."""
    def flag(report):
        effects = [{**e, "caveats": ["a note"]} if e["missing"] else e for e in report["effects"]]
        return {**report, "effects": effects}
    rc, cap, out = _run_edited(rec, tmp_path, capsys, monkeypatch, flag)
    assert rc == 0, cap.err
    assert f"caveats for hot_pixels: see the section 'Caveats' of {out / 'report.md'}" in cap.out
    assert "- **hot_pixels**: a note" in (out / "report.md").read_text()


@pytest.mark.parametrize("what", ["no_frames", "no_events", "disjoint"])
def test_cli_bad_recordings_exit_2(rec, tmp_path, capsys, what):
    if what == "no_frames":
        bad = Recording(rec.width, rec.height, events=rec.events)
        msg = "no frames"
    elif what == "no_events":
        bad = Recording(rec.width, rec.height, frames=rec.frames)
        msg = "no events"
    else:
        arr = rec.events.array.copy()
        arr["t"] += 5_000_000
        bad = Recording(rec.width, rec.height, events=Events(arr, rec.width, rec.height), frames=rec.frames)
        msg = "overlap"
    path = tmp_path / f"{what}.h5"
    write_recording(path, bad)
    rc, cap = _run(capsys, path, "--out", tmp_path / "o", "--params", _params(tmp_path))
    assert rc == 2
    assert msg in cap.err and "Traceback" not in cap.err
    assert not (tmp_path / "o" / "report.json").exists()


def test_cli_unknown_set_key_and_missing_file(rec, tmp_path, capsys):
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    rc, cap = _run(capsys, path, "--out", tmp_path / "o", "--params", _params(tmp_path), "--set", "degrade.gremlins=1")
    assert rc == 2 and "degrade.gremlins" in cap.err
    rc, cap = _run(capsys, path, "--out", tmp_path / "o", "--params", _params(tmp_path), "--set", "calibrate.nope=1")
    assert rc == 2 and "calibrate.nope" in cap.err
    rc, cap = _run(capsys, path, "--out", tmp_path / "o", "--params", _params(tmp_path),
                   "--set", "calibrate.candidates=[gremlins]")
    assert rc == 2 and "calibrate.candidates" in cap.err
    rc, cap = _run(capsys, tmp_path / "missing.h5", "--out", tmp_path / "o", "--params", _params(tmp_path))
    assert rc == 2 and "missing.h5" in cap.err
    assert not (tmp_path / "o").exists()


def test_cli_events_only_raw_fails_before_decoding(tmp_path, capsys, monkeypatch):
    """A Prophesee RAW file has no frames: the one-line error comes from its header, before
    any event is decoded (decoding these 3 data bytes would fail with 'truncated' instead)."""
    from rdnet.events.io.prophesee import ProphReader

    def no_decode(self):
        raise AssertionError("decoded the events")
    monkeypatch.setattr(ProphReader, "units", no_decode)
    path = tmp_path / "night.raw"
    path.write_bytes(b"% evt 3.0\n% geometry 64x48\n% end\n" + b"\x01\x02\x03")
    rc, cap = _run(capsys, path, "--out", tmp_path / "o", "--params", _params(tmp_path))
    assert rc == 2 and "no frames" in cap.err and "night.raw" in cap.err
    assert "Traceback" not in cap.err and len(cap.err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_base_ideal_switches_every_effect_off_but_those_set():
    """``--base ideal``: each key of the effect vocabulary at its off value (ON/OFF ratio 1,
    the rest 0) unless given with --set; the shape keys stay as read."""
    from rdnet.calib.effects import EFFECTS
    from rdnet.cli.calibrate import base_degrade
    from rdnet.sim.settings import DegradeConfig

    d = DegradeConfig(shot_noise_hz=5.0, onoff_ratio=1.3, latency_us=100.0, cutoff_hz=300.0,
                      hot_pixel_on_fraction=0.8, cutoff_floor=0.05)
    assert base_degrade(d, "params", []) is d
    ideal = base_degrade(d, "ideal", ["sensor.threshold_on=0.3"])
    keys = {k for e in EFFECTS.values() for k in e.keys}
    assert len(keys) == 11 and not any(e.present(ideal) for e in EFFECTS.values())
    assert ideal.onoff_ratio == 1.0 and ideal.shot_noise_hz == 0.0 and ideal.cutoff_hz == 0.0
    assert (ideal.hot_pixel_on_fraction, ideal.cutoff_floor) == (0.8, 0.05)      # shape and tuning kept
    kept = base_degrade(d, "ideal", ["degrade.shot_noise_hz=5", " degrade.latency_us = 100"])
    assert (kept.shot_noise_hz, kept.latency_us, kept.onoff_ratio) == (5.0, 100.0, 1.0)


def test_cli_base_ideal_compares_with_the_ideal_sensor(rec, tmp_path, capsys):
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    out = tmp_path / "out"
    rc, cap = _run(capsys, path, "--out", out, "--params", _params(tmp_path), "--base", "ideal", "--no-plots")
    assert rc == 0, cap.err
    r = json.loads((out / "report.json").read_text())
    assert r["base_config"]["degrade"]["shot_noise_hz"] == 0.0        # 3.0 in the params file
    assert r["refit_caveats"] == []
    with pytest.raises(SystemExit) as e:
        _run(capsys, path, "--out", tmp_path / "o2", "--base", "best")
    assert e.value.code == 2 and "invalid choice: 'best'" in capsys.readouterr().err


def test_cli_points_to_the_refit_caveats(rec, tmp_path, capsys, monkeypatch):
    """A re-fit that ran out of its ranges is pointed out on the console, in the finding and in
    the report's caveats."""
    rc, cap, out = _run_edited(rec, tmp_path, capsys, monkeypatch,
                               lambda report: {**report, "refit_caveats": ["a refit note"]})
    assert rc == 0, cap.err
    assert "so this cannot be trusted: see the report's caveats." in cap.out
    assert f"caveats for the basic refit: see the section 'Caveats' of {out / 'report.md'}" in cap.out
    assert "- **basic refit**: a refit note" in (out / "report.md").read_text()
