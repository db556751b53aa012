"""One streaming interface over every recording format: :func:`open_events`.

>>> with open_events("night.raw") as s:                      # doctest: +SKIP
...     print(s.format, s.width, s.height, s.has_frames)
...     for chunk in s.chunks(1_000_000):                     # time-sorted Events
...         ...
...     burst = s.slice_time(1_000_000, 1_100_000)            # stops reading past t1

How each format streams:

- Prophesee RAW (EVT 2.0/3.0) and DAT: decoded incrementally by byte blocks
  (:class:`~rdnet.events.io.prophesee.ProphReader`); memory stays bounded whatever the
  file size, and :meth:`EventStream.slice_time` stops reading once past ``t1``.
- HDF5: the lazy :class:`~rdnet.events.io.hdf5.H5EventReader` (chunks read on demand,
  time slices through the time index).
- AEDAT 4, text and npz: loaded whole on opening, then sliced. These are small in
  practice (AEDAT 4 is LZ4-compressed DV output, text and npz are exchange formats);
  convert a big one to HDF5 once to stream it.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from rdnet.errors import FormatError, ValidationError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.recording import Frames


class EventStream:
    """Events of one recording, read chunk by chunk (a context manager).

    Attributes: ``path``, ``format`` (the name :func:`~rdnet.events.io.format_of` gives),
    ``width``, ``height``, ``sensor``, ``has_events``, ``has_frames`` and ``n_events``
    (None where it is only known after decoding the whole file: RAW, DAT)."""

    path: Path
    format: str
    width: int
    height: int
    sensor: str = ""
    has_events: bool = True
    has_frames: bool = False
    n_events: int | None = None

    def __enter__(self) -> "EventStream":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        pass

    def frames(self) -> Frames | None:
        """All frames of the recording, or None when it has none."""
        return None

    def chunks(self, max_events: int = 1_000_000) -> Iterator[Events]:
        """Time-sorted :class:`Events` of at most ``max_events`` each, in bounded memory."""
        raise NotImplementedError

    def slice_time(self, t0_us: int, t1_us: int) -> Events:
        """Events with ``t0_us <= t < t1_us`` (reading stops once past ``t1_us``)."""
        parts = []
        for ch in self.chunks():
            if len(ch) and int(ch.t[0]) >= t1_us:
                break
            if len(ch) and int(ch.t[-1]) >= t0_us:
                parts.append(ch.slice_time(t0_us, t1_us).array)
        arr = np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)
        return Events(arr, self.width, self.height, validate=False)

    @staticmethod
    def _check_max(max_events: int) -> int:
        if int(max_events) <= 0:
            raise ValidationError("max_events", f"must be > 0, got {max_events}")
        return int(max_events)


class _ProphStream(EventStream):
    def __init__(self, path: Path, fmt: str, sensor_size):
        from rdnet.events.io.prophesee import ProphReader
        self.path, self.format = path, fmt
        self._reader = ProphReader(path, sensor_size=sensor_size)
        self.width, self.height, self.sensor = self._reader.width, self._reader.height, self._reader.sensor
        self.encoding = self._reader.header.encoding

    def chunks(self, max_events: int = 1_000_000) -> Iterator[Events]:
        return self._reader.chunks(self._check_max(max_events))


class _H5Stream(EventStream):
    def __init__(self, path: Path, sensor_size):
        import h5py

        from rdnet.events.io._common import check_sensor_size, wrap_errors
        from rdnet.events.io.hdf5 import H5EventReader, read_header
        self.path, self.format = path, "hdf5"
        self.width, self.height, self.sensor, _ = read_header(path)
        check_sensor_size(path, (self.width, self.height), sensor_size)
        with wrap_errors(path), h5py.File(path, "r") as f:
            self.has_events = "events" in f
            self.has_frames = "frames" in f
        if not (self.has_events or self.has_frames):
            raise FormatError(path, "events", "recording has neither /events nor /frames")
        self._reader = H5EventReader(path, "events") if self.has_events else None
        self.n_events = len(self._reader) if self._reader is not None else 0

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()

    def frames(self) -> Frames | None:
        from rdnet.events.io.hdf5 import read_frames
        return read_frames(self.path) if self.has_frames else None

    def chunks(self, max_events: int = 1_000_000) -> Iterator[Events]:
        if self._reader is None:
            return iter(())
        return self._reader.iter_chunks(self._check_max(max_events))

    def slice_time(self, t0_us: int, t1_us: int) -> Events:
        if self._reader is None:
            return Events.empty(self.width, self.height)
        return self._reader.slice_time(t0_us, t1_us)


class _MemoryStream(EventStream):
    def __init__(self, path: Path, fmt: str, sensor_size):
        from rdnet.events.io.dispatch import load
        self.path, self.format = path, fmt
        self._rec = load(path, sensor_size=sensor_size)
        self.width, self.height, self.sensor = self._rec.width, self._rec.height, self._rec.sensor
        self.has_events = self._rec.events is not None
        self.has_frames = self._rec.frames is not None
        self.n_events = 0 if self._rec.events is None else len(self._rec.events)

    def frames(self) -> Frames | None:
        return self._rec.frames

    def chunks(self, max_events: int = 1_000_000) -> Iterator[Events]:
        n = self._check_max(max_events)
        ev = self._rec.events
        if ev is None:
            return
        for i in range(0, len(ev), n):
            yield ev[i:i + n]

    def slice_time(self, t0_us: int, t1_us: int) -> Events:
        ev = self._rec.events
        return Events.empty(self.width, self.height) if ev is None else ev.slice_time(t0_us, t1_us)


def open_events(path: str | Path, *, sensor_size: tuple[int, int] | None = None) -> EventStream:
    """Open a recording of any known format for streaming (see the module docstring).

    ``sensor_size=(width, height)`` is needed for text files (and Prophesee files whose
    header gives no size); where the file states a size it must agree."""
    from rdnet.events.io._common import require_file
    from rdnet.events.io.dispatch import format_of
    fmt = format_of(path)
    path = require_file(path)
    if fmt in ("prophesee_raw", "prophesee_dat"):
        return _ProphStream(path, fmt, sensor_size)
    if fmt == "hdf5":
        return _H5Stream(path, sensor_size)
    return _MemoryStream(path, fmt, sensor_size)
