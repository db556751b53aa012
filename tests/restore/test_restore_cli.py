"""rdnet restore: streamed windows, CLI round trips, bad input (exit 2, no partial output)."""
import json
import sys

import numpy as np
import pytest

from rdnet.baselines import baf_filter, stcf_filter
from rdnet.cli import main
from rdnet.events import Events, Frames, Recording
from rdnet.events.io import read_recording, write_recording
from rdnet.restore.base import GefRestorer
from rdnet.restore.settings import RestoreConfig
from rdnet.restore.stream import windows

from _streams import edge_noise_hot, prophesee_codec


def _frames(W=60, H=40, n=4):
    im = np.zeros((n, H, W), np.float32)
    im[:, :, W // 2:] = 0.8
    return Frames(im + 0.1, 5_000 + 15_000 * np.arange(n), np.full(n, 1000))


def _write(path, frames=False, events=True):
    ev, _ = edge_noise_hot(seed=2)
    rec = Recording(ev.width, ev.height, events=ev if events else None,
                    frames=_frames(ev.width, ev.height) if frames else None, sensor="SYN")
    write_recording(path, rec)
    return ev


def test_windows_tile_the_stream():
    ev, _ = edge_noise_hot(seed=4)
    chunks = (ev[i:i + 137] for i in range(0, len(ev), 137))
    got = list(windows(chunks, 4000))
    t0s = [w[0] for w in got]
    assert t0s[0] == int(ev.t[0]) and all(b[0] == a[1] for a, b in zip(got[:-1], got[1:]))
    assert all(a[1] - a[0] == 4000 for a in got)
    for t0, t1, e in got:
        assert len(e) == 0 or (e.t[0] >= t0 and e.t[-1] < t1)
    np.testing.assert_array_equal(np.concatenate([w[2].array for w in got]), ev.array)


@pytest.mark.parametrize("method,ref", [("baf", lambda e: baf_filter(e, 10_000)),
                                        ("stcf", lambda e: stcf_filter(e, 10_000, 2, 1)),
                                        ("raw", lambda e: e)])
@pytest.mark.parametrize("hot_pass", [True, False])
def test_cli_round_trip_without_frames(tmp_path, method, ref, hot_pass):
    ev = _write(tmp_path / "in.h5")
    out = tmp_path / "out.h5"
    rc = main(["restore", str(tmp_path / "in.h5"), str(out), "--method", method, "--no-progress",
               "--set", "restore.window_us=7000", "--set", "restore.chunk_events=333",
               *([] if hot_pass else ["--set", "restore.hot_pixel_factor=0"])])
    assert rc == 0
    rec = read_recording(out)
    info = json.loads(out.with_suffix(".json").read_text())
    hot = (ev.x == 7) & (ev.y == 33)     # the stream's hot pixel: 86 events, neighbours ~1
    if hot_pass and method != "raw":     # its events go before the filter runs
        assert info["hot_pixels"]["pixels"] == [[7, 33]] and info["hot_pixels"]["events_dropped"] == hot.sum()
        # its events are all ON; one pixel is too few for the Beta fit
        assert info["hot_pixels"]["polarity"] == {"on_fraction": 1.0, "hot_pixel_on_fraction": None,
                                                  "hot_pixel_polarity_concentration": None}
        want = ref(Events(ev.array[~hot], ev.width, ev.height))
    else:
        assert info["hot_pixels"] is None
        want = ref(ev)                   # small windows and chunks give the one-pass result
    np.testing.assert_array_equal(rec.events.array, want.array)
    assert rec.frames is None
    assert info["method"] == method and info["events_in"] == len(ev) and info["events_out"] == len(want)
    assert info["events_not_recorded"] == 0            # a filter only keeps recorded events
    assert info["has_frames"] is False and info["scores"]["consistency"] is None
    assert info["scores"]["esr"]["raw"] > 0
    if method != "raw":
        assert len(want) < len(ev)       # the isolated noise of the synthetic stream goes


def test_cli_with_frames_copies_frames_and_scores(tmp_path):
    ev = _write(tmp_path / "in.h5", frames=True)
    out = tmp_path / "o.h5"
    assert main(["restore", str(tmp_path / "in.h5"), str(out), "--method", "gef", "--no-progress"]) == 0
    rec, src = read_recording(out), read_recording(tmp_path / "in.h5")
    np.testing.assert_array_equal(rec.frames.images, src.frames.images)
    np.testing.assert_array_equal(rec.frames.t_us, src.frames.t_us)
    info = json.loads(out.with_suffix(".json").read_text())
    assert info["has_frames"] and set(info["scores"]["consistency"]) == {"raw", "restored"}
    kept = rec.events
    assert 0 < len(kept) < len(ev) and np.isin(kept.array, ev.array).all()   # a subset, nothing invented


@pytest.mark.parametrize("setting, filter_name", [(None, None), ("gzip", "gzip"), ("lzf", "lzf")])
def test_frames_are_copied_with_restore_frame_compression(tmp_path, setting, filter_name):
    import h5py
    _write(tmp_path / "in.h5", frames=True)
    out = tmp_path / "o.h5"
    extra = [] if setting is None else ["--set", f"restore.frame_compression={setting}"]
    assert main(["restore", str(tmp_path / "in.h5"), str(out), "--method", "baf", "--no-progress", *extra]) == 0
    with h5py.File(out) as f:
        assert f["frames/images"].compression == filter_name          # default none: stored as they are
        assert f["events/t"].compression == "gzip"                     # events: always gzip
    np.testing.assert_array_equal(read_recording(out).frames.images, read_recording(tmp_path / "in.h5").frames.images)


def test_unknown_frame_compression_is_a_config_error_naming_the_key():
    from rdnet.errors import ConfigError
    with pytest.raises(ConfigError, match="restore.frame_compression"):
        RestoreConfig(frame_compression="zstd")


def _support(ev, dt_us):
    """Brute-force reference: distinct neighbour pixels (3 x 3, self excluded) that fired
    within dt before each event (earlier in the stream)."""
    t, x, y = ev.t, ev.x.astype(int), ev.y.astype(int)
    out = np.zeros(len(ev), int)
    for i in range(len(ev)):
        j = np.arange(i)
        near = (np.abs(x[j] - x[i]) <= 1) & (np.abs(y[j] - y[i]) <= 1) & ~((x[j] == x[i]) & (y[j] == y[i]))
        near &= t[i] - t[j] <= dt_us
        out[i] = np.unique(y[j][near] * ev.width + x[j][near]).size
    return out


@pytest.mark.parametrize("method,k", [("baf", 1), ("stcf", 2)])
def test_filters_keep_edge_remove_noise_and_hot_pixel(method, k):
    from rdnet.restore.base import get_restorer
    ev, lab = edge_noise_hot(seed=5, n_noise=150)
    r = get_restorer(method, {}, has_frames=False)
    parts = [r.restore(ev.slice_time(a, a + 5000), a, a + 5000, None) for a in range(0, 65_000, 5000)]
    kept = np.isin(ev.array, np.concatenate([p.array for p in parts]))
    np.testing.assert_array_equal(kept, _support(ev, 10_000) >= k)       # the rule, across windows
    edge = (lab == 0) & (ev.x > 1)          # the first columns have no earlier neighbour
    assert kept[edge].mean() > 0.97
    isolated = (lab == 1) & (_support(ev, 10_000) == 0)
    assert isolated.sum() > 50 and not kept[isolated].any()
    # a hot pixel with silent neighbours: removed entirely away from the edge's passage
    # (x = 7 at about 7 ms, its support lasts 10 ms). With random noise around it, BAF
    # (k = 1) lets it through whenever one noise event lands next to it (14 of 67 here).
    ev, lab = edge_noise_hot(seed=5, n_noise=0)
    r = get_restorer(method, {}, has_frames=False)
    out = r.restore(ev, 0, 65_000, None)
    kept = np.isin(ev.array, out.array)
    hot = (lab == 2) & ((ev.t < 6_000) | (ev.t > 19_000))
    assert hot.sum() > 50 and not kept[hot].any()
    assert kept[(lab == 0) & (ev.x > 1)].all()          # noise-free: the edge passes unchanged


def test_gef_keeps_structure_drops_isolated_event():
    W, H = 40, 30
    im = np.full((H, W), 0.1, np.float32)
    im[:, 20:] = 0.9                                      # one vertical intensity edge at x = 20
    t = np.arange(0, 2000, 20)                            # 100 events on the edge columns ...
    x = np.where(np.arange(t.size) % 2 == 0, 19, 20)
    y = np.arange(t.size) % H
    t = np.r_[t, 1000]; x = np.r_[x, 3]; y = np.r_[y, 3]  # ... and one in the flat corner
    o = np.argsort(t, kind="stable")
    ev = Events.from_columns(t[o], x[o], y[o], np.ones(t.size, np.uint8), W, H)
    out = GefRestorer(RestoreConfig()).restore(ev, 0, 2000, im)
    assert not ((out.x == 3) & (out.y == 3)).any()
    assert ((out.x == 19) | (out.x == 20)).sum() == 100


def _assert_no_output(tmp_path, *names):
    for n in names:
        assert not (tmp_path / n).exists()
    assert not list(tmp_path.glob(".*.tmp"))


def test_recording_without_events_exits_2(tmp_path, capsys):
    _write(tmp_path / "in.h5", frames=True, events=False)
    rc = main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o.h5"), "--method", "baf", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "in.h5" in err and "events" in err
    _assert_no_output(tmp_path, "o.h5", "o.json")


def test_cuda_without_a_gpu_names_the_restore_key(tmp_path, capsys, monkeypatch):
    """No GPU (forced here): the error names restore.device (it once named train.device)."""
    import torch
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    _write(tmp_path / "in.h5")
    rc = main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o.h5"), "--no-progress",
               "--set", "restore.device=cuda"])
    err = capsys.readouterr().err
    assert rc == 2 and "'restore.device'" in err and "no CUDA device" in err and "train.device" not in err
    _assert_no_output(tmp_path, "o.h5", "o.json")


