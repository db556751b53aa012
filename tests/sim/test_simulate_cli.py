"""``rdnet simulate`` end to end on a tiny synthetic HDF5 recording."""
import json

import numpy as np
import pytest

import rdnet.cli as cli
from rdnet.events.io import read_events, read_recording, write_recording
from rdnet.events.recording import Frames, Recording
from rdnet.sim.pair import simulate
from rdnet.sim.settings import SensorConfig


@pytest.fixture(autouse=True)
def _registered(monkeypatch):
    if "simulate" not in cli.COMMANDS:
        monkeypatch.setattr(cli, "COMMANDS", cli.COMMANDS + ["simulate"])


@pytest.fixture
def tiny(tmp_path):
    n, h, w = 10, 12, 16
    t = np.arange(n, dtype=np.int64) * 2000
    x = np.arange(w)[None, None, :]
    im = 0.1 + 0.8 / (1 + np.exp(-(x - 4 - np.arange(n)[:, None, None])))
    im = np.broadcast_to(im, (n, h, w)).astype(np.float32)
    src = tmp_path / "in.h5"
    write_recording(src, Recording(w, h, frames=Frames(im, t, np.full(n, 500))))
    params = tmp_path / "params.yaml"
    params.write_text("sensor: {threshold_on: 0.2, threshold_off: 0.2, log_eps: 0.01}\n"
                      "degrade: {shot_noise_hz: 50.0, refractory_us: 100.0, jitter_us: 300.0}\n"
                      "randomize: {train_scale: [0.5, 0.9], test_scale: [1.0, 1.5]}\n"
                      "interpolate: {method: linear, max_upsample: 4}\n")
    return src, params, im, t


def test_simulate_degraded_and_ideal(tiny, tmp_path):
    src, params, im, t = tiny
    out = tmp_path / "out.h5"
    assert cli.main(["simulate", str(src), str(out), "--params", str(params), "--seed", "3",
                     "--set", "degrade.shot_noise_hz=80", "--no-interpolate", "--chunk", "3"]) == 0
    rec = read_recording(out)
    np.testing.assert_array_equal(rec.frames.images, im)
    np.testing.assert_array_equal(rec.frames.t_us, t)
    assert len(rec.events) > 0
    assert json.loads(rec.attrs["degrade_json"])["shot_noise_hz"] == 80.0
    ideal = tmp_path / "ideal.h5"
    assert cli.main(["simulate", str(src), str(ideal), "--params", str(params), "--ideal",
                     "--no-interpolate"]) == 0
    expect = simulate(im, t, SensorConfig())
    assert np.array_equal(read_events(ideal).array, expect.array)
    assert len(rec.events) != len(expect)


def test_simulate_pair_split_with_interpolation(tiny, tmp_path):
    src, params, im, t = tiny
    out = tmp_path / "pair.h5"
    assert cli.main(["simulate", str(src), str(out), "--params", str(params), "--pair",
                     "--split", "test", "--chunk", "4"]) == 0
    deg, ideal = read_events(out, "events"), read_events(out, "events_ideal")
    assert len(deg) > 0 and len(ideal) > 0
    d = json.loads(read_recording(out).attrs["degrade_json"])
    assert 50.0 <= d["shot_noise_hz"] <= 75.0


def test_unknown_set_key_exits_2_without_output(tiny, tmp_path, capsys):
    src, params, _, _ = tiny
    out = tmp_path / "bad.h5"
    assert cli.main(["simulate", str(src), str(out), "--params", str(params),
                     "--set", "degrade.bogus_hz=1"]) == 2
    assert not out.exists()
    assert "bogus_hz" in capsys.readouterr().err
    assert cli.main(["simulate", str(tmp_path / "missing.h5"), str(out), "--params", str(params)]) == 2
    assert not out.exists()
    assert not list(tmp_path.glob("bad*"))


# --- speed-ups keep the events; frames, attributes, small frames, light imports ---------------

def _pan_u8(n: int, h: int, w: int) -> np.ndarray:
    """uint8 frames of a smooth texture panning 1 px per frame."""
    x = np.arange(w + n)[None, :]
    y = np.arange(h)[:, None]
    tex = 40 + 180 * (0.5 + 0.25 * np.sin(x / 3.0) + 0.25 * np.cos(y / 4.0 + x / 7.0))
    return np.stack([tex[:, k:k + w] for k in range(n)]).astype(np.uint8)


@pytest.fixture
def pan_u8(tmp_path):
    n, h, w = 8, 36, 40
    im = _pan_u8(n, h, w)
    t = np.arange(n, dtype=np.int64) * 1000
    src = tmp_path / "pan.h5"
    write_recording(src, Recording(w, h, frames=Frames(im, t, np.zeros(n, np.int64))))
    params = tmp_path / "params.yaml"
    params.write_text("sensor: {threshold_on: 0.2, threshold_off: 0.2, log_eps: 0.01}\n"
                      "degrade: {threshold_sigma: 0.05, shot_noise_hz: 50.0, refractory_us: 100.0, jitter_us: 50.0}\n"
                      "interpolate: {method: flow, max_upsample: 4, pixel_quantile: 0.99}\n")
    return src, params, im, t


