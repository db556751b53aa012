"""HDF5 recording layout: round trips, lazy slices, incremental writer, atomicity, errors."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from rdnet.errors import FormatError, ValidationError
from rdnet.events import Events, Frames, Recording, concatenate
from rdnet.events.io import (H5EventReader, H5RecordingWriter, event_groups, load, read_events, read_frames,
                             read_recording, save, write_recording)


@pytest.mark.parametrize("n_frames,color,dtype", [(0, False, np.uint8), (4, False, np.uint8),
                                                  (3, True, np.uint8), (4, False, np.float32),
                                                  (2, True, np.float32)])
def test_round_trip(tmp_path, make_recording, same_recording, n_frames, color, dtype):
    rec = make_recording(2000, n_frames, color=color, dtype=dtype, attrs={"note": "x", "level": 0.5})
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    back = read_recording(path)
    same_recording(rec, back)
    assert back.attrs == {"note": "x", "level": 0.5}
    with h5py.File(path, "r") as f:       # the documented layout
        assert f["events/t"].dtype == np.int64 and f["events/x"].dtype == np.uint16
        assert f["events/y"].dtype == np.uint16 and f["events/p"].dtype == np.uint8
        assert f.attrs["width"] == 64 and f.attrs["height"] == 48 and f.attrs["sensor"] == "TEST64"
        assert f["events/t"].compression == "gzip" and f["events/t"].chunks is not None
        if n_frames:
            assert f["frames/images"].dtype == dtype
            assert f["frames/images"].shape == ((n_frames, 48, 64, 3) if color else (n_frames, 48, 64))
            assert f["frames/t"].dtype == np.int64 and f["frames/exposure_us"].dtype == np.int64
        else:
            assert "frames" not in f


def test_frames_only_and_extra_event_group(tmp_path, make_recording, same_recording, events_factory, rng):
    rec = make_recording(None, 3, dtype=np.float32)
    ideal = events_factory(rng, 500, 64, 48)
    path = tmp_path / "seq.hdf5"
    save(path, rec, extra_events={"events_ideal": ideal}, attrs={"degrade_json": '{"jitter_us": 3.0}'})
    back = load(path)
    same_recording(rec, back)
    assert back.events is None
    assert back.attrs["degrade_json"] == '{"jitter_us": 3.0}'
    assert event_groups(path) == ["events_ideal"]
    np.testing.assert_array_equal(read_events(path, "events_ideal").array, ideal.array)
    with pytest.raises(FormatError, match="events"):
        read_events(path)                  # no /events group


def test_lazy_slice_equals_in_memory_slice_on_multi_chunk_file(tmp_path, events_factory, rng):
    ev = events_factory(rng, 20_000, 64, 48, t0_us=10_000, span_us=2_000_000)
    path = tmp_path / "multi.h5"
    write_recording(path, Recording(64, 48, events=ev), chunk_events=1024)     # ~20 chunks
    with h5py.File(path, "r") as f:
        assert f["events/t"].chunks == (1024,)
        np.testing.assert_array_equal(f["events/index_t"][()], ev.t[::1024])
        np.testing.assert_array_equal(f["events/index_offset"][()], np.arange(0, 20_000, 1024))
    bounds = np.concatenate([rng.integers(0, 2_100_000, 40), ev.t[[0, 1023, 1024, 5000, -1]], [ev.t[-1] + 1]])
    with H5EventReader(path) as r:
        assert len(r) == 20_000
        assert r.t_range == (int(ev.t[0]), int(ev.t[-1]))
        for a, b in zip(bounds[:-1], bounds[1:]):
            np.testing.assert_array_equal(r.slice_time(a, b).array, ev.slice_time(a, b).array)
        np.testing.assert_array_equal(r.slice_time(None, None).array, ev.array)
        np.testing.assert_array_equal(concatenate(list(r.iter_chunks(3000))).array, ev.array)
    np.testing.assert_array_equal(read_events(path, t_start_us=500_000, t_end_us=600_000).array,
                                  ev.slice_time(500_000, 600_000).array)


def test_slice_without_index_uses_binary_search(tmp_path, events_factory, rng, monkeypatch):
    import rdnet.events.io.hdf5 as h5mod
    monkeypatch.setattr(h5mod, "_SEARCH_WINDOW", 64)   # force several bisection steps
    ev = events_factory(rng, 5000, 64, 48, span_us=100_000)
    path = tmp_path / "noindex.h5"
    write_recording(path, Recording(64, 48, events=ev), chunk_events=512)
    with h5py.File(path, "a") as f:       # as a third-party file without index would be
        del f["events/index_t"], f["events/index_offset"]
        del f["events"].attrs["index_stride"]
    with H5EventReader(path) as r:
        assert r._index_t is None
        for a, b in rng.integers(-10, 100_010, (30, 2)):
            np.testing.assert_array_equal(r.slice_time(a, b).array, ev.slice_time(a, b).array)


def test_incremental_writer_streams_chunks(tmp_path, events_factory, rng):
    ev = events_factory(rng, 10_000, 32, 32, span_us=1_000_000)
    path = tmp_path / "stream.h5"
    with H5RecordingWriter(path, 32, 32, sensor="SIM", chunk_events=700) as w:
        for a in range(0, 10_000, 1234):
            w.append_events(ev[a:a + 1234])
            w.append_events(ev[a:a + 617], group="events_ideal")
        w.append_events(Events.empty(32, 32), group="events_empty")
        for i in range(3):
            w.append_frames(np.full((2, 32, 32), i, np.uint8), [10 * i, 10 * i + 5], [1, 1])
        w.set_attr("degrade_json", "{}")
        assert not path.exists()           # written under a temporary name until closed
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.events.array, ev.array)
    assert rec.sensor == "SIM" and rec.attrs == {"degrade_json": "{}"}
    assert len(rec.frames) == 6 and list(rec.frames.t_us) == [0, 5, 10, 15, 20, 25]
    assert len(read_events(path, "events_empty")) == 0
    with H5EventReader(path) as r:
        np.testing.assert_array_equal(r.slice_time(250_000, 750_000).array, ev.slice_time(250_000, 750_000).array)
    assert list(tmp_path.iterdir()) == [path]
    assert read_frames(path, 2, 4).t_us.tolist() == [10, 15]


def test_writer_checks_order_and_leaves_nothing_on_error(tmp_path, events_factory, rng):
    ev = events_factory(rng, 100, 16, 16)
    path = tmp_path / "bad.h5"
    with pytest.raises(ValidationError, match="events/t"):
        with H5RecordingWriter(path, 16, 16) as w:
            w.append_events(ev[50:])
            w.append_events(ev[:50])       # goes back in time
    with pytest.raises(ValidationError, match="frames/t"):
        with H5RecordingWriter(path, 16, 16) as w:
            w.append_frames(np.zeros((1, 16, 16), np.uint8), [10], [0])
            w.append_frames(np.zeros((1, 16, 16), np.uint8), [10], [0])
    with pytest.raises(ValidationError, match="frames/images"):
        with H5RecordingWriter(path, 16, 16) as w:
            w.append_frames(np.zeros((1, 16, 16), np.uint8), [10], [0])
            w.append_frames(np.zeros((1, 16, 16), np.float32), [20], [0])
    with pytest.raises(ValidationError):
        with H5RecordingWriter(path, 16, 16) as w:
            w.append_events(events_factory(rng, 10, 17, 16))
    with pytest.raises(RuntimeError):
        with H5RecordingWriter(path, 16, 16) as w:
            w.append_events(ev)
            raise RuntimeError("simulator crashed")
    assert list(tmp_path.iterdir()) == []


def test_failed_overwrite_keeps_the_old_file(tmp_path, make_recording, same_recording):
    rec = make_recording(100)
    path = tmp_path / "keep.h5"
    write_recording(path, rec)
    with pytest.raises(FormatError, match=r"keep\.h5: field 'attrs/bad': unsupported attribute type dict"):
        write_recording(path, rec, attrs={"bad": {"nested": "dict"}})
    same_recording(read_recording(path), rec)
    assert list(tmp_path.iterdir()) == [path]


def _write_raw(path, **datasets):
    with h5py.File(path, "w") as f:
        f.attrs["width"], f.attrs["height"] = 10, 8
        for name, value in datasets.items():
            f[name] = value


GOOD = {"events/t": np.array([1, 2, 3], np.int64), "events/x": np.array([0, 1, 9], np.uint16),
        "events/y": np.array([0, 7, 1], np.uint16), "events/p": np.array([1, 0, 1], np.uint8)}


@pytest.mark.parametrize("change,field", [
    ({"events/t": np.array([1, 3, 2], np.int64)}, "events/t"),
    ({"events/t": np.array([1.0, 2.0, 3.0])}, "events/t"),
    ({"events/x": np.array([0, 1, 10], np.uint16)}, "events/x"),
    ({"events/y": np.array([0, 8, 1], np.uint16)}, "events/y"),
    ({"events/x": np.array([0, -1, 2], np.int32)}, "events/x"),
    ({"events/p": np.array([1, 2, 0], np.uint8)}, "events/p"),
    ({"events/p": None}, "events/p"),
    ({"events/y": np.array([0, 1], np.uint16)}, "events/y"),
    ({"frames/images": np.zeros((2, 8, 9), np.uint8), "frames/t": np.array([0, 1]),
      "frames/exposure_us": np.array([0, 0])}, "frames/images"),
    ({"frames/images": np.zeros((2, 8, 10), np.uint8), "frames/t": np.array([0, 1])}, "frames/exposure_us"),
    ({"frames/images": np.zeros((2, 8, 10), np.int16), "frames/t": np.array([0, 1]),
      "frames/exposure_us": np.array([0, 0])}, "frames/images"),
])
def test_bad_content_raises_format_error_naming_file_and_field(tmp_path, change, field):
    path = tmp_path / "bad.h5"
    data = {k: v for k, v in {**GOOD, **change}.items() if v is not None}
    _write_raw(path, **data)
    with pytest.raises(FormatError) as e:
        read_recording(path)
    assert e.value.path == str(path) and e.value.field == field
    assert str(path) in str(e.value)


def test_missing_attrs_groups_and_files(tmp_path):
    path = tmp_path / "noattr.h5"
    with h5py.File(path, "w") as f:
        for k, v in GOOD.items():
            f[k] = v
    with pytest.raises(FormatError, match="width"):
        read_recording(path)
    path2 = tmp_path / "empty.h5"
    with h5py.File(path2, "w") as f:
        f.attrs["width"], f.attrs["height"] = 4, 4
    with pytest.raises(FormatError, match="neither"):
        read_recording(path2)
    with pytest.raises(FormatError, match="no such file"):
        read_recording(tmp_path / "absent.h5")
    (tmp_path / "text.h5").write_text("not hdf5")
    with pytest.raises(FormatError, match="text.h5"):
        read_recording(tmp_path / "text.h5")
    with pytest.raises(FormatError, match="events_ideal"):
        H5EventReader(path2, "events_ideal")


def test_extra_attrs_round_trip_types(tmp_path, make_recording):
    rec = make_recording(10, attrs={"i": 3, "f": 0.25, "s": "txt", "b": True})
    path = tmp_path / "a.h5"
    write_recording(path, rec, attrs={"arr": np.arange(3)})
    back = read_recording(path).attrs
    assert back["i"] == 3 and back["f"] == 0.25 and back["s"] == "txt" and bool(back["b"]) is True
    np.testing.assert_array_equal(back["arr"], [0, 1, 2])


def test_lzf_and_uncompressed(tmp_path, make_recording, same_recording):
    rec = make_recording(3000, 2)
    for comp in ("lzf", None):
        path = tmp_path / f"{comp}.h5"
        write_recording(path, rec, compression=comp)
        same_recording(read_recording(path), rec)
    with pytest.raises(ValidationError):
        write_recording(tmp_path / "x.h5", rec, compression="zstd")


def test_frames_of_wrong_size_rejected_by_writer(tmp_path):
    fr = Frames(np.zeros((1, 5, 5), np.uint8), [0], [0])
    with pytest.raises(ValidationError, match="frames/images"):
        with H5RecordingWriter(tmp_path / "f.h5", 6, 5) as w:
            w.write_frames(fr)
    assert list(tmp_path.iterdir()) == []


def test_copy_frames_keeps_the_stored_chunks_and_appends_continue(tmp_path, rng):
    n, h, w = 5, 6, 7
    im = rng.integers(0, 256, (n, h, w), dtype=np.uint8)
    src = tmp_path / "src.h5"
    write_recording(src, Recording(w, h, frames=Frames(im, np.arange(n) * 10, np.full(n, 3))))
    out = tmp_path / "out.h5"
    with H5RecordingWriter(out, w, h, compression="lzf") as wr:
        assert wr.copy_frames(src) == n
        wr.append_frames(im[:2], np.array([100, 110]), np.zeros(2, np.int64))
        with pytest.raises(ValidationError, match="frames/t"):
            wr.append_frames(im[:1], np.array([105]), np.zeros(1, np.int64))
    fr = read_frames(out)
    np.testing.assert_array_equal(fr.images, np.concatenate([im, im[:2]]))
    np.testing.assert_array_equal(fr.t_us, [0, 10, 20, 30, 40, 100, 110])
    with h5py.File(src, "r") as a, h5py.File(out, "r") as b:
        assert b["frames/images"].compression == a["frames/images"].compression == "gzip"
    with H5RecordingWriter(tmp_path / "x.h5", w, h) as wr:
        wr.append_frames(im[:1], np.array([0]), np.zeros(1, np.int64))
        with pytest.raises(ValidationError, match="already written"):
            wr.copy_frames(src)
    with pytest.raises(FormatError, match="frame size"):
        with H5RecordingWriter(tmp_path / "y.h5", w + 1, h) as wr:
            wr.copy_frames(src)
    assert not (tmp_path / "y.h5").exists()
