"""The project's HDF5 recording layout (see DATA.md), written in compressed chunks and
read lazily.

Layout::

    /events/t            int64  (n,)  microseconds, non-decreasing
    /events/x, /events/y uint16 (n,)
    /events/p            uint8  (n,)  1 = ON, 0 = OFF
    /events/index_t      int64  (K,)  t of event k * index_stride (attr index_stride on /events)
    /events/index_offset int64  (K,)  k * index_stride (the event offset the entry points at)
    /frames/images       uint8 or float32, (N, H, W) or (N, H, W, 3)
    /frames/t            int64  (N,)  mid-exposure, microseconds
    /frames/exposure_us  int64  (N,)
    root attrs: width, height (int), sensor (str), any extra (e.g. degrade_json)

Other event groups (``/events_ideal``...) have the same layout. ``/frames`` or
``/events`` may be absent. The time index (one entry every ``index_stride`` events,
by default one per HDF5 chunk) lets :class:`H5EventReader` find a time slice by
reading the small index plus one chunk per boundary; files written by other tools
without an index fall back to a binary search over the chunked ``t`` dataset
(O(log n) single-element reads, then one window).
"""
from __future__ import annotations

import logging
import math
import os
from pathlib import Path
from typing import Iterator, Mapping

import h5py
import numpy as np

from rdnet.errors import FormatError, ValidationError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.io._common import (DECODE_ERRORS, as_format_error, checked_cast, remove_quietly,
                                     require_file, temp_path_for, wrap_errors)
from rdnet.events.recording import Frames, Recording

log = logging.getLogger(__name__)

FORMAT_NAME = "rdnet-recording"
FORMAT_VERSION = 1
#: Events per HDF5 chunk and per time-index entry.
DEFAULT_CHUNK_EVENTS = 1 << 16
#: Root attributes managed by the format itself (not returned in ``Recording.attrs``).
_RESERVED_ATTRS = ("width", "height", "sensor", "format", "format_version")
#: Binary search without an index stops at windows this small and reads them whole.
_SEARCH_WINDOW = 1 << 16
_INTEGER_KINDS = "iub"


def _compression_kwargs(compression: str | None, level: int | None) -> dict:
    if compression is None or compression == "none":
        return {}
    if compression == "gzip":
        return {"compression": "gzip", "compression_opts": 4 if level is None else int(level), "shuffle": True}
    if compression == "lzf":
        return {"compression": "lzf", "shuffle": True}
    raise ValidationError("compression", f"unknown compression {compression!r}; use gzip, lzf or none")


