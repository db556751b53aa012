"""User errors of the commands that the per-command tests do not reach: a bad ``--params``
file, a bad ``--set`` value (blamed on the ``--set``, not on the file), a negative
``--seed``, out-of-range sizes and latencies, and outputs that clash with what is on disk
(one line, exit 2, nothing half-written, found before the work where the names are known)."""
from __future__ import annotations

import json

import pytest

from rdnet.cli import main
from rdnet.config import load_params, parse_set
from rdnet.errors import ConfigError, FormatError


def _run(capsys, argv):
    rc = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("rdnet ")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("command", [["simulate", "frames", "out.h5"], ["calibrate", "rec.h5", "--out", "o"]])
def test_negative_seed_is_refused_by_the_parser(capsys, command):
    with pytest.raises(SystemExit) as e:
        main(command + ["--seed", "-1"])
    assert e.value.code == 2
    assert "argument --seed: must be >= 0, got -1" in capsys.readouterr().err


def test_params_file_that_is_not_text_or_not_yaml(capsys, tmp_path, make_recording):
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=200))
    binary = tmp_path / "p.yaml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    rc, _, err = _run(capsys, ["restore", str(tmp_path / "rec.h5"), str(tmp_path / "o.h5"), "--method", "baf",
                               "--params", str(binary), "--no-progress"])
    assert rc == 2 and "p.yaml: parameter 'params': not a YAML text file (byte 0 is not UTF-8)" in _one_line(err)
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\nb: 3\n")
    rc, _, err = _run(capsys, ["restore", str(tmp_path / "rec.h5"), str(tmp_path / "o.h5"), "--method", "baf",
                               "--params", str(bad), "--no-progress"])
    assert rc == 2 and "bad.yaml: parameter 'params': invalid YAML: " in _one_line(err) and "(line 2, column 2)" in err
    assert not list(tmp_path.glob("o.*"))


def test_a_bad_set_value_is_blamed_on_the_set(tmp_path):
    p = tmp_path / "params.yaml"
    p.write_text("restore: {window_us: 20000}\n")
    with pytest.raises(ConfigError) as e:
        load_params(p, ["restore.window_us=0"])
    assert str(e.value) == "--set restore.window_us=0: parameter 'restore.window_us': must be > 0, got 0"
    p.write_text("restore: {window_us: 0}\n")                      # the file's own value: the file
    with pytest.raises(ConfigError, match=r"params\.yaml: parameter 'restore\.window_us'"):
        load_params(p, ["restore.method=baf"])


def test_set_reads_exponent_numbers_yaml_reads_as_strings():
    assert parse_set("restore.latency_us=1e3") == (["restore", "latency_us"], 1000.0)
    assert parse_set("a.b=-2.5E-1") == (["a", "b"], -0.25)
    assert parse_set("a.b=2.5e3") == (["a", "b"], 2500.0)
    assert parse_set("a.b=1e3x") == (["a", "b"], "1e3x")
    assert parse_set("a.b=inf") == (["a", "b"], "inf")              # not a number the params take


def test_latency_is_bounded_on_the_command_line_and_in_a_calibration(capsys, tmp_path, make_recording):
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=200))
    base = ["restore", str(tmp_path / "rec.h5"), str(tmp_path / "o.h5"), "--method", "baf", "--no-progress"]
    rc, _, err = _run(capsys, base + ["--set", "restore.latency_us=1.0e+30"])
    assert rc == 2 and "--set restore.latency_us=1.0e+30: parameter 'restore.latency_us': must be at most" in err
    report = tmp_path / "cal.json"
    report.write_text(json.dumps({"fitted_config": {"sensor": {}, "degrade": {"latency_us": 1e30}}}))
    rc, _, err = _run(capsys, base + ["--calibration", str(report)])
    assert rc == 2 and "cal.json (its fitted latency_us, --calibration)" in _one_line(err)
    report.write_text(json.dumps({"fitted_config": {"sensor": {}, "degrade": {"latency_us": "abc"}}}))
    rc, _, err = _run(capsys, base + ["--calibration", str(report)])
    assert rc == 2 and "cal.json: parameter 'fitted_config.degrade.latency_us': expected a number" in _one_line(err)
    assert not list(tmp_path.glob("o.*"))


