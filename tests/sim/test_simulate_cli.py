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
