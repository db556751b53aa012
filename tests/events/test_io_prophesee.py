"""Prophesee RAW (EVT 2.0 / 3.0) and DAT readers, the streaming interface and .npy."""
from __future__ import annotations

import numpy as np
import pytest
from prophesee_codec import encode_dat, encode_evt2, encode_evt3, known_events

from rdnet.errors import FormatError
from rdnet.events import Events
from rdnet.events.io import NPY_DTYPE, ProphReader, load, open_events, save, write_recording
from rdnet.events.io.prophesee import read_header

W, H = 320, 240
EVT2_HEAD = f"% date 2024-01-01\n% evt 2.0\n% format EVT2;height={H};width={W}\n% end\n"
EVT3_HEAD = f"% evt 3.0\n% geometry {W}x{H}\n% plugin_name hal_plugin_imx636_evk4\n"


def _same(a: np.ndarray, b: np.ndarray) -> None:
    assert len(a) == len(b)
    for k in "txyp":
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


# --- the shared real files ------------------------------------------------------------------
@pytest.mark.parametrize("name, n, size, on, duration_s", [
    ("sparklers_path", 521_252, (640, 480), 0.36, 0.0959),
    ("night_path", 1_218_618, (1280, 720), 0.45, 10.77)])
def test_shared_files_match_readme(request, name, n, size, on, duration_s):
    rec = load(request.getfixturevalue(name))
    ev = rec.events
    assert len(ev) == n and (rec.width, rec.height) == size and rec.frames is None
    assert round(ev.on_fraction, 2) == on
    assert round(ev.duration_us * 1e-6, 4 if duration_s < 1 else 2) == duration_s
    assert np.all(np.diff(ev.t) >= 0)
    assert ev.x.max() < size[0] and ev.y.max() < size[1]


def test_evt3_time_high_wrap_is_unrolled(night_path):
    """night.raw spans 11.2 .. 22.0 s of camera time: across the 2^24 us wrap of EVT 3.0."""
    ev = load(night_path).events
    assert int(ev.t[0]) < 1 << 24 < int(ev.t[-1])


def test_chunks_equal_whole_load(night_path):
    whole = load(night_path).events.array
    with ProphReader(night_path, decode_events=300_000, block_bytes=1 << 16) as r:
        parts = list(r.chunks(250_000))
    assert max(len(c) for c in parts) == 250_000 and min(len(c) for c in parts) > 0
    _same(np.concatenate([c.array for c in parts]), whole)
    with open_events(night_path) as s:
        assert (s.format, s.width, s.height, s.has_frames, s.frames()) == ("prophesee_raw", 1280, 720, False, None)
        _same(np.concatenate([c.array for c in s.chunks(400_000)]), whole)


def test_slice_time_streams_and_stops(night_path, monkeypatch):
    whole = load(night_path).events
    t0 = int(whole.t[0]) + 200_000
    with open_events(night_path) as s:
        s._reader._unit = 100_000
        seen = []
        units = s._reader.units

        def counting():
            for u in units():
                seen.append(len(u))
                yield u
        monkeypatch.setattr(s._reader, "units", counting)
        got = s.slice_time(t0, t0 + 50_000)
    _same(got.array, whole.slice_time(t0, t0 + 50_000).array)
    assert len(got) > 1000 and sum(seen) < len(whole) // 2


