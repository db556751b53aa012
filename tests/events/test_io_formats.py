"""npz, ECD text, AEDAT 4 and the suffix dispatch; summaries of the two real recordings."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from rdnet.errors import FormatError
from rdnet.events import Recording
from rdnet.events.io import (format_of, load, read_aedat4, read_npz, read_text, read_text_events, save,
                             write_npz, write_text)


# --- npz ------------------------------------------------------------------------------
@pytest.mark.parametrize("n_events,n_frames,color,dtype", [(1000, 0, False, np.uint8), (500, 3, True, np.float32),
                                                           (None, 2, False, np.uint8), (0, 2, False, np.float32)])
def test_npz_round_trip(tmp_path, make_recording, same_recording, n_events, n_frames, color, dtype):
    rec = make_recording(n_events, n_frames, color=color, dtype=dtype, attrs={"k": [1, 2]})
    path = tmp_path / "r.npz"
    write_npz(path, rec)
    back = read_npz(path)
    same_recording(rec, back)
    assert back.attrs == {"k": [1, 2]}
    assert list(tmp_path.iterdir()) == [path]


@pytest.mark.parametrize("arrays,field", [
    ({"t": np.array([0, 1]), "x": np.array([0, 1]), "y": np.array([0, 1])}, "p"),
    ({"t": np.array([0.5, 1.0]), "x": np.array([0, 1]), "y": np.array([0, 1]), "p": np.array([0, 1])}, "t"),
    ({"t": np.array([2, 1]), "x": np.array([0, 1]), "y": np.array([0, 1]), "p": np.array([0, 1])}, "t"),
    ({"t": np.array([1, 2]), "x": np.array([0, 4]), "y": np.array([0, 1]), "p": np.array([0, 1])}, "x"),
    ({"t": np.array([1, 2]), "x": np.array([0, 1]), "y": np.array([0, 1]), "p": np.array([0, 3])}, "p"),
    ({"t": np.array([1, 2]), "x": np.array([0, 1, 2]), "y": np.array([0, 1]), "p": np.array([0, 1])}, "x"),
    ({}, "t"),
])
def test_npz_bad_content(tmp_path, arrays, field):
    path = tmp_path / "bad.npz"
    np.savez(path, width=np.int64(4), height=np.int64(3), **arrays)
    with pytest.raises(FormatError) as e:
        read_npz(path)
    assert e.value.path == str(path) and e.value.field == field
    np.savez(path, height=np.int64(3), t=np.array([1]), x=np.array([0]), y=np.array([0]), p=np.array([0]))
    with pytest.raises(FormatError, match="width"):
        read_npz(path)


# --- text -----------------------------------------------------------------------------
def test_text_round_trip_with_frames(tmp_path, make_recording, same_recording):
    rec = make_recording(3000, 3, color=True, dtype=np.uint8)
    path = tmp_path / "events.txt"
    write_text(path, rec)
    back = read_text(path)                      # size from the header line
    same_recording(rec, back, sensor=False)
    assert (tmp_path / "images.txt").read_text().splitlines()[0].split()[1] == "images/frame_00000000.png"
    grey = make_recording(10, 2, dtype=np.float32)
    (tmp_path / "g").mkdir()
    write_text(tmp_path / "g" / "events.txt", grey)
    same_recording(grey, load(tmp_path / "g" / "events.txt"), sensor=False)


def test_text_reads_ecd_without_header_and_comments(tmp_path):
    p = tmp_path / "events.txt"
    p.write_text("# t x y p\n0.000000000 5 4 0\n0.000648999 1 2 1\n  0.5\t3 0 -1\n")
    ev = read_text_events(p, 6, 5)
    assert ev.t.tolist() == [0, 649, 500_000]
    assert ev.x.tolist() == [5, 1, 3] and ev.y.tolist() == [4, 2, 0] and ev.p.tolist() == [0, 1, 0]
    with pytest.raises(FormatError, match="sensor size unknown"):
        read_text(p)
    with pytest.raises(FormatError, match="events/x"):
        read_text(p, 5, 5)


def test_text_size_inference_warns(tmp_path, caplog):
    p = tmp_path / "events.txt"
    p.write_text("0.1 5 4 0\n0.2 1 2 1\n")
    with caplog.at_level(logging.WARNING):
        rec = load(p)
    assert (rec.width, rec.height) == (6, 5)
    assert any("inferred 6x5" in r.getMessage() for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        rec = load(p, sensor_size=(240, 180))
    assert (rec.width, rec.height) == (240, 180) and not caplog.records


@pytest.mark.parametrize("content,field", [
    ("0.1 5 4 0\n0.2 1 2\n", "events"),
    ("0.1 5 4 0\n0.2 1 2 1 7\n", "events"),
    ("0.1 5 4 0\n0.2 x 2 1\n", "events"),
    ("0.2 5 4 0\n0.1 1 2 1\n", "events/t"),
    ("0.1 5.5 4 0\n", "events/x"),
    ("0.1 5 4 2\n", "events/p"),
    ("0.1 5 9 1\n", "events/y"),
    ("", "events"),
    ("# only a comment\n", "events"),
])
def test_text_bad_content(tmp_path, content, field):
    p = tmp_path / "events.txt"
    p.write_text(content)
    with pytest.raises(FormatError) as e:
        read_text(p, 8, 8)
    assert e.value.path == str(p) and e.value.field == field


def test_text_bad_images(tmp_path, make_recording):
    rec = make_recording(10, 2)
    write_text(tmp_path / "events.txt", rec)
    (tmp_path / "images" / "frame_00000001.png").unlink()
    with pytest.raises(FormatError, match="frame_00000001.png"):
        read_text(tmp_path / "events.txt")


# --- dispatch -------------------------------------------------------------------------
def test_dispatch_by_suffix(tmp_path, make_recording, same_recording):
    rec = make_recording(200, 1)
    for name in ("a.h5", "a.hdf5", "a.npz", "A.NPZ"):
        save(tmp_path / name, rec)
        same_recording(load(tmp_path / name), rec)
    assert format_of("x.aedat4") == "aedat4" and format_of("x.TXT") == "text"
    with pytest.raises(FormatError, match="a.mp4"):
        save(tmp_path / "a.mp4", rec)
    with pytest.raises(FormatError, match="read-only"):
        save(tmp_path / "a.aedat4", rec)
    with pytest.raises(FormatError, match="missing.h5"):
        load(tmp_path / "missing.h5")
    (tmp_path / "x.dat").write_text("1")
    with pytest.raises(FormatError, match="x.dat"):
        load(tmp_path / "x.dat")
    with pytest.raises(FormatError, match="requested 10x10"):
        load(tmp_path / "a.h5", sensor_size=(10, 10))
    assert not any(p.name.endswith(".tmp") for p in tmp_path.iterdir())


# --- real recordings ------------------------------------------------------------------
def test_davis346_aedat4_summary(davis346_path):
    rec = read_aedat4(davis346_path)
    s = rec.summary()
    assert rec.sensor == "DAVIS346" and (rec.width, rec.height) == (346, 260)
    assert s["events"] == 78_830 and s["on_events"] == 41_257 and s["off_events"] == 37_573
    assert s["active_pixels"] == 7_772
    assert s["x_range"] == [0, 345] and s["y_range"] == [2, 259]
    t0, t1 = s["event_t_range_us"]
    assert round((t1 - t0) * 1e-6, 2) == 2.36
    fr = rec.frames
    assert len(fr) == 59 and fr.images.shape == (59, 260, 346) and fr.images.dtype == np.uint8
    assert set(fr.exposure_us.tolist()) == {500}
    period = np.diff(fr.t_us)
    assert np.median(period) == 40_000 and np.abs(period - 40_000).max() <= 1   # 40 ms (+-1 us of clock)
    assert s["frame_rate_hz"] == pytest.approx(25.0)
    assert np.all(np.diff(rec.events.t) >= 0)


def test_davis346_frames_and_events_share_the_pixel_grid(davis346_path):
    """Where the frames change most, events fire most (no flip or transpose)."""
    rec = read_aedat4(davis346_path)
    fr = rec.frames.images.astype(np.float32)
    change = np.abs(np.diff(fr, axis=0)).sum(axis=0)
    counts = rec.events.count_per_pixel().astype(np.float64)
    corr = np.corrcoef(change.ravel(), counts.ravel())[0, 1]
    flipped = np.corrcoef(change[::-1].ravel(), counts.ravel())[0, 1]
    assert corr > 0.2 and corr > 2 * abs(flipped)


def test_davis346_converts_losslessly(tmp_path, davis346_path, same_recording):
    rec = load(davis346_path)
    for name in ("d.h5", "d.npz"):
        save(tmp_path / name, rec)
        same_recording(load(tmp_path / name), rec)
    (tmp_path / "txt").mkdir()
    save(tmp_path / "txt" / "events.txt", rec)
    same_recording(load(tmp_path / "txt" / "events.txt"), rec, sensor=False)


def test_ecd_shapes_text_summary(ecd_path):
    rec = read_text(ecd_path, 240, 180, sensor="DAVIS240C")
    s = rec.summary()
    assert (s["width"], s["height"]) == (240, 180)
    assert s["events"] == 34_634 and s["on_events"] == 13_821 and s["off_events"] == 20_813
    assert round(s["duration_s"], 2) == 0.79
    assert rec.frames is None
    assert rec.events.t[0] == 0 and rec.events.t[2] == 649     # 0.000648999 s rounds to 649 us
    assert isinstance(rec, Recording)