def test_sensor_size_option_is_bounded(capsys, tmp_path):
    (tmp_path / "ev.txt").write_text("0.1 1 1 1\n")
    rc, _, err = _run(capsys, ["info", str(tmp_path / "ev.txt"), "--width", "60000", "--height", "60000"])
    assert rc == 2 and "at most 8192 pixels a side" in _one_line(err)


def test_restore_output_json_that_is_a_folder(capsys, tmp_path, make_recording):
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=200))
    (tmp_path / "o.json").mkdir()
    rc, _, err = _run(capsys, ["restore", str(tmp_path / "rec.h5"), str(tmp_path / "o.h5"), "--method", "baf",
                               "--no-progress"])
    assert rc == 2 and "o.json: exists and is a folder" in _one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.json", "rec.h5"]


def test_calibrate_and_train_check_their_output_folder_before_the_work(capsys, tmp_path, make_recording):
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=200, n_frames=4))
    (tmp_path / "rep" / "report.md").mkdir(parents=True)
    rc, _, err = _run(capsys, ["calibrate", str(tmp_path / "rec.h5"), "--out", str(tmp_path / "rep"),
                               "--no-plots", "--no-progress"])
    assert rc == 2 and "report.md: exists and is a folder" in _one_line(err)
    assert [p.name for p in (tmp_path / "rep").iterdir()] == ["report.md"]
    rc, _, err = _run(capsys, ["train", "--task", "restore", "--train", str(tmp_path / "missing.h5"),
                               "--out", str(tmp_path / "rec.h5"), "--no-progress"])
    assert rc == 2 and "rec.h5: exists and is not a folder (the output folder)" in _one_line(err)


def test_convert_to_text_with_images_txt_a_folder_leaves_nothing(capsys, tmp_path, make_recording):
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=200, n_frames=3))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "images.txt").mkdir()
    rc, _, err = _run(capsys, ["convert", str(tmp_path / "rec.h5"), str(tmp_path / "out" / "ev.txt")])
    assert rc == 2 and "images.txt: exists and is a folder" in _one_line(err)
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["images.txt"]     # no images/ folder left


def test_a_whole_section_set_to_a_non_mapping_is_refused(tmp_path):
    """``--set degrade=null`` once reset the whole section to the built-in defaults (the
    study's degradations silently off); a section takes a mapping."""
    p = tmp_path / "params.yaml"
    p.write_text("degrade: {refractory_us: 100}\n")
    for value in ("null", "~", "1"):
        with pytest.raises(ConfigError, match=r"'degrade': a whole section takes a mapping"):
            load_params(p, [f"degrade={value}"])
    assert load_params(p, ["degrade={refractory_us: 200}"])["degrade"]["refractory_us"] == 200


def test_a_set_value_python_cannot_convert_is_one_error():
    with pytest.raises(ConfigError, match=r"'restore.window_us': cannot read the value"):
        parse_set("restore.window_us=" + "9" * 5000)


@pytest.mark.parametrize("key,value", [("time_bin_us", "1.0e+30"), ("warmup_us", "1.0e+30"), ("max_lag_us", "1e12"),
                                       ("threads", "100000"), ("seeds", "1000000000")])
def test_calibrate_keys_that_overflow_or_exhaust_the_machine_are_bounded(key, value):
    with pytest.raises(ConfigError, match=rf"--set calibrate.{key}=.*'calibrate.{key}': must be at most"):
        load_params(None, [f"calibrate.{key}={value}"])


def test_convert_onto_a_symlink_loop(capsys, tmp_path, make_recording):
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=50))
    (tmp_path / "loop.h5").symlink_to("loop.h5")
    rc, _, err = _run(capsys, ["convert", str(tmp_path / "rec.h5"), str(tmp_path / "loop.h5")])
    assert rc == 2 and "loop.h5: cannot resolve the path" in _one_line(err)


