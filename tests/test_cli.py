"""``rdnet info`` and ``rdnet convert`` through ``rdnet.cli.main``."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rdnet.cli import main
from rdnet.events.io import load, read_events, save


def _run(capsys, argv):
    rc = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


def test_info_davis346_human_and_json(capsys, davis346_path):
    rc, out, _ = _run(capsys, ["info", str(davis346_path)])
    assert rc == 0
    assert "DAVIS346 (346 x 260)" in out
    assert "78,830" in out and "ON 41,257 / OFF 37,573" in out
    assert "59 (uint8 grey), exposure 500 us" in out and "25.000 Hz (period 40.0 ms)" in out
    rc, out, _ = _run(capsys, ["info", str(davis346_path), "--json"])
    s = json.loads(out)
    assert rc == 0 and s["events"] == 78_830 and s["frames"] == 59 and s["width"] == 346
    assert s["active_pixels"] == 7_772 and s["exposure_us_median"] == 500.0


def test_info_text_needs_or_infers_size(capsys, ecd_path):
    rc, out, _ = _run(capsys, ["info", str(ecd_path), "--width", "240", "--height", "180", "--json"])
    s = json.loads(out)
    assert rc == 0 and (s["width"], s["height"]) == (240, 180) and s["events"] == 34_634
    assert s["on_events"] == 13_821 and s["frames"] == 0
    rc, out, _ = _run(capsys, ["info", str(ecd_path), "--width", "240"])
    assert rc == 2


def test_info_shows_extra_event_groups(capsys, tmp_path, make_recording, events_factory, rng):
    path = tmp_path / "seq.h5"
    save(path, make_recording(100, 2), extra_events={"events_ideal": events_factory(rng, 77, 64, 48)})
    rc, out, _ = _run(capsys, ["info", str(path)])
    assert rc == 0 and "/events_ideal" in out and "77 events" in out
    rc, out, _ = _run(capsys, ["info", str(path), "--json"])
    assert json.loads(out)["extra_event_groups"] == {"events_ideal": 77}


@pytest.mark.parametrize("name", ["missing.h5", "bad.h5", "x.mp4", "bad.aedat4", "bad.txt", "bad.raw", "bad.dat",
                                  "bad.npy"])
def test_info_bad_input_exits_2_with_one_line(capsys, tmp_path, name):
    if name != "missing.h5":
        (tmp_path / name).write_bytes(b"\x00garbage\x01" * 10)
    rc, out, err = _run(capsys, ["info", str(tmp_path / name)])
    assert rc == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rdnet info: error: ") and name in lines[0]


def test_convert_between_formats(capsys, tmp_path, davis346_path):
    h5 = tmp_path / "d.h5"
    rc, out, _ = _run(capsys, ["convert", str(davis346_path), str(h5)])
    assert rc == 0 and "78,830 events, 59 frames" in out
    npz = tmp_path / "d.npz"
    assert _run(capsys, ["convert", str(h5), str(npz)])[0] == 0
    (tmp_path / "txt").mkdir()
    txt = tmp_path / "txt" / "events.txt"
    assert _run(capsys, ["convert", str(npz), str(txt)])[0] == 0
    ref = load(davis346_path)
    for p in (h5, npz, txt):
        back = load(p)
        np.testing.assert_array_equal(back.events.array, ref.events.array)
        np.testing.assert_array_equal(back.frames.images, ref.frames.images)


def test_convert_text_with_size_and_keep_extra_groups(capsys, tmp_path, ecd_path, events_factory, rng):
    out = tmp_path / "ecd.h5"
    rc, _, _ = _run(capsys, ["convert", str(ecd_path), str(out), "--width", "240", "--height", "180"])
    assert rc == 0 and (load(out).width, load(out).height) == (240, 180)
    ideal = events_factory(rng, 50, 240, 180)
    save(tmp_path / "two.h5", load(out), extra_events={"events_ideal": ideal})
    assert _run(capsys, ["convert", str(tmp_path / "two.h5"), str(tmp_path / "copy.h5")])[0] == 0
    np.testing.assert_array_equal(read_events(tmp_path / "copy.h5", "events_ideal").array, ideal.array)


@pytest.mark.parametrize("out_name", ["o.h5", "o.npz", "o.aedat4", "o.xyz", "o.npy", "o.raw"])
def test_failing_convert_leaves_no_output(capsys, tmp_path, out_name):
    bad = tmp_path / "in.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 100)
    rc, out, err = _run(capsys, ["convert", str(bad), str(tmp_path / out_name)])
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.h5"]


def test_convert_into_missing_folder(capsys, tmp_path, davis346_path):
    rc, out, err = _run(capsys, ["convert", str(davis346_path), str(tmp_path / "no" / "such" / "o.h5")])
    assert rc == 2 and "does not exist" in err and not (tmp_path / "no").exists()


def test_convert_onto_itself_is_refused(capsys, tmp_path, make_recording):
    path = tmp_path / "r.h5"
    save(path, make_recording(10))
    rc, _, err = _run(capsys, ["convert", str(path), str(path)])
    assert rc == 2 and "output is the input" in err


# --- Prophesee RAW / DAT and .npy -----------------------------------------------------------------
def test_info_prophesee_raw(capsys, night_path, sparklers_path):
    rc, out, _ = _run(capsys, ["info", str(night_path), "--json"])
    s = json.loads(out)
    assert rc == 0 and (s["width"], s["height"], s["events"], s["frames"]) == (1280, 720, 1_218_618, 0)
    assert round(s["on_fraction"], 2) == 0.45 and round(s["duration_s"], 2) == 10.77
    ev = load(night_path).events
    assert s["on_events"] == int(ev.p.sum()) and s["active_pixels"] == int(np.count_nonzero(ev.count_per_pixel()))
    assert s["x_range"] == [int(ev.x.min()), int(ev.x.max())] and s["event_t_range_us"] == [int(ev.t[0]), int(ev.t[-1])]
    rc, out, _ = _run(capsys, ["info", str(sparklers_path)])
    assert rc == 0 and "(640 x 480)" in out and "521,252" in out


def test_info_streams_the_same_summary_as_a_whole_load(capsys, tmp_path, make_recording, monkeypatch):
    from rdnet.cli import info
    rec = make_recording(5000, 3)
    path = tmp_path / "r.h5"
    save(path, rec)
    calls = []
    chunks = info.stream_summary

    def small_chunks(stream, max_events=1_000_000, progress=False):
        calls.append(1)
        return chunks(stream, 700, progress)
    monkeypatch.setattr(info, "stream_summary", small_chunks)
    rc, out, _ = _run(capsys, ["info", str(path), "--json"])
    s = json.loads(out)
    del s["file"]
    expected = {k: (None if isinstance(v, float) and np.isnan(v) else v) for k, v in load(path).summary().items()}
    assert rc == 0 and calls and s == expected


def test_convert_prophesee_to_npy_and_h5(capsys, tmp_path, night_path):
    ref = load(night_path).events
    npy, h5 = tmp_path / "n.npy", tmp_path / "n.h5"
    rc, out, _ = _run(capsys, ["convert", str(night_path), str(npy)])
    assert rc == 0 and "1,218,618 events, 0 frames, 1280 x 720" in out
    a = np.load(npy)
    assert a.dtype.names == ("x", "y", "t", "p") and a["t"].dtype == np.int64
    for k in "txyp":
        np.testing.assert_array_equal(a[k], ref.array[k])
    assert _run(capsys, ["convert", str(night_path), str(h5)])[0] == 0
    np.testing.assert_array_equal(read_events(h5).array, ref.array)
    back = tmp_path / "back.h5"
    assert _run(capsys, ["convert", str(npy), str(back), "--width", "1280", "--height", "720"])[0] == 0
    np.testing.assert_array_equal(read_events(back).array, ref.array)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["back.h5", "n.h5", "n.npy"]


@pytest.mark.parametrize("out_name", ["o.npy", "o.h5", "o.npz"])
def test_convert_corrupt_prophesee_exits_2_without_output(capsys, tmp_path, night_path, out_name):
    data = night_path.read_bytes()
    bad = tmp_path / "bad.raw"
    bad.write_bytes(data[:-1])                          # the last 16-bit word cut in half
    rc, out, err = _run(capsys, ["convert", str(bad), str(tmp_path / out_name)])
    assert rc == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "bad.raw" in err and "truncated" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.raw"]


@pytest.mark.parametrize("name", ["night_path", "dvxplorer_path"])
def test_calibrate_events_only_says_frames_are_needed(capsys, tmp_path, request, name):
    path = request.getfixturevalue(name)
    rc, out, err = _run(capsys, ["calibrate", str(path), "--out", str(tmp_path / "cal")])
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and str(path) in lines[0] and "no frames" in lines[0]
    assert not (tmp_path / "cal").exists()


def test_info_dvxplorer_aedat4_without_frames(capsys, dvxplorer_path):
    rc, out, _ = _run(capsys, ["info", str(dvxplorer_path), "--json"])
    s = json.loads(out)
    assert rc == 0 and (s["width"], s["height"], s["events"], s["frames"]) == (320, 240, 111_954, 0)
    assert round(s["on_fraction"], 3) == 0.491 and "frame_rate_hz" not in s


def test_every_long_command_takes_no_progress():
    """The commands that show a progress bar all take --no-progress (calibrate and simulate
    once did not)."""
    from rdnet.cli import build_parser
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name in ("info", "convert", "simulate", "calibrate", "restore", "deblur"):
        opts = {o: a for a in sub.choices[name]._actions for o in a.option_strings}
        assert "--no-progress" in opts and opts["--no-progress"].dest == "progress", name
        assert opts["--no-progress"].default is True, name


def _in_fresh_interpreter(setter: str, variable: str, user_value: str | None, numpy_first: bool, probe: str) -> list[str]:
    """Run ``rdnet.cli.<setter>()`` in a fresh interpreter whose environment has ``variable``
    set to ``user_value`` (or unset), after importing numpy when ``numpy_first``, then import
    numpy; returns the printed words: the setter's result, the variable's value and
    ``probe`` (a Python expression)."""
    import os
    import subprocess
    import sys

    code = ("import sys, os\n" + ("import numpy\n" if numpy_first else "")
            + "import rdnet.cli as cli\n"
            + "assert ('numpy' in sys.modules) == " + str(numpy_first) + ", 'rdnet.cli imported numpy'\n"
            + f"result = cli.{setter}()\n"
            + "import numpy\n"
            + f"print(result, os.environ.get({variable!r}), {probe})\n")
    env = {k: v for k, v in os.environ.items() if k != variable}
    if user_value is not None:
        env[variable] = user_value
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


@pytest.mark.parametrize("user_value,numpy_first,want_env,want_advice", [
    (None, False, "0", False),       # the console script's default: numpy advises no huge pages
    ("1", False, "1", True),         # the user's setting stands
    ("0", False, "0", False),
    (None, True, None, True),        # numpy already imported: nothing changes
])
def test_the_console_script_turns_numpys_huge_page_advice_off(user_value, numpy_first, want_env, want_advice):
    """``entry`` calls :func:`rdnet.cli.small_pages` before anything imports numpy: it sets
    ``NUMPY_MADVISE_HUGEPAGE=0`` unless the user set the variable, and numpy then advises no
    transparent huge pages; with numpy already imported it changes nothing (numpy reads the
    variable once). Each case in a fresh interpreter."""
    off, env_value, advice = _in_fresh_interpreter("small_pages", "NUMPY_MADVISE_HUGEPAGE", user_value, numpy_first,
                                           "numpy._core.multiarray._get_madvise_hugepage()")
    assert off == str(not want_advice) and env_value == str(want_env) and advice == str(want_advice)


@pytest.mark.parametrize("user_value,numpy_first,want_env,want_single", [
    (None, False, "1", True),        # the console script's default: one BLAS thread
    ("2", False, "2", False),        # the user's setting stands
    ("1", False, "1", True),
    (None, True, None, False),       # numpy already imported: nothing changes
])
def test_the_console_script_asks_openblas_for_one_thread(user_value, numpy_first, want_env, want_single):
    """``entry`` calls :func:`rdnet.cli.single_thread_blas` before anything imports numpy: it
    sets ``OPENBLAS_NUM_THREADS=1`` unless the user set the variable, and numpy's OpenBLAS
    then starts no thread of its own (Linux: the process has one task after importing
    numpy); with numpy already imported it changes nothing. Each case in a fresh
    interpreter."""
    single, env_value, tasks = _in_fresh_interpreter(
        "single_thread_blas", "OPENBLAS_NUM_THREADS", user_value, numpy_first,
        "len(os.listdir('/proc/self/task')) if os.path.isdir('/proc/self/task') else -1")
    assert single == str(want_single) and env_value == str(want_env)
    if want_single and tasks != "-1":
        assert tasks == "1"            # no OpenBLAS thread beside the main one


def test_the_console_script_exits_with_mains_code_and_leaves_the_garbage_to_the_os(monkeypatch):
    """``rdnet`` (``rdnet.cli:entry``) exits with :func:`main`'s code after freezing the
    garbage collector, so the interpreter's shutdown does not collect what the process is
    about to drop (0.3-0.5 s after ``rdnet calibrate``); :func:`main` itself leaves the
    collector alone."""
    import gc
    import subprocess
    import sys

    import rdnet.cli as cli
    frozen = []
    monkeypatch.setattr(cli, "main", lambda: 3)
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(True))
    with pytest.raises(SystemExit) as e:
        cli.entry()
    assert e.value.code == 3 and frozen == [True]
    r = subprocess.run([sys.executable, "-m", "rdnet.cli", "info", "no_such_file.h5"], capture_output=True, text=True)
    assert r.returncode == 2 and "no_such_file.h5" in r.stderr and "Traceback" not in r.stderr
