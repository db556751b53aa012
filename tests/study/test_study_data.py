"""The study's data steps stream sequences chunk by chunk (rdnet.study.data): the result
equals the whole-sequence computation, bit for bit."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from rdnet.config import load_params, section
from rdnet.errors import FormatError
from rdnet.events.io import read_events, read_header, read_recording, write_recording
from rdnet.sim.interpolate import upsample_all
from rdnet.sim.pair import simulate_pair
from rdnet.sim.randomize import draw_degrade
from rdnet.study import data as D

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def params():
    p = yaml.safe_load((ROOT / "params.yaml").read_text())
    p["scenes"].update(n_train=1, n_test=1, height=20, width=24, n_frames=12, n_objects=1)
    p["interpolate"].update(max_upsample=4)
    return load_params(None, base=p)


@pytest.mark.parametrize("chunk", [5, 64])          # 5: every sequence spans several chunks
def test_streamed_steps_equal_whole_sequence(params, tmp_path, monkeypatch, chunk):
    monkeypatch.setattr(D, "STREAM_FRAMES", chunk)
    D.render_scenes(params, tmp_path / "scenes")
    D.interpolate_scenes(params, tmp_path / "scenes", tmp_path / "interp")
    D.simulate_sequences(params, tmp_path / "scenes", tmp_path / "interp", tmp_path / "events")
    scene = read_recording(tmp_path / "scenes" / "test" / "seq_000.h5")
    interp = read_recording(tmp_path / "interp" / "test" / "seq_000.h5")
    cfg, sensor = section(params, "interpolate"), section(params, "sensor")
    im, t = upsample_all(scene.frames.linear(), scene.frames.t_us, cfg, sensor.log_eps, warn=False)
    assert len(t) > 2 * chunk or chunk == 64
    assert np.array_equal(interp.frames.images, im.astype(np.float32)) and np.array_equal(interp.frames.t_us, t)
    assert interp.attrs == scene.attrs

    rng = D.step_rng(params, "simulate", "test", 0)
    deg = draw_degrade(section(params, "degrade"), section(params, "randomize"), "test", rng)
    ideal, degraded = simulate_pair(interp.frames, None, sensor, deg, rng)
    out = tmp_path / "events" / "test" / "seq_000.h5"
    assert np.array_equal(read_events(out, "events_ideal").array, ideal.array)
    assert np.array_equal(read_events(out, "events").array, degraded.array)
    rec = read_recording(out)
    assert np.array_equal(rec.frames.images, scene.frames.images)        # the sharp frames, as stored
    assert read_header(out)[2] == "rdnet-sim" and "degrade_json" in rec.attrs


def test_frame_parts_chunks_and_errors(tmp_path, make_recording):
    rec = make_recording(n_events=10, n_frames=7, dtype=np.float32)     # linear frames pass as stored
    write_recording(tmp_path / "r.h5", rec)
    parts = list(D.frame_parts(tmp_path / "r.h5", chunk=3))
    assert [len(p) for p in parts] == [3, 3, 1]
    assert np.array_equal(np.concatenate([p.images for p in parts]), rec.frames.images)
    assert [len(p) for p in D.frame_parts(tmp_path / "r.h5", chunk=7)] == [7]
    write_recording(tmp_path / "e.h5", make_recording(n_events=10, n_frames=0, dtype=np.float32))
    with pytest.raises(FormatError, match="frames"):
        list(D.frame_parts(tmp_path / "e.h5"))