@pytest.mark.parametrize("extra", [["--set", "interpolate.max_upsample=1"], []])
def test_uint8_source_gives_the_events_of_the_float_frames(pan_u8, tmp_path, extra):
    """Frames kept as uint8 (and the reused flow) simulate exactly what the library does on
    the float32 linear frames in the same chunks (the path the CLI took before)."""
    from rdnet.config import load_params, section
    from rdnet.events.core import concatenate
    from rdnet.sim.pair import frame_chunks, stream_events
    from rdnet.sim.sensor import Sensor
    from rdnet.sim.settings import DegradeConfig

    src, params, im, t = pan_u8
    out = tmp_path / "out.h5"
    assert cli.main(["simulate", str(src), str(out), "--params", str(params), "--seed", "5",
                     "--chunk", "3", *extra]) == 0
    p = load_params(params, extra[1:])
    sensor, degrade = section(p, "sensor"), section(p, "degrade")
    assert degrade != DegradeConfig()
    lin = im.astype(np.float32) / np.float32(255.0)
    parts = [Frames(lin[i:i + 3], t[i:i + 3], np.zeros(len(t[i:i + 3]), np.int64)) for i in range(0, len(t), 3)]
    chunks = frame_chunks(parts, interpolate=section(p, "interpolate"), log_eps=sensor.log_eps, chunk=3)
    sim = Sensor(im.shape[2], im.shape[1], sensor, degrade, np.random.default_rng(5))
    expect = concatenate([evs[0] for evs in stream_events(chunks, [sim])])
    got = read_events(out)
    assert len(got) > 100
    assert np.array_equal(got.array, expect.array)


def test_frames_keep_the_source_dtype_or_are_skipped(pan_u8, tmp_path):
    src, params, im, t = pan_u8
    out = tmp_path / "out.h5"
    assert cli.main(["simulate", str(src), str(out), "--params", str(params), "--no-interpolate"]) == 0
    rec = read_recording(out)
    assert rec.frames.images.dtype == np.uint8
    np.testing.assert_array_equal(rec.frames.images, im)
    np.testing.assert_array_equal(rec.frames.t_us, t)
    import h5py
    with h5py.File(src, "r") as a, h5py.File(out, "r") as b:   # auto: copied as stored
        assert a["frames/images"].compression == "gzip"
        assert b["frames/images"].compression == "gzip"
        assert b["events/t"].compression == "lzf"
    lzf = tmp_path / "lzf.h5"
    assert cli.main(["simulate", str(src), str(lzf), "--params", str(params), "--no-interpolate",
                     "--compression", "lzf"]) == 0   # explicit: frames re-encoded
    with h5py.File(lzf, "r") as b:
        assert b["frames/images"].compression == "lzf"
    same = read_recording(lzf)
    np.testing.assert_array_equal(same.frames.images, im)
    assert np.array_equal(same.events.array, rec.events.array)
    bare = tmp_path / "bare.h5"
    assert cli.main(["simulate", str(src), str(bare), "--params", str(params), "--no-interpolate",
                     "--no-frames", "--compression", "gzip"]) == 0
    assert read_recording(bare).frames is None
    assert np.array_equal(read_events(bare).array, rec.events.array)


def test_params_source_and_effective_sections_logged_and_stored(pan_u8, tmp_path, monkeypatch, caplog):
    src, params, _, _ = pan_u8
    out = tmp_path / "out.h5"
    with caplog.at_level("INFO", logger="rdnet"):
        assert cli.main(["simulate", str(src), str(out), "--params", str(params), "--no-interpolate"]) == 0
    attrs = read_recording(out).attrs
    assert attrs["params_source"] == str(params.resolve())
    assert json.loads(attrs["degrade_json"])["shot_noise_hz"] == 50.0
    assert json.loads(attrs["sensor_json"])["threshold_on"] == 0.2
    assert json.loads(attrs["interpolate_json"]) == {"method": "none"}
    assert f"params: {params.resolve()}" in caplog.text
    assert '"shot_noise_hz": 50.0' in caplog.text
    # outside a folder with params.yaml: built-in defaults (every degradation off), said so
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    monkeypatch.chdir(empty)
    caplog.clear()
    out2 = tmp_path / "defaults.h5"
    with caplog.at_level("INFO", logger="rdnet"):
        assert cli.main(["simulate", str(src), str(out2)]) == 0
    attrs = read_recording(out2).attrs
    assert attrs["params_source"] == "built-in defaults"
    assert "params: built-in defaults" in caplog.text
    assert json.loads(attrs["degrade_json"])["shot_noise_hz"] == 0.0
    assert json.loads(attrs["interpolate_json"])["method"] == "flow"