def test_restore_calibration_that_is_not_a_regular_file(capsys, tmp_path, make_recording):
    """A FIFO given as --calibration once blocked forever (json read it); a folder too is
    refused before anything is read."""
    import os
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=50))
    os.mkfifo(tmp_path / "fifo.json")
    (tmp_path / "dir.json").mkdir()
    for name in ("fifo.json", "dir.json"):
        rc, _, err = _run(capsys, ["restore", str(tmp_path / "rec.h5"), str(tmp_path / "o.h5"), "--method", "baf",
                                   "--calibration", str(tmp_path / name), "--no-progress"])
        assert rc == 2 and f"{name}: not a regular file" in _one_line(err)
    assert not list(tmp_path.glob("o.*"))


def test_an_output_folder_that_is_a_file_is_named_as_such(capsys, tmp_path, make_recording):
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=50))
    (tmp_path / "f").write_text("a file")
    rc, _, err = _run(capsys, ["convert", str(tmp_path / "rec.h5"), str(tmp_path / "f" / "o.npz")])
    assert rc == 2 and "output folder" in err and "is not a folder" in _one_line(err)


@pytest.mark.parametrize("defect", ["nan", "inf", "group"])
def test_train_on_a_pairs_file_with_bad_values_or_a_group_is_refused_before_the_work(capsys, tmp_path, defect,
                                                                                     pairs_copier):
    """NaN or inf in the data once stopped training with a traceback ("non-finite loss"), and a
    dataset that is an HDF5 group with one from the layout check: now one line naming the file
    and the dataset, before any step and before the output folder is made."""
    import h5py
    import numpy as np
    from rdnet.train.synthetic import write_synthetic_pairs
    good = write_synthetic_pairs(tmp_path / "good.h5", n=4, bins=3, height=20, width=20, seed=1)
    bad = pairs_copier(good, tmp_path / "bad.h5", replace=("blurry",) if defect == "group" else ())
    if defect != "group":
        with h5py.File(bad, "r+") as f:
            f["blurry"][2, 0, 10, 7] = np.nan if defect == "nan" else np.inf
    params = tmp_path / "params.yaml"
    params.write_text("train: {iterations: 2, batch_size: 2, crop: 16, device: cpu}\n")
    rc, _, err = _run(capsys, ["train", "--task", "deblur", "--train", str(bad), "--out", str(tmp_path / "out"),
                               "--params", str(params), "--no-progress"])
    expected = ("is an HDF5 group, expected a dataset" if defect == "group"
                else "holds NaN or inf values (first at index (2, 0, 10, 7))")
    assert rc == 2 and f"{bad}: field 'blurry': {expected}" in _one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.h5", "good.h5", "params.yaml"]


def test_one_hour_bound_is_shared_and_named():
    """The microsecond durations of restore and calibrate share one bound (an hour), and the
    message names the key, the bound and the unit; values at the bound pass."""
    from rdnet.calib.settings import CalibrateConfig
    from rdnet.config import ONE_HOUR_US, at_most
    from rdnet.restore.settings import RestoreConfig
    RestoreConfig(latency_us=ONE_HOUR_US)
    CalibrateConfig(max_lag_us=ONE_HOUR_US)
    for make, key in ((lambda: RestoreConfig(latency_us=ONE_HOUR_US * 2), "restore.latency_us"),
                      (lambda: CalibrateConfig(warmup_us=ONE_HOUR_US * 2), "calibrate.warmup_us")):
        with pytest.raises(ConfigError) as e:
            make()
        assert str(e.value) == f"parameter '{key}': must be at most 3.6e+09 us (an hour), got 7.2e+09"
    with pytest.raises(ConfigError, match=r"'calibrate.threads': must be at most 256, got 257$"):
        CalibrateConfig(threads=257)
    at_most("k", 5, 5)