# --- hand-built files with known events -------------------------------------------------------
def test_evt2_round_trip_with_vendor_words_and_34_bit_wrap(tmp_path, rng):
    ev = known_events(rng, 3000, W, H, (1 << 34) - 20_000, (1 << 34) + 20_000)
    path = tmp_path / "a.raw"
    path.write_bytes(encode_evt2(ev, EVT2_HEAD))
    with ProphReader(path) as r:
        got = r.read()
    assert (got.width, got.height, r.vendor_words) == (W, H, -(-len(ev) // 50))
    _same(got.array, ev)


def test_evt3_round_trip_vectors_and_24_bit_wraps(tmp_path, rng):
    ev = known_events(rng, 4000, W, H, 1_000, 40_000_000)       # two wraps of the 24-bit time
    path = tmp_path / "a.raw"
    path.write_bytes(encode_evt3(ev, EVT3_HEAD))
    with ProphReader(path, decode_events=500, block_bytes=64) as r:
        got = r.read()
        assert r.vendor_words > 0
    _same(got.array, ev)


def test_dat_round_trip_and_32_bit_wrap(tmp_path, rng):
    ev = known_events(rng, 3000, W, H, (1 << 32) - 5_000, (1 << 32) + 5_000)
    path = tmp_path / "a.dat"
    path.write_bytes(encode_dat(ev, W, H))
    rec = load(path)
    assert (rec.width, rec.height) == (W, H)
    _same(rec.events.array, ev)
    with open_events(path) as s:
        assert s.format == "prophesee_dat"
        _same(np.concatenate([c.array for c in s.chunks(777)]), ev)


def test_events_before_the_first_time_word_are_skipped(tmp_path):
    # EVT 2.0: a CD word, then TIME_HIGH 1, then a CD word at t = 64 + 5
    words = [(1 << 28) | (3 << 11) | 4, (0x8 << 28) | 1, (5 << 22) | (7 << 11) | 9]
    path = tmp_path / "a.raw"
    path.write_bytes(EVT2_HEAD.encode() + np.array(words, "<u4").tobytes())
    with ProphReader(path) as r:
        got = r.read()
    assert (r.skipped_events, len(got), int(got.t[0]), int(got.x[0]), int(got.y[0]), int(got.p[0])) == (
        1, 1, 69, 7, 9, 0)


@pytest.mark.parametrize("head, size, expected", [
    ("% format EVT3;height=720;width=1280\n", None, ("evt3", 1280, 720)),
    ("% evt 3.0\n% geometry 640x480\n", None, ("evt3", 640, 480)),
    ("% evt 2.0\n% plugin_name hal_plugin_gen3_fx3\n", None, ("evt2", 640, 480)),
    ("% evt 2.0\n", (346, 260), ("evt2", 346, 260)),
    ("% evt 3.0\n% geometry 640x480\n", (640, 480), ("evt3", 640, 480))])
def test_header_variants(tmp_path, head, size, expected):
    path = tmp_path / "h.raw"
    path.write_bytes(head.encode() + b"\x00\x80" * 4)
    h = read_header(path, sensor_size=size)
    assert (h.encoding, h.width, h.height, h.data_offset) == (*expected, len(head))


@pytest.mark.parametrize("head, size, field", [
    ("% evt 3.0\n", None, "geometry"),                        # no size anywhere
    ("% evt 3.0\n% geometry 640x480\n", (1280, 720), "width/height"),
    ("% evt 2.1\n% geometry 640x480\n", None, "format"),       # EVT 2.1 is not supported
    ("% format EVT3;height=x;width=1\n", None, "geometry"),
    ("% geometry 640x480\n", None, "format"),                  # no encoding
    ("% evt 3.0\n% geometry 640x480", None, "header")])        # header line never ends
def test_bad_headers(tmp_path, head, size, field):
    path = tmp_path / "h.raw"
    path.write_bytes(head.encode())
    with pytest.raises(FormatError, match=field) as e:
        load(path, sensor_size=size)
    assert str(path) in str(e.value)


def test_dat_header_checks(tmp_path, rng):
    ev = known_events(rng, 10, W, H, 0, 1000)
    good = encode_dat(ev, W, H)
    i = good.index(bytes([0x0C, 8]))
    for bad, field in ((good[:i] + bytes([0x0E, 8]) + good[i + 2:], "event type"),
                       (good[:i] + bytes([0x0C, 16]) + good[i + 2:], "event size"),
                       (good.replace(b"% Version 2", b"% Version 1"), "Version")):
        path = tmp_path / "b.dat"
        path.write_bytes(bad)
        with pytest.raises(FormatError, match=field):
            load(path)


# --- other formats through open_events, and .npy ------------------------------------------------
def test_open_events_hdf5_and_memory_formats(tmp_path, make_recording, davis346_path):
    rec = make_recording(5000, 2)
    path = tmp_path / "r.h5"
    write_recording(path, rec, chunk_events=1000)
    with open_events(path) as s:
        assert (s.format, s.has_frames, len(s.frames())) == ("hdf5", True, 2)
        _same(np.concatenate([c.array for c in s.chunks(1500)]), rec.events.array)
        t0 = int(rec.events.t[1000])
        _same(s.slice_time(t0, t0 + 10_000).array, rec.events.slice_time(t0, t0 + 10_000).array)
    with open_events(davis346_path) as s:
        assert (s.format, s.width, s.height, s.has_frames) == ("aedat4", 346, 260, True)
        assert sum(len(c) for c in s.chunks(10_000)) == 78_830


def test_npy_is_tonic_layout_and_round_trips(tmp_path, make_recording):
    rec = make_recording(3000, 0)
    path = tmp_path / "e.npy"
    save(path, rec)
    a = np.load(path)
    assert a.dtype.names == ("x", "y", "t", "p") and a.dtype == NPY_DTYPE and len(a) == 3000
    back = load(path, sensor_size=(rec.width, rec.height))
    _same(back.events.array, rec.events.array)
    with pytest.raises(FormatError, match="width/height"):
        load(path)
    with pytest.raises(FormatError, match="field 'x'"):
        np.save(tmp_path / "f.npy", np.zeros(3, [("t", "<i8")]))
        load(tmp_path / "f.npy", sensor_size=(10, 10))


def test_empty_data_is_zero_events(tmp_path):
    path = tmp_path / "e.raw"
    path.write_bytes(EVT3_HEAD.encode())
    with open_events(path) as s:
        assert list(s.chunks()) == [] and len(s.slice_time(0, 10)) == 0
    assert isinstance(load(path).events, Events) and len(load(path).events) == 0


def test_out_of_order_words_are_sorted_in_a_unit_and_clamped_across_units(tmp_path):
    """EVT 2.0 events within one time-high period may come out of order: sorted within a
    decode unit (stable); one earlier than the previous unit's last event is clamped."""
    def cd(low, x, p=1):
        return (p << 28) | (low << 22) | (x << 11) | 3
    words = [(0x8 << 28) | 1, cd(10, 0), cd(5, 1), cd(7, 2), cd(7, 3), cd(2, 4), cd(9, 5)]
    path = tmp_path / "a.raw"
    path.write_bytes(EVT2_HEAD.encode() + np.array(words, "<u4").tobytes())
    with ProphReader(path) as r:
        ev = r.read()
    assert ev.t.tolist() == [66, 69, 71, 71, 73, 74] and ev.x.tolist() == [4, 1, 2, 3, 5, 0]
    with ProphReader(path, decode_events=64) as r:          # units of 64 events: all in one unit
        assert r.read().t.tolist() == ev.t.tolist()
    words = [(0x8 << 28) | 1] + [cd(10, i) for i in range(64)] + [cd(3, 70), cd(12, 71)]
    path.write_bytes(EVT2_HEAD.encode() + np.array(words, "<u4").tobytes())
    with ProphReader(path, decode_events=64) as r:
        ev = r.read()
        assert r.clamped_events == 1
    assert ev.t.tolist()[-3:] == [74, 74, 76] and ev.x.tolist()[-2:] == [70, 71]


def test_data_that_begin_with_a_percent_sign_after_a_header_without_end(tmp_path):
    """A RAW file without `% end` whose first data byte is `%` (0x25, here the low byte of a
    TIME_HIGH word) had the data read as a header line; with `% end`, as before."""
    head = f"% evt 2.0\n% geometry {W}x{H}\n"
    words = [(0x8 << 28) | 0x25, (1 << 28) | (5 << 22) | (7 << 11) | 10, (6 << 22) | (8 << 11) | 11]
    data = np.array(words, "<u4").tobytes()
    for header in (head, head + "% end\n"):
        path = tmp_path / "p.raw"
        path.write_bytes(header.encode() + data)
        assert read_header(path).data_offset == len(header)
        ev = load(path).events
        assert ev.t.tolist() == [0x25 * 64 + 5, 0x25 * 64 + 6] and ev.x.tolist() == [7, 8]
        assert ev.y.tolist() == [10, 11] and ev.p.tolist() == [1, 0]