def test_frames_too_small_for_the_flow_fall_back_to_linear(tmp_path, caplog):
    n, h, w = 6, 4, 5
    im = _pan_u8(n, h, w)
    t = np.arange(n, dtype=np.int64) * 1000
    src = tmp_path / "small.h5"
    write_recording(src, Recording(w, h, frames=Frames(im, t, np.zeros(n, np.int64))))
    outs = {}
    for method in ("flow", "linear"):
        outs[method] = tmp_path / f"{method}.h5"
        params = tmp_path / f"{method}.yaml"
        params.write_text(f"interpolate: {{method: {method}, max_upsample: 8}}\n")
        caplog.clear()
        assert cli.main(["simulate", str(src), str(outs[method]), "--params", str(params), "--ideal"]) == 0
        assert ("too small for the optical flow" in caplog.text) == (method == "flow")
    a, b = read_events(outs["flow"]), read_events(outs["linear"])
    assert len(a) > 0 and np.array_equal(a.array, b.array)


def _modules_after(code: str) -> set:
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    res = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True,
                         env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})
    assert res.returncode == 0, res.stderr
    return set(res.stdout.split())


def test_simulate_help_and_info_do_not_import_torch(pan_u8):
    src = pan_u8[0]
    code = ("import sys, contextlib, io\nfrom rdnet.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n        main(['simulate', '--help'])\n    except SystemExit:\n        pass\n"
            f"    assert main(['info', {str(src)!r}]) == 0\n"
            "print(' '.join(m for m in ('torch', 'rdnet.cli', 'rdnet.sim.interpolate') if m in sys.modules))")
    mods = _modules_after(code)
    assert "rdnet.cli" in mods          # the probe ran
    assert "torch" not in mods


def test_background_writes_keep_order_and_raise_errors(tmp_path):
    from rdnet.errors import ValidationError
    from rdnet.events.core import EVENT_DTYPE, Events
    from rdnet.events.io import H5RecordingWriter
    from rdnet.events.io.hdf5 import BackgroundWrites

    def ev(t):
        a = np.zeros(len(t), EVENT_DTYPE)
        a["t"] = t
        return Events(a, 8, 6)

    out = tmp_path / "bg.h5"
    with H5RecordingWriter(out, 8, 6) as w, BackgroundWrites(w, max_pending=2) as bg:
        for k in range(10):
            bg.append_events(ev(np.arange(3) + 10 * k))
    np.testing.assert_array_equal(read_events(out).t, (np.arange(3)[None] + 10 * np.arange(10)[:, None]).ravel())
    bad = tmp_path / "bad.h5"
    with pytest.raises(ValidationError, match="before the last"):
        with H5RecordingWriter(bad, 8, 6) as w, BackgroundWrites(w) as bg:
            bg.append_events(ev([5, 6]))
            bg.append_events(ev([1]))            # out of order: fails in the thread
    assert not bad.exists()


def test_error_while_reading_ahead_exits_2_without_output_or_thread(pan_u8, tmp_path, monkeypatch, capsys):
    """A source that fails after its first chunk (read in the prefetch thread): one-line
    error, exit 2, no output file, no thread left."""
    import threading

    import rdnet.sim.sources as sources
    from rdnet.errors import FormatError

    src, params, im, t = pan_u8
    real = sources.iter_frames

    def failing(path, **kw):
        it = real(path, **kw)
        yield next(it)
        yield next(it)
        raise FormatError(path, "frames/images", "corrupt chunk")

    monkeypatch.setattr(sources, "iter_frames", failing)
    out = tmp_path / "out.h5"
    assert cli.main(["simulate", str(src), str(out), "--params", str(params), "--chunk", "2"]) == 2
    assert "corrupt chunk" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("out*"))
    assert not [th for th in threading.enumerate() if th.name in ("rdnet-prefetch", "h5-writer")]


def test_kernels_leave_a_core_and_get_the_log_frames_of_the_statistics(pan_u8, tmp_path, monkeypatch):
    import numba

    import rdnet.sim.sensor as sensor_mod
    src, params, _, _ = pan_u8
    before = numba.get_num_threads()
    seen = []
    real_step = sensor_mod.Sensor.step

    def step(self, *a, log_frames=None, **kw):
        seen.append((numba.get_num_threads(), log_frames is not None))
        return real_step(self, *a, log_frames=log_frames, **kw)

    monkeypatch.setattr(sensor_mod.Sensor, "step", step)
    assert cli.main(["simulate", str(src), str(tmp_path / "o.h5"), "--params", str(params), "--chunk", "3"]) == 0
    # frames inserted: the sensors compute the log themselves
    assert set(seen) == {(max(1, before - 1), False)}
    assert numba.get_num_threads() == before
    seen.clear()
    assert cli.main(["simulate", str(src), str(tmp_path / "o1.h5"), "--params", str(params), "--chunk", "3",
                     "--set", "interpolate.max_upsample=1"]) == 0
    # nothing inserted: the log frames of the statistics are handed over
    assert set(seen) == {(max(1, before - 1), True)} and len(seen) == 3