def test_train_refuses_events_a_task_does_not_read_and_a_pairs_file_that_is_not_a_file(capsys, tmp_path):
    """`--events undegraded` with a restore task was silently replaced by the degraded events
    (restore and rdnet always read those); a FIFO or a folder as `--train` was "not found"."""
    import os
    from rdnet.train.synthetic import write_synthetic_pairs
    good = write_synthetic_pairs(tmp_path / "good.h5", n=4, bins=3, height=20, width=20, seed=1)
    params = tmp_path / "params.yaml"
    params.write_text("train: {iterations: 2, batch_size: 2, crop: 16, device: cpu}\n")
    for task in ("restore", "rdnet", "image_only"):
        rc, _, err = _run(capsys, ["train", "--task", task, "--events", "undegraded", "--train", str(good),
                                   "--out", str(tmp_path / "out"), "--params", str(params), "--no-progress"])
        assert rc == 2 and f"task '{task}' reads no choice of events" in _one_line(err)
    os.mkfifo(tmp_path / "fifo.h5")
    (tmp_path / "dir.h5").mkdir()
    for name in ("fifo.h5", "dir.h5"):
        rc, _, err = _run(capsys, ["train", "--task", "deblur", "--train", str(tmp_path / name),
                                   "--out", str(tmp_path / "out"), "--params", str(params), "--no-progress"])
        assert rc == 2 and f"{name}: not a regular file" in _one_line(err)
    rc, _, err = _run(capsys, ["train", "--task", "deblur", "--train", str(tmp_path / "nope.h5"),
                               "--out", str(tmp_path / "out"), "--params", str(params), "--no-progress"])
    assert rc == 2 and "nope.h5: pairs file not found" in _one_line(err)
    assert not (tmp_path / "out").exists()


def test_a_checkpoint_that_is_a_folder_is_not_a_regular_file(tmp_path):
    from rdnet.train.checkpoint import read_checkpoint
    (tmp_path / "model.pt").mkdir()
    with pytest.raises(FormatError, match="model.pt: not a regular file"):
        read_checkpoint(tmp_path / "model.pt")
    with pytest.raises(FormatError, match="checkpoint not found"):
        read_checkpoint(tmp_path / "other.pt")


def test_the_train_stage_refuses_events_beside_a_network(tmp_path):
    """`stages/train.py --network NAME --events ...` ignored --events (the network's events come
    from params.yaml): now exit 2 with one line."""
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, str(root / "stages" / "train.py"), "--network", "deblur_degraded",
                        "--events", "undegraded", "--out", str(tmp_path / "out"),
                        "--params", str(root / "params.yaml")],
                       capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "'--events': goes with --task; network 'deblur_degraded' reads the events of networks.deblur_degraded.events" in r.stderr
    assert not (tmp_path / "out").exists()


def test_frames_beyond_2_52_us_are_refused_before_the_simulator(capsys, tmp_path):
    """Frames at 2^53 us once crashed `simulate` (double free in a compiled kernel; the exact
    place was not located); 2^52 is the bound, epoch times (~1.8e15) pass."""
    import numpy as np
    from rdnet.events import Frames, Recording
    from rdnet.events.io import save
    from rdnet.events.recording import MAX_FRAME_TIME_US
    images = np.random.default_rng(0).random((3, 8, 8)).astype(np.float32)
    Frames(images, 1_800_000_000_000_000 + np.arange(3) * 100, 0)       # Unix time in us: fine
    with pytest.raises(Exception, match=r"beyond \+-2\^52 us"):
        Frames(images, MAX_FRAME_TIME_US + np.arange(3) * 100, 0)
    # through the CLI: a file written before the check existed (the writer validates too)
    import h5py
    save(tmp_path / "rec.h5", Recording(8, 8, frames=Frames(images, np.arange(3) * 100, 0)))
    with h5py.File(tmp_path / "rec.h5", "r+") as f:
        f["frames/t"][:] = 2 ** 53 + np.arange(3) * 100
    rc, _, err = _run(capsys, ["simulate", str(tmp_path / "rec.h5"), str(tmp_path / "out.h5"), "--no-progress"])
    assert rc == 2 and "rec.h5: field 'frames/t': timestamp" in _one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.h5"]


