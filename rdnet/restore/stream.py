"""Reading a recording for ``rdnet restore``: chunks of events grouped into consecutive
time windows, memory bounded.

All reading goes through :func:`_open` (one place to change). The windows tile the
recording from its first event: [t_first + k W, t_first + (k + 1) W), k = 0, 1, ...;
every window up to the one holding the last event is yielded (empty ones included),
so a stateful restorer sees the stream in order.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from rdnet.errors import FormatError
from rdnet.events.core import Events, concatenate
from rdnet.events.recording import Frames


class _LoadedSource:
    """The interface of ``rdnet.events.io.stream.open_events`` over a fully loaded
    recording (``.width .height .format .has_frames .frames() .chunks(max_events)``)."""

    def __init__(self, path: Path, sensor_size: tuple[int, int] | None = None):
        from rdnet.events.io import format_of, load
        self.format = format_of(path)
        rec = load(path, sensor_size=sensor_size)
        self.width, self.height = rec.width, rec.height
        self.sensor = rec.sensor
        self._events = rec.events if rec.events is not None else Events.empty(rec.width, rec.height)
        self._frames = rec.frames if rec.frames is not None and len(rec.frames) else None
        self.has_frames = self._frames is not None
        self.n_events = len(self._events)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def frames(self) -> Frames | None:
        return self._frames

    def chunks(self, max_events: int) -> Iterator[Events]:
        for i in range(0, len(self._events), int(max_events)):
            yield self._events[i:i + int(max_events)]


def _open(path: str | Path, sensor_size: tuple[int, int] | None = None):
    """Open ``path`` for streaming (a context manager with ``width``, ``height``,
    ``format``, ``has_frames``, ``frames()`` and ``chunks(max_events)``); ``sensor_size``
    (width, height) for formats that do not store it."""
    # TODO(lead): switch to open_events after merge:
    #   from rdnet.events.io.stream import open_events; return open_events(path, sensor_size=sensor_size)
    return _LoadedSource(Path(path), sensor_size)


def windows(chunks: Iterator[Events], window_us: int, *, path: str | Path = "recording"
            ) -> Iterator[tuple[int, int, Events]]:
    """(t0, t1, events in [t0, t1)) for consecutive windows of ``window_us`` (module
    docstring). :class:`FormatError` naming ``path`` when there is no event at all."""
    buf: list[Events] = []
    t0 = None
    W = int(window_us)
    for ch in chunks:
        if len(ch) == 0:
            continue
        if t0 is None:
            t0 = int(ch.t[0])
        buf.append(ch)
        last = int(ch.t[-1])
        if last < t0 + W:
            continue
        ev = concatenate(buf) if len(buf) > 1 else buf[0]
        # emit every window that ends at or before the last event seen (it is complete)
        n_done = (last - t0) // W
        cuts = np.searchsorted(ev.t, t0 + W * np.arange(1, n_done + 1), side="left")
        start = 0
        for k, c in enumerate(cuts):
            yield t0 + k * W, t0 + (k + 1) * W, ev[start:int(c)]
            start = int(c)
        t0 += n_done * W
        buf = [ev[start:]]
    if t0 is None:
        raise FormatError(path, "events", "recording has no events")
    ev = concatenate(buf) if len(buf) > 1 else buf[0]
    yield t0, t0 + W, ev