def test_neither_adding_nor_deleting_exits_2_naming_the_key(tmp_path, capsys):
    """restore.add_events and restore.delete_events both false would leave every voxel at
    its input: one line naming the key and pointing to --method raw, no output."""
    _write(tmp_path / "in.h5", frames=False)
    rc = main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o.h5"), "--no-progress",
               "--set", "restore.add_events=false", "--set", "restore.delete_events=false"])
    err = capsys.readouterr().err
    assert rc == 2 and "restore.delete_events" in err and "method: raw" in err and "Traceback" not in err
    _assert_no_output(tmp_path, "o.h5", "o.json")


def test_gef_without_frames_exits_2(tmp_path, capsys):
    _write(tmp_path / "in.h5")
    rc = main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o.h5"), "--method", "gef", "--no-progress"])
    assert rc == 2 and "frames" in capsys.readouterr().err
    _assert_no_output(tmp_path, "o.h5", "o.json")


def test_bad_arguments_exit_2_and_leave_old_output(tmp_path, capsys):
    _write(tmp_path / "in.h5")
    (tmp_path / "o.h5").write_bytes(b"old")
    for extra in (["--method", "baf", "--checkpoint", str(tmp_path / "x.pt")],
                  ["--method", "baf", "--set", "restore.window_us=0"],
                  ["--method", "baf", "--set", "restore.nope=1"]):
        rc = main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o.h5"), "--no-progress", *extra])
        assert rc == 2
    assert (tmp_path / "o.h5").read_bytes() == b"old" and not (tmp_path / "o.json").exists()
    assert main(["restore", str(tmp_path / "missing.h5"), str(tmp_path / "p.h5"), "--method", "baf"]) == 2
    assert main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "p.txt"), "--method", "baf"]) == 2
    _assert_no_output(tmp_path, "p.h5", "p.json", "p.txt")