def test_deblur_refuses_to_write_over_its_input(capsys, tmp_path, make_recording):
    """`rdnet deblur OUT/restored.h5 OUT` replaced the recording it read and exited 0."""
    from rdnet.events.io import save
    (tmp_path / "out").mkdir()
    rec = tmp_path / "out" / "restored.h5"
    save(rec, make_recording(n_events=200, n_frames=4))
    before = rec.read_bytes()
    rc, _, err = _run(capsys, ["deblur", str(rec), str(tmp_path / "out"), "--no-progress"])
    assert rc == 2 and "restored.h5: output is the input file" in _one_line(err)
    assert rec.read_bytes() == before and sorted(p.name for p in (tmp_path / "out").iterdir()) == ["restored.h5"]


def test_infinite_settings_are_refused():
    """`--set sensor.threshold_on=.inf` (or 1e400) passed the shared range check and gave 0
    events; `restore.gef_eps=.inf` dropped every event."""
    from rdnet.config import positive
    from rdnet.restore.settings import RestoreConfig
    from rdnet.sim.settings import SensorConfig
    for make, key in ((lambda: SensorConfig(threshold_on=float("inf")), "sensor.threshold_on"),
                      (lambda: RestoreConfig(gef_eps=float("inf")), "restore.gef_eps")):
        with pytest.raises(ConfigError) as e:
            make()
        assert e.value.key == key and "must be finite" in str(e.value)
    positive("x", 1e300)                                   # large but finite: still accepted here


def test_a_huge_sensor_size_in_a_file_is_refused(capsys, tmp_path):
    """An npz whose width and height say 100000 gave an ArrayMemoryError traceback in `info`
    and `restore`; the file's size now has the same cap as --width/--height."""
    import numpy as np
    from rdnet.events.core import MAX_SENSOR_SIDE
    path = tmp_path / "big.npz"
    np.savez(path, t=np.arange(5, dtype=np.int64), x=np.zeros(5, np.int64), y=np.zeros(5, np.int64),
             p=np.ones(5, np.int64), width=100000, height=100000)
    for argv in (["info", str(path)], ["restore", str(path), str(tmp_path / "o.h5"), "--method", "baf",
                                       "--no-progress"]):
        rc, _, err = _run(capsys, argv)
        assert rc == 2 and f"at most {MAX_SENSOR_SIDE} pixels a side" in _one_line(err) and "big.npz" in _one_line(err)
    assert not list(tmp_path.glob("o.*"))


def test_a_closed_stdout_pipe_ends_quietly(tmp_path, make_recording, monkeypatch):
    """`rdnet info rec.h5 | head -1` ended with a BrokenPipeError traceback: a stdout whose
    reader went away now ends the command quietly with 141 (128 + SIGPIPE), as Unix tools do."""
    import io
    import sys
    from rdnet.events.io import save
    save(tmp_path / "rec.h5", make_recording(n_events=50))

    class Closed(io.StringIO):
        def write(self, s):
            raise BrokenPipeError(32, "Broken pipe")
    monkeypatch.setattr(sys, "stdout", Closed())
    assert main(["info", str(tmp_path / "rec.h5")]) == 141


def test_frames_only_to_npy_and_simulate_to_hdf_are_refused(capsys, tmp_path, make_recording):
    """A frames-only HDF5 converted to .npy wrote an empty file with exit 0 (.npz refused it);
    `simulate` wrote a `.hdf` file that no reader takes."""
    import dataclasses
    from rdnet.events.io import save
    rec = make_recording(n_events=50, n_frames=3)
    save(tmp_path / "frames.h5", dataclasses.replace(rec, events=None))
    rc, _, err = _run(capsys, ["convert", str(tmp_path / "frames.h5"), str(tmp_path / "o.npy")])
    assert rc == 2 and "frames.h5: field 'events': recording has no events" in _one_line(err)
    save(tmp_path / "rec.h5", rec)
    rc, _, err = _run(capsys, ["simulate", str(tmp_path / "rec.h5"), str(tmp_path / "o.hdf"), "--no-progress"])
    assert rc == 2 and "o.hdf: output must be an HDF5 recording (.h5)" in _one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames.h5", "rec.h5"]