def _py(value):
    """h5py attribute value -> plain Python (bytes decoded, numpy scalars unwrapped)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray) and value.dtype.kind in "SO":
        return [_py(v) for v in value.tolist()]
    return value


def _sensor_size(f: h5py.File, path) -> tuple[int, int]:
    size = []
    for key in ("width", "height"):
        if key not in f.attrs:
            raise FormatError(path, key, "missing root attribute")
        v = _py(f.attrs[key])
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise FormatError(path, key, f"root attribute must be a positive integer, got {v!r}")
        size.append(v)
    return size[0], size[1]


class H5EventReader:
    """Lazy access to one event group of an HDF5 recording (a context manager).

    Nothing but the small time index is read on opening; :meth:`slice_time` reads only
    the chunks that hold the requested events. Every slice is validated (sorted,
    on-sensor, polarity 0/1); problems raise :class:`FormatError` naming the file and
    the dataset.
    """

    def __init__(self, path: str | Path, group: str = "events"):
        self.path = require_file(path)
        self.group = group
        with wrap_errors(self.path):
            self._file = h5py.File(self.path, "r")
        try:
            with wrap_errors(self.path, group):
                self._open()
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        f, path, group = self._file, self.path, self.group
        self.width, self.height = _sensor_size(f, path)
        if group not in f or not isinstance(f[group], h5py.Group):
            raise FormatError(path, group, "no such event group")
        g = f[group]
        self._ds = {}
        n = None
        for k in "txyp":
            name = f"{group}/{k}"
            if k not in g or not isinstance(g[k], h5py.Dataset):
                raise FormatError(path, name, "missing dataset")
            ds = g[k]
            if ds.ndim != 1:
                raise FormatError(path, name, f"expected a 1-D dataset, got shape {ds.shape}")
            if ds.dtype.kind not in _INTEGER_KINDS:
                raise FormatError(path, name, f"expected an integer dtype ({EVENT_DTYPE[k]}), got {ds.dtype}")
            if n is not None and ds.shape[0] != n:
                raise FormatError(path, name, f"length {ds.shape[0]} differs from {group}/t ({n})")
            n = ds.shape[0]
            self._ds[k] = ds
        self._n = int(n)
        self._index_t, self._stride = self._load_index(g)

    def _load_index(self, g: h5py.Group) -> tuple[np.ndarray | None, int]:
        if "index_t" not in g or "index_stride" not in g.attrs:
            log.debug("%s: /%s has no time index; using binary search", self.path, self.group)
            return None, 0
        stride = int(_py(g.attrs["index_stride"]))
        idx = np.asarray(g["index_t"][()])
        if stride <= 0 or idx.ndim != 1 or idx.shape[0] != math.ceil(self._n / stride) or (
                idx.size > 1 and np.any(np.diff(idx) < 0)):
            log.warning("%s: ignoring inconsistent time index of /%s", self.path, self.group)
            return None, 0
        return idx.astype(np.int64), stride

    # --- context manager ------------------------------------------------------------
    def close(self) -> None:
        f = getattr(self, "_file", None)
        if f is not None:
            try:
                f.close()
            except DECODE_ERRORS:  # pragma: no cover - closing a corrupt file
                pass
            self._file = None

    def __enter__(self) -> "H5EventReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- access ---------------------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    @property
    def t_range(self) -> tuple[int, int] | None:
        """(first, last) timestamp in microseconds, or None when the group is empty."""
        if self._n == 0:
            return None
        with wrap_errors(self.path, f"{self.group}/t"):
            return int(self._ds["t"][0]), int(self._ds["t"][self._n - 1])

    def _t_window(self, i0: int, i1: int) -> np.ndarray:
        return np.asarray(self._ds["t"][i0:i1])

    def _search(self, value: int) -> int:
        """First index i with t[i] >= value (assuming sorted t)."""
        n = self._n
        if n == 0:
            return 0
        if self._index_t is not None:
            k = int(np.searchsorted(self._index_t, value, "left"))
            if k == 0:
                return 0
            lo, hi = (k - 1) * self._stride, min(k * self._stride, n)
        else:
            lo, hi = 0, n
            ds = self._ds["t"]
            while hi - lo > _SEARCH_WINDOW:
                mid = (lo + hi) // 2
                if int(ds[mid]) < value:
                    lo = mid + 1
                else:
                    hi = mid
        return lo + int(np.searchsorted(self._t_window(lo, hi), value, "left"))

    def index_range(self, t_start_us: int | None, t_end_us: int | None) -> tuple[int, int]:
        """[i0, i1) of the events with t_start_us <= t < t_end_us (None = unbounded)."""
        with wrap_errors(self.path, f"{self.group}/t"):
            i0 = 0 if t_start_us is None else self._search(int(t_start_us))
            i1 = self._n if t_end_us is None else self._search(int(t_end_us))
        return i0, max(i0, i1)

    def read(self, start: int = 0, stop: int | None = None) -> Events:
        """Events [start, stop) by index, validated."""
        stop = self._n if stop is None else min(int(stop), self._n)
        start = max(0, min(int(start), stop))
        arr = np.empty(stop - start, EVENT_DTYPE)
        for k in "txyp":
            field = f"{self.group}/{k}"
            with wrap_errors(self.path, field):
                col = np.asarray(self._ds[k][start:stop])
                arr[k] = checked_cast(col, EVENT_DTYPE[k], self.path, field)
        try:
            return Events(arr, self.width, self.height)
        except ValidationError as e:
            raise FormatError(self.path, f"{self.group}/{e.field}", str(e).split(": ", 1)[-1]) from None

    def slice_time(self, t_start_us: int | None, t_end_us: int | None) -> Events:
        """Events with t_start_us <= t < t_end_us, reading only the chunks involved."""
        return self.read(*self.index_range(t_start_us, t_end_us))

    def iter_chunks(self, size: int = DEFAULT_CHUNK_EVENTS) -> Iterator[Events]:
        """Consecutive slices of at most ``size`` events (for streaming consumers)."""
        if size <= 0:
            raise ValidationError("size", f"must be > 0, got {size}")
        for i in range(0, self._n, size):
            yield self.read(i, i + size)


def _attrs_of(f: h5py.File, path) -> dict:
    out = {}
    for k in f.attrs:
        if k in _RESERVED_ATTRS:
            continue
        with wrap_errors(path, k):
            out[k] = _py(f.attrs[k])
    return out


def _read_frames_group(f: h5py.File, path, start: int = 0, stop: int | None = None) -> Frames | None:
    if "frames" not in f:
        return None
    g = f["frames"]
    if not isinstance(g, h5py.Group):
        raise FormatError(path, "frames", "expected a group")
    ds = {}
    for k in ("images", "t", "exposure_us"):
        if k not in g or not isinstance(g[k], h5py.Dataset):
            raise FormatError(path, f"frames/{k}", "missing dataset")
        ds[k] = g[k]
    im = ds["images"]
    if im.dtype not in (np.uint8, np.float32):
        raise FormatError(path, "frames/images", f"dtype must be uint8 or float32, got {im.dtype}")
    n = im.shape[0] if im.ndim else 0
    for k in ("t", "exposure_us"):
        if ds[k].dtype.kind not in _INTEGER_KINDS:
            raise FormatError(path, f"frames/{k}", f"expected an integer dtype (int64), got {ds[k].dtype}")
        if ds[k].shape != (n,):
            raise FormatError(path, f"frames/{k}", f"expected shape ({n},), got {ds[k].shape}")
    stop = n if stop is None else min(int(stop), n)
    start = max(0, min(int(start), stop))
    images = np.asarray(im[start:stop])
    t = checked_cast(np.asarray(ds["t"][start:stop]), np.dtype(np.int64), path, "frames/t")
    exp = checked_cast(np.asarray(ds["exposure_us"][start:stop]), np.dtype(np.int64), path, "frames/exposure_us")
    return Frames(images, t, exp)


def read_frames(path: str | Path, start: int = 0, stop: int | None = None) -> Frames | None:
    """Frames [start, stop) of an HDF5 recording (None if it has no /frames)."""
    path = require_file(path)
    with wrap_errors(path), h5py.File(path, "r") as f:
        w, h = _sensor_size(f, path)
        fr = _read_frames_group(f, path, start, stop)
        if fr is not None and (fr.width, fr.height) != (w, h):
            raise FormatError(path, "frames/images", f"frame size {fr.width}x{fr.height} != sensor {w}x{h}")
        return fr


def event_groups(path: str | Path) -> list[str]:
    """Names of the root groups that hold an event stream (have a ``t`` dataset)."""
    path = require_file(path)
    with wrap_errors(path), h5py.File(path, "r") as f:
        return [k for k in f if k != "frames" and isinstance(f[k], h5py.Group) and "t" in f[k]]


def read_events(path: str | Path, group: str = "events", t_start_us: int | None = None,
                t_end_us: int | None = None) -> Events:
    """Events of ``group`` with t_start_us <= t < t_end_us (None = unbounded); reads only
    the chunks of the slice."""
    with H5EventReader(path, group) as r:
        return r.slice_time(t_start_us, t_end_us)


def read_header(path: str | Path) -> tuple[int, int, str, dict]:
    """``(width, height, sensor, attrs)`` of an HDF5 recording without reading its events
    or frames (for streaming a large recording through :func:`read_frames` chunks)."""
    path = require_file(path)
    with wrap_errors(path), h5py.File(path, "r") as f:
        w, h = _sensor_size(f, path)
        return w, h, str(_py(f.attrs.get("sensor", ""))), _attrs_of(f, path)


def read_recording(path: str | Path) -> Recording:
    """Whole recording: /events (if present), /frames (if present), sensor size, name and
    extra root attributes (``Recording.attrs``). Extra event groups: :func:`read_events`."""
    path = require_file(path)
    with wrap_errors(path):
        with h5py.File(path, "r") as f:
            w, h = _sensor_size(f, path)
            sensor = _py(f.attrs.get("sensor", ""))
            attrs = _attrs_of(f, path)
            frames = _read_frames_group(f, path)
            has_events = "events" in f
        events = None
        if has_events:
            with H5EventReader(path, "events") as r:
                events = r.read()
        if events is None and frames is None:
            raise FormatError(path, "events", "recording has neither /events nor /frames")
        return Recording(w, h, events=events, frames=frames, sensor=str(sensor), attrs=attrs)


class _Stream:
    """Write state of one appendable event group."""

    def __init__(self, group: h5py.Group):
        self.group = group
        self.n = 0
        self.last_t: int | None = None


class H5RecordingWriter:
    """Incremental writer of the HDF5 recording layout (a context manager).

    Events are appended chunk by chunk (time order is checked across chunks), frames
    likewise, so hours of simulated events never need to be in memory at once. Data go
    to a temporary file in the target folder that replaces ``path`` on a successful
    :meth:`close`; on an exception inside the ``with`` block (or :meth:`abort`) the
    temporary file is removed and ``path`` is untouched.

    ``compression`` (gzip, lzf or none) and ``compression_level`` apply to the events;
    ``frame_compression`` to the frames ("same": as the events). Camera frames are mostly
    sensor noise to a lossless coder: gzip saves 16 % of the DAVIS346 road recording's
    APS frames at 2.7 ms per frame, against about 0.1 ms to store them as they are.
    """

    def __init__(self, path: str | Path, width: int, height: int, sensor: str = "", *,
                 compression: str | None = "gzip", compression_level: int | None = None,
                 chunk_events: int = DEFAULT_CHUNK_EVENTS, frame_compression: str | None = "same"):
        if int(width) <= 0 or int(height) <= 0:
            raise ValidationError("width/height", f"sensor size must be positive, got {width}x{height}")
        if chunk_events <= 0:
            raise ValidationError("chunk_events", f"must be > 0, got {chunk_events}")
        self.path = Path(path)
        self.width, self.height = int(width), int(height)
        self._comp = _compression_kwargs(compression, compression_level)
        self._frame_comp = self._comp if frame_compression == "same" else \
            _compression_kwargs(frame_compression, compression_level)
        self._chunk = int(chunk_events)
        self._streams: dict[str, _Stream] = {}
        self._frames: dict | None = None
        self._tmp = temp_path_for(self.path)
        try:
            self._file = h5py.File(self._tmp, "w")
            self._file.attrs["format"] = FORMAT_NAME
            self._file.attrs["format_version"] = FORMAT_VERSION
            self._file.attrs["width"] = self.width
            self._file.attrs["height"] = self.height
            self._file.attrs["sensor"] = str(sensor)
        except OSError as e:
            remove_quietly(self._tmp)
            raise as_format_error(self.path, e, what="cannot write") from e

    # --- context manager ------------------------------------------------------------
    def __enter__(self) -> "H5RecordingWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def abort(self) -> None:
        """Discard everything written so far."""
        if self._file is not None:
            try:
                self._file.close()
            except DECODE_ERRORS:  # pragma: no cover
                pass
            self._file = None
        remove_quietly(self._tmp)

    def close(self) -> None:
        """Finish the file and move it to ``path``."""
        if self._file is None:
            return
        try:
            self._file.close()
            self._file = None
            os.replace(self._tmp, self.path)
        except OSError as e:
            self.abort()
            raise as_format_error(self.path, e, what="cannot write") from e

    def _check_open(self) -> h5py.File:
        if self._file is None:
            raise ValidationError("writer", "already closed")
        return self._file

    # --- content --------------------------------------------------------------------
    def set_attr(self, key: str, value) -> None:
        """Root attribute (str, int, float, bool, a numpy array or a list of numbers);
        width/height/format are managed by the writer, ``sensor`` may be overwritten. One it
        cannot store is a :class:`FormatError` naming the file and the attribute."""
        f = self._check_open()
        if key in _RESERVED_ATTRS and key != "sensor":
            raise FormatError(self.path, f"attrs/{key}", "reserved attribute")
        if isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) for v in value):
            value = np.asarray(value)
        if not isinstance(value, (str, int, float, bool, np.generic, np.ndarray)):
            raise FormatError(self.path, f"attrs/{key}", f"unsupported attribute type {type(value).__name__} (use "
                              "str, int, float, bool or a numpy array; JSON-encode dicts)")
        with wrap_errors(self.path, f"attrs/{key}", what="cannot write"):     # e.g. a NUL in a string
            f.attrs[key] = value

    def _stream(self, group: str) -> _Stream:
        st = self._streams.get(group)
        if st is not None:
            return st
        f = self._check_open()
        if group in ("frames", "") or "/" in group:
            raise ValidationError("group", f"invalid event group name {group!r}")
        g = f.create_group(group)
        for k in "txyp":
            g.create_dataset(k, shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE[k],
                             chunks=(self._chunk,), **self._comp)
        g.create_dataset("index_t", shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(4096,))
        g.create_dataset("index_offset", shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(4096,))
        g.attrs["index_stride"] = self._chunk
        st = self._streams[group] = _Stream(g)
        return st

    def append_events(self, events: Events, group: str = "events") -> None:
        """Append time-sorted events to ``group`` (created on first use, even when empty).
        The first event must not be earlier than the last one already written."""
        if (events.width, events.height) != (self.width, self.height):
            raise ValidationError(f"{group}", f"sensor {events.width}x{events.height} != "
                                              f"recording {self.width}x{self.height}")
        st = self._stream(group)
        n = len(events)
        if n == 0:
            return
        if st.last_t is not None and int(events.t[0]) < st.last_t:
            raise ValidationError(f"{group}/t", f"chunk starts at {int(events.t[0])} us, before the last "
                                                f"written event ({st.last_t} us)")
        n0, n1 = st.n, st.n + n
        g = st.group
        try:
            for k in "txyp":
                g[k].resize((n1,))
                g[k][n0:n1] = events.array[k]
            pos = np.arange(-(-n0 // self._chunk) * self._chunk, n1, self._chunk, dtype=np.int64)
            if pos.size:
                k0 = g["index_t"].shape[0]
                for name, values in (("index_t", events.t[pos - n0]), ("index_offset", pos)):
                    g[name].resize((k0 + pos.size,))
                    g[name][k0:] = values
        except OSError as e:
            raise as_format_error(self.path, e, group, what="cannot write") from e
        st.n, st.last_t = n1, int(events.t[-1])

    def write_frames(self, frames: Frames) -> None:
        """Append all frames of ``frames``."""
        self.append_frames(frames.images, frames.t_us, frames.exposure_us)

    def append_frames(self, images: np.ndarray, t_us, exposure_us) -> None:
        """Append frames (validated as :class:`Frames`); shape and dtype must match the
        frames already written and times must keep increasing."""
        fr = Frames(images, t_us, exposure_us)
        if (fr.width, fr.height) != (self.width, self.height):
            raise ValidationError("frames/images", f"frame size {fr.width}x{fr.height} != "
                                                   f"sensor {self.width}x{self.height}")
        f = self._check_open()
        st = self._frames
        if st is None:
            g = f.create_group("frames")
            shape = fr.images.shape[1:]
            g.create_dataset("images", shape=(0, *shape), maxshape=(None, *shape), dtype=fr.images.dtype,
                             chunks=(1, *shape), **self._frame_comp)
            for k in ("t", "exposure_us"):
                g.create_dataset(k, shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(4096,))
            st = self._frames = {"group": g, "n": 0, "last_t": None,
                                 "shape": shape, "dtype": fr.images.dtype}
        if fr.images.shape[1:] != st["shape"] or fr.images.dtype != st["dtype"]:
            raise ValidationError("frames/images", f"frames {fr.images.shape[1:]} {fr.images.dtype} do not match "
                                                   f"the ones written ({st['shape']} {st['dtype']})")
        n = len(fr)
        if n == 0:
            return
        if st["last_t"] is not None and int(fr.t_us[0]) <= st["last_t"]:
            raise ValidationError("frames/t", f"frame at {int(fr.t_us[0])} us is not after the last "
                                              f"written frame ({st['last_t']} us)")
        g, n0 = st["group"], st["n"]
        try:
            for k, values in (("images", fr.images), ("t", fr.t_us), ("exposure_us", fr.exposure_us)):
                g[k].resize((n0 + n, *g[k].shape[1:]))
                g[k][n0:n0 + n] = values
        except OSError as e:
            raise as_format_error(self.path, e, "frames", what="cannot write") from e
        st["n"], st["last_t"] = n0 + n, int(fr.t_us[-1])

    def copy_frames(self, source: str | Path) -> int:
        """Copy the whole ``/frames`` group of the HDF5 recording ``source`` as stored: its
        compressed chunks are copied without decoding or re-encoding (HDF5's object copy),
        so the frames keep the source's dtype, chunking and compression. Only before any
        frames were written; later :meth:`append_frames` calls continue the copied frames.
        Returns the number of frames copied (FormatError when ``source`` has none or its
        frame size is not this recording's sensor size)."""
        f = self._check_open()
        if self._frames is not None:
            raise ValidationError("frames", "frames were already written; copy_frames must come first")
        source = require_file(source)
        with wrap_errors(source), h5py.File(source, "r") as src:
            fr = _read_frames_group(src, source, 0, 1)
            if fr is None or len(fr) == 0:
                raise FormatError(source, "frames", "recording has no frames")
            if (fr.width, fr.height) != (self.width, self.height):
                raise FormatError(source, "frames/images", f"frame size {fr.width}x{fr.height} != "
                                                           f"sensor {self.width}x{self.height}")
            try:
                src.copy(src["frames"], f, "frames")
            except OSError as e:
                raise as_format_error(self.path, e, "frames", what="cannot write") from e
        g = f["frames"]
        n = int(g["t"].shape[0])
        self._frames = {"group": g, "n": n, "last_t": int(g["t"][n - 1]),
                        "shape": g["images"].shape[1:], "dtype": g["images"].dtype}
        return n


class BackgroundWrites:
    """Runs the appends of an :class:`H5RecordingWriter` in one background thread, in the
    order submitted, so compressing and writing overlap with the caller's work (h5py
    releases the GIL inside HDF5's dataset reads and writes). At most ``max_pending``
    appends wait (bounded memory). An error in the thread is raised in the caller at the
    next :meth:`append_events` / :meth:`append_frames` or at :meth:`close`. Use as a
    context manager inside the writer's ``with`` block: leaving it waits for every write;
    on an exception the waiting writes are dropped (the writer then discards the file)."""

    def __init__(self, writer: "H5RecordingWriter", max_pending: int = 4):
        import queue
        import threading
        self.writer = writer
        self._queue: "queue.Queue" = queue.Queue(maxsize=max(1, int(max_pending)))
        self._error: BaseException | None = None
        self._cancel = False
        self._thread = threading.Thread(target=self._work, name="h5-writer", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._error is None and not self._cancel:
                fn, args = item
                try:
                    fn(*args)
                except BaseException as e:   # handed to the caller
                    self._error = e

    def _submit(self, fn, *args) -> None:
        if self._error is not None:
            raise self._error
        self._queue.put((fn, args))

    def append_events(self, events: Events, group: str = "events") -> None:
        """:meth:`H5RecordingWriter.append_events` in the background (on a copy of the events)."""
        self._submit(self.writer.append_events, Events(events.array.copy(), events.width, events.height,
                                                       validate=False), group)

    def append_frames(self, images: np.ndarray, t_us, exposure_us) -> None:
        """:meth:`H5RecordingWriter.append_frames` in the background (the arrays must not be
        modified afterwards)."""
        self._submit(self.writer.append_frames, images, t_us, exposure_us)

    def close(self, cancel: bool = False) -> None:
        """Wait for the pending writes (``cancel``: drop them) and stop the thread."""
        self._cancel = self._cancel or cancel
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        if self._error is not None and not cancel:
            raise self._error

    def __enter__(self) -> "BackgroundWrites":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(cancel=exc_type is not None)


def write_recording(path: str | Path, rec: Recording, extra_events: Mapping[str, Events] | None = None,
                    attrs: Mapping | None = None, **writer_kw) -> None:
    """Write ``rec`` (events, frames, sensor, ``rec.attrs``) plus extra event groups
    (e.g. ``{"events_ideal": ev}``) and extra root attributes, atomically."""
    with H5RecordingWriter(path, rec.width, rec.height, rec.sensor, **writer_kw) as w:
        for k, v in {**(rec.attrs or {}), **(attrs or {})}.items():
            w.set_attr(k, v)
        if rec.events is not None:
            w.append_events(rec.events)
        for name, ev in (extra_events or {}).items():
            w.append_events(ev, group=name)
        if rec.frames is not None:
            w.write_frames(rec.frames)