def test_rdnet_method_without_learned_module_exits_2(tmp_path, capsys, monkeypatch):
    """An installation where the learned restorer cannot be imported: one clear line, exit 2,
    no output (None in sys.modules makes the import fail whether the module exists or not)."""
    monkeypatch.setitem(sys.modules, "rdnet.restore.learned", None)
    _write(tmp_path / "in.h5")
    rc = main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o.h5"), "--method", "rdnet", "--no-progress"])
    assert rc == 2 and "learned restorer not available" in capsys.readouterr().err
    _assert_no_output(tmp_path, "o.h5", "o.json")


@pytest.mark.parametrize("method", ["baf", "stcf"])
def test_streamed_restore_equals_loaded_restore(tmp_path, monkeypatch, method):
    """Prophesee RAW and HDF5 are read through open_events in chunks of 333 events (chunk
    boundaries fall inside the 7 ms windows): the output equals the restore of the fully
    loaded events cut into the same windows, and nothing loads the whole file."""
    import rdnet.events.io as io_pkg
    from rdnet.events.io import dispatch, load
    from rdnet.restore.base import get_restorer
    ev = _write(tmp_path / "in.h5")
    codec = prophesee_codec()
    head = f"% evt 2.0\n% format EVT2;height={ev.height};width={ev.width}\n% end\n"
    (tmp_path / "in.raw").write_bytes(codec.encode_evt2(ev.array, head))
    window_us, chunk = 7000, 333
    assert np.any((ev.t[chunk::chunk] - ev.t[0]) % window_us > 0)       # boundaries inside windows
    params = {"restore": {"window_us": window_us}}
    restorer = get_restorer(method, params, has_frames=False)
    loaded = load(tmp_path / "in.raw").events
    np.testing.assert_array_equal(loaded.array, ev.array)
    want = np.concatenate([restorer.restore(e, t0, t1, None).array
                           for t0, t1, e in windows(iter([loaded]), window_us)])

    def no_load(*a, **k):
        raise AssertionError("restore loaded the whole file")
    monkeypatch.setattr(dispatch, "load", no_load)
    monkeypatch.setattr(io_pkg, "load", no_load)
    for name in ("in.raw", "in.h5"):
        out = tmp_path / f"out_{name.replace('.', '_')}.h5"
        assert main(["restore", str(tmp_path / name), str(out), "--method", method, "--no-progress",
                     "--set", f"restore.window_us={window_us}", "--set", f"restore.chunk_events={chunk}",
                     "--set", "restore.hot_pixel_factor=0"]) == 0   # the hot-pixel pass: test_hotpixels
        np.testing.assert_array_equal(read_recording(out).events.array, want, err_msg=name)
        info = json.loads(out.with_suffix(".json").read_text())
        assert info["events_in"] == len(ev) and info["events_out"] == len(want)
        assert info["format"] == ("prophesee_raw" if name.endswith(".raw") else "hdf5")
    assert 0 < len(want) < len(ev)


