"""Reading a recording for ``rdnet restore``: chunks of events grouped into consecutive
time windows, memory bounded.

The chunks come from :func:`rdnet.events.io.stream.open_events` (memory stays bounded on
large Prophesee and HDF5 files). The windows tile the
recording from its first event: [t_first + k W, t_first + (k + 1) W), k = 0, 1, ...;
every window up to the one holding the last event is yielded (empty ones included),
so a stateful restorer sees the stream in order; with ``cuts`` (a frame-pair restorer:
the frames' timestamps) the windows end at the cuts instead. A recording whose events span more than
:data:`MAX_WINDOWS` windows is refused (a timestamp jump: every window is a restorer call,
and events spanning 2^63 us once asked for a 1.3 PiB array of window edges).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np

from rdnet.errors import FormatError
from rdnet.events.core import Events, concatenate

#: the most windows a recording is cut into: 5.8 days of events at the default 50 ms
#: (``restore.window_us``); an event recording spans minutes to hours
MAX_WINDOWS = 10_000_000


def windows(chunks: Iterator[Events], window_us: int, *, path: str | Path = "recording",
            cuts=None) -> Iterator[tuple[int, int, Events]]:
    """(t0, t1, events in [t0, t1)) for consecutive windows of ``window_us`` (module
    docstring). ``cuts`` (increasing timestamps, e.g. a recording's frame times): windows
    end at each of them instead, so that between the first and the last cut every window
    spans one interval between consecutive cuts; before the first cut the windows keep
    ``window_us``, the last of them ending at the cut, and after the last cut they keep
    ``window_us``. :class:`FormatError` naming ``path`` when there is no event at all."""
    buf: list[Events] = []
    t0 = first = None
    W = int(window_us)
    cuts = None if cuts is None or len(cuts) == 0 else np.asarray(cuts, np.int64)

    def next_end(t: int) -> int:
        if cuts is not None:
            i = int(np.searchsorted(cuts, t, side="right"))
            if i < cuts.size and (i > 0 or t + W > cuts[0]):
                return int(cuts[i])
        return t + W

    for ch in chunks:
        if len(ch) == 0:
            continue
        if t0 is None:
            t0 = first = int(ch.t[0])
        buf.append(ch)
        last = int(ch.t[-1])
        if last - first >= MAX_WINDOWS * W:
            raise FormatError(path, "t", f"events from {first} to {last} us span {(last - first) // W + 1:.3g} "
                                         f"windows of {W} us, more than {MAX_WINDOWS:,}: a timestamp jump?")
        t1 = next_end(t0)
        if last < t1:
            continue
        ev = concatenate(buf) if len(buf) > 1 else buf[0]
        # emit every window that ends at or before the last event seen (it is complete)
        start = 0
        while last >= t1:
            c = start + int(np.searchsorted(ev.t[start:], t1, side="left"))
            yield t0, t1, ev[start:c]
            start = c
            t0, t1 = t1, next_end(t1)
        buf = [ev[start:]]
    if t0 is None:
        raise FormatError(path, "events", "recording has no events")
    ev = concatenate(buf) if len(buf) > 1 else buf[0]
    yield t0, next_end(t0), ev


def ordered_map(fn: Callable, items: Iterable, workers: int = 1) -> Iterator[tuple]:
    """``(item, fn(item))`` for every item, in the order of ``items``. ``workers`` > 1: up to
    that many calls run at once in threads (``fn`` must release the GIL to gain: torch does),
    with at most ``2 x workers`` items taken ahead of the one yielded, so memory stays
    bounded on a long stream; 1: each call in turn in this thread."""
    if workers <= 1:
        for item in items:
            yield item, fn(item)
        return
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor
    ahead: deque = deque()
    with ThreadPoolExecutor(workers, thread_name_prefix="rdnet-window") as pool:
        try:
            for item in items:
                ahead.append((item, pool.submit(fn, item)))
                if len(ahead) >= 2 * workers:
                    item0, fut = ahead.popleft()
                    yield item0, fut.result()
            while ahead:
                item0, fut = ahead.popleft()
                yield item0, fut.result()
        finally:
            for _, fut in ahead:             # an error or an early close: drop what is queued
                fut.cancel()