def test_classical_restore_does_not_import_torch():
    import subprocess
    import sys
    # every params section is built when the CLI loads params.yaml: none may import torch
    code = ("import sys; from rdnet.restore.run import restore_recording; import rdnet.cli.restore; "
            "from rdnet.restore.base import get_restorer; get_restorer('baf', {}, has_frames=False); "
            "from rdnet.config import SECTIONS, section_class; [section_class(n) for n in SECTIONS]; "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_consistency_skipped_beyond_score_max_events(tmp_path):
    _write(tmp_path / "in.h5", frames=True)
    out = tmp_path / "o.h5"
    assert main(["restore", str(tmp_path / "in.h5"), str(out), "--method", "raw", "--no-progress",
                 "--set", "restore.score_max_events=100", "--set", "restore.window_us=5000"]) == 0
    info = json.loads(out.with_suffix(".json").read_text())
    assert info["scores"]["consistency"] is None and "not scored" in info["notes"][0]
    assert info["scores"]["esr"]["raw"] == info["scores"]["esr"]["restored"]   # raw = identity


def _edge_frames(W=60, H=40, n=4):
    """Frames of edge_noise_hot's sweeping edge (1 ms a column): bright where it has passed."""
    t = 5_000 + 15_000 * np.arange(n)
    im = np.full((n, H, W), 0.1, np.float32)
    for k, tk in enumerate(t):
        im[k, :, :tk // 1000] = 0.8
    return Frames(im, t, np.full(n, 1000))


@pytest.mark.parametrize("latency_us", [0, 2500])
def test_streamed_consistency_equals_the_whole_stream_score(tmp_path, latency_us):
    """OUT.json's event-frame consistency, scored window by window in the restore loop, is
    the whole-stream score (rdnet.deblur.consistency.compare_consistency) of raw = the stream as
    recorded (the events the latency shift keeps, at their recorded times) and restored =
    the output (at the corrected times)."""
    from rdnet.config import section
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    ev, _ = edge_noise_hot(seed=2)
    frames = _edge_frames(ev.width, ev.height)
    write_recording(tmp_path / "in.h5", Recording(ev.width, ev.height, events=ev, frames=frames, sensor="SYN"))
    out = tmp_path / "o.h5"
    assert main(["restore", str(tmp_path / "in.h5"), str(out), "--method", "baf", "--no-progress",
                 "--set", "restore.window_us=7000", "--set", f"restore.latency_us={latency_us}"]) == 0
    got = json.loads(out.with_suffix(".json").read_text())["scores"]["consistency"]
    raw = ev.select(ev.t >= latency_us)
    sensor = section({}, "sensor")
    want = compare_consistency(LogFrames.of(frames, raw, sensor.log_eps), {"raw": raw, "restored": read_recording(out).events},
                               sensor.threshold_on, sensor.threshold_off)
    assert list(got) == ["raw", "restored"] and want["raw"]["active"] > 1000
    for name in want:
        g = {k: float("nan") if v is None else v for k, v in got[name].items()}
        assert g == pytest.approx(want[name], rel=1e-9, abs=1e-12, nan_ok=True), name
    assert got["restored"]["events"] < got["raw"]["events"] == len(raw)


@pytest.mark.parametrize("method,sets", [("raw", {}), ("baf", {}), ("stcf", {"stcf_same_polarity": True}),
                                         ("gef", {}), ("gef", {"gef_mode": "filter"})])
def test_restorer_contract(method, sets):
    """Any restorer: called on consecutive windows, returns time-sorted events of the same
    sensor inside each window; the filters return a subset of their input."""
    from rdnet.restore.base import Restorer, get_restorer
    ev, _ = edge_noise_hot(seed=6)
    frame = _frames(ev.width, ev.height, 1).grey()[0]
    r = get_restorer(method, {"restore": sets}, has_frames=True)
    assert isinstance(r, Restorer)
    total = 0
    for a in range(0, 62_000, 7_000):
        w = ev.slice_time(a, a + 7_000)
        out = r.restore(w, a, a + 7_000, frame if r.needs_frames else None)
        assert (out.width, out.height) == (ev.width, ev.height)
        if len(out):
            assert out.t[0] >= a and out.t[-1] < a + 7_000 and np.all(np.diff(out.t) >= 0)
        if sets.get("gef_mode") != "filter":
            assert np.isin(out.array, w.array).all()
        total += len(out)
    assert 0 < total <= len(ev) or sets.get("gef_mode") == "filter"


def test_latency_from_a_calibration_report_is_undone_first(tmp_path, capsys):
    ev = _write(tmp_path / "in.h5")
    report = tmp_path / "report.json"
    report.write_text(json.dumps({"fitted_config": {"sensor": {"threshold_on": 0.3, "threshold_off": 0.5},
                                                    "degrade": {"latency_us": 2500.4}}}))
    out = tmp_path / "out.h5"
    assert main(["restore", str(tmp_path / "in.h5"), str(out), "--method", "raw", "--no-progress",
                 "--calibration", str(report), "--set", "restore.window_us=7000"]) == 0
    got = read_recording(out).events
    keep = ev.t >= 2500                      # events that would fall before 0 are dropped
    assert len(got) == keep.sum() and (got.t[:10] < 2500).any()
    np.testing.assert_array_equal(got.t, ev.t[keep] - 2500)
    np.testing.assert_array_equal(got.x, ev.x[keep])
    info = json.loads(out.with_suffix(".json").read_text())
    assert info["settings"]["latency_us"] == 2500.4
    assert info["settings"]["guide_threshold"] == pytest.approx(0.4)     # the fitted thresholds' mean
    # same with the key set directly, and the BAF result is the one of the shifted stream
    out2 = tmp_path / "out2.h5"
    assert main(["restore", str(tmp_path / "in.h5"), str(out2), "--method", "baf", "--no-progress",
                 "--set", "restore.latency_us=2500", "--set", "restore.hot_pixel_factor=0"]) == 0
    want = baf_filter(Events(got.array, ev.width, ev.height), 10_000)
    np.testing.assert_array_equal(read_recording(out2).events.array, want.array)
    # a report without a fitted config: one line naming the file, exit 2, nothing written
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    capsys.readouterr()
    assert main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o3.h5"), "--calibration", str(bad)]) == 2
    assert "bad.json" in capsys.readouterr().err and not (tmp_path / "o3.h5").exists()
    assert main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o3.h5"),
                 "--calibration", str(tmp_path / "none.json")]) == 2
    assert "--calibration" in capsys.readouterr().err
    # a shift longer than the recording: one line naming the key, exit 2, nothing written
    assert main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o4.h5"), "--method", "raw",
                 "--set", "restore.latency_us=1e9"]) == 2
    assert "restore.latency_us" in capsys.readouterr().err and not (tmp_path / "o4.h5").exists()
    assert info["latency_dropped"] == (~keep).sum() > 0


def test_an_output_that_adds_many_events_is_noted(tmp_path, monkeypatch, caplog):
    """More than restore.MANY_ADDED x the recorded events: a note in OUT.json and a warning."""
    from rdnet.restore import base, run
    from rdnet.events.core import concatenate

    class Doubler(base.RawRestorer):
        name = "doubler"

        def restore(self, events, t0_us, t1_us, frame):
            return concatenate([events, events], sort=True)

    _write(tmp_path / "in.h5")
    monkeypatch.setattr(run, "get_restorer", lambda *a, **k: Doubler())
    res = run.restore_recording(tmp_path / "in.h5", tmp_path / "o.h5", {}, method="raw", progress=False)
    assert res["events_out"] == 2 * res["events_in"]
    assert res["events_not_recorded"] == res["events_in"]    # each event once recorded, once added
    assert any("2.00x the recorded events" in n for n in res["notes"])
    assert "invention" in caplog.text
    monkeypatch.undo()                                  # the identity: no note
    res = run.restore_recording(tmp_path / "in.h5", tmp_path / "q.h5", {}, method="raw", progress=False)
    assert not any("recorded events" in n for n in res["notes"])
