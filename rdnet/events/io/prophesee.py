"""Prophesee recordings: RAW (EVT 2.0, EVT 3.0) and DAT (read only, streamed).

A Prophesee file is an ASCII header (lines ``% key value``, newer RAW files end it with
``% end``) followed by binary little-endian data:

- **EVT 2.0** RAW: 32-bit words, type in bits 31..28. ``CD_OFF``/``CD_ON`` (0x0/0x1)
  carry the 6 low timestamp bits (27..22), x (21..11) and y (10..0); ``EVT_TIME_HIGH``
  (0x8) the 28 high bits. Timestamps are 34 bits and wrap every 2^34 us (4.8 h).
- **EVT 3.0** RAW: 16-bit words, type in bits 15..12, a stateful encoding: ``EVT_ADDR_Y``
  (0x0) sets y, ``EVT_ADDR_X`` (0x2) emits one event at x with polarity bit 11,
  ``VECT_BASE_X`` (0x3) sets a base x and polarity, ``VECT_12``/``VECT_8`` (0x4/0x5)
  emit the events of a 12/8-bit mask from the base x and advance it, ``EVT_TIME_LOW``/
  ``EVT_TIME_HIGH`` (0x6/0x8) set the 12 low / 12 high bits of a 24-bit timestamp that
  wraps every 2^24 us (16.8 s).
- **DAT**: two bytes (event type, event size = 8) after the header, then 8-byte records
  (uint32 t in us; uint32 with x in bits 0..13, y in 14..27, polarity in 28..31).

Wraps are unrolled (a timestamp that goes back by more than half the range starts a new
period), so timestamps come out as int64 microseconds as written by the camera (not
shifted to start at 0). y counts from the top (as the sensor and everything in rdnet).
Vendor words (EXT_TRIGGER, OTHERS, CONTINUED) and events before the first time word are
skipped and counted (logged at debug level). Undefined word types, coordinates outside
the sensor, a data length that is not a whole number of words and a bad header raise
:class:`~rdnet.errors.FormatError` naming the file, the field and the byte offset.

Decoding runs in numba kernels over the words with the decoder state carried across
byte blocks, so a file of any size streams in bounded memory (:class:`ProphReader`).
Events inside one decode unit (:data:`DECODE_EVENTS` events) are sorted stably by time if
the file is not already in order (the shared sample files are); an event earlier than
the previous unit's last one (not seen in practice) is clamped to that time and counted
in a warning, so the stream stays time-sorted.

Why not a third-party decoder: see docs/cli.md ("Prophesee formats") and
``benchmarks/bench_formats.py``.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numba
import numpy as np

from rdnet.errors import FormatError, ValidationError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.io._common import check_sensor_size, require_file, wrap_errors

log = logging.getLogger(__name__)

#: Events per decode unit (the unit sorted by time when the file is out of order).
DECODE_EVENTS = 1 << 20
#: Bytes read per block.
BLOCK_BYTES = 1 << 22
#: The header must end within this many bytes.
MAX_HEADER_BYTES = 1 << 20

#: Sensor sizes of plugins whose RAW headers give no geometry (older Gen3 files).
_PLUGIN_SIZES = (("imx636", (1280, 720)), ("gen41", (1280, 720)), ("gen4", (1280, 720)),
                 ("imx8", (320, 320)), ("genx320", (320, 320)), ("gen31", (640, 480)),
                 ("gen3", (640, 480)))
_DAT_TYPES = {0x00: "Event2d", 0x0C: "EventCD"}
_ERRORS = {1: ("type", "undefined event type 0x{v:X}"), 2: ("x", "x = {v} outside the sensor"),
           3: ("y", "y = {v} outside the sensor")}


@dataclass(frozen=True)
class ProphHeader:
    """What the header of a Prophesee file says."""

    encoding: str               # "evt2", "evt3" or "dat"
    width: int
    height: int
    data_offset: int            # first byte of the binary data (after DAT's type/size bytes)
    sensor: str = ""
    keys: dict = field(default_factory=dict, compare=False)

    @property
    def word_bytes(self) -> int:
        return {"evt2": 4, "evt3": 2, "dat": 8}[self.encoding]


#: A header line: ``%``, then a key and its value in printable ASCII (or nothing).
_HEADER_LINE = re.compile(rb"%[ \t]*(?:[A-Za-z][\x20-\x7e\t]*)?\r?")
#: The ``% end`` line that ends the header of newer RAW files.
_HEADER_END = re.compile(rb"(?:^|\n)%[ \t]*end[ \t\r]*\n")


def _header_lines(path: Path, fh) -> tuple[list[str], int]:
    """The header lines and the offset of the first data byte. Without ``% end`` the header
    ends at the first line that is not ``%`` plus text: data whose first byte is ``%`` (0x25)
    are data; with it, a bad line before it is an error."""
    head = fh.read(MAX_HEADER_BYTES + 2)
    has_end = _HEADER_END.search(head) is not None
    lines, pos = [], 0
    while pos < len(head) and head[pos:pos + 1] == b"%":
        end = head.find(b"\n", pos)
        if not has_end and not _HEADER_LINE.fullmatch(head, pos, len(head) if end < 0 else end):
            break
        if end < 0:
            raise FormatError(path, "header", f"header line at byte {pos} does not end (truncated file?)")
        try:
            line = head[pos + 1:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise FormatError(path, "header", f"non-ASCII header line at byte {pos}") from None
        pos = end + 1
        if line == "end":
            break
        lines.append(line)
    if pos > MAX_HEADER_BYTES:
        raise FormatError(path, "header", f"header longer than {MAX_HEADER_BYTES} bytes")
    return lines, pos


def _size_from(path: Path, keys: dict[str, str], fmt_opts: dict[str, str]) -> tuple[int, int] | None:
    try:
        if "width" in fmt_opts or "height" in fmt_opts:
            return int(fmt_opts["width"]), int(fmt_opts["height"])
        if "geometry" in keys:
            m = re.fullmatch(r"(\d+)\s*x\s*(\d+)", keys["geometry"])
            if not m:
                raise ValueError(keys["geometry"])
            return int(m[1]), int(m[2])
        if "width" in keys or "height" in keys:  # DAT: "% Width 640" / "% Height 480"
            return int(keys["width"]), int(keys["height"])
    except (KeyError, ValueError) as e:
        raise FormatError(path, "geometry", f"unreadable sensor size in the header ({e})") from None
    plugin = keys.get("plugin_name", "").lower()
    for name, size in _PLUGIN_SIZES:
        if name in plugin:
            log.info("%s: no geometry in the header; %dx%d from plugin %r", path, *size, plugin)
            return size
    return None


def read_header(path: str | Path, *, sensor_size: tuple[int, int] | None = None) -> ProphHeader:
    """Parse the header of a Prophesee RAW (EVT 2.0 / 3.0) or DAT file.

    The sensor size comes from ``% format ...;width=W;height=H``, ``% geometry WxH``,
    DAT's ``% Width``/``% Height`` or, for older RAW files, the plugin name; ``sensor_size``
    (width, height) is used when the header has none and must agree when it has one."""
    path = require_file(path)
    is_dat = path.suffix.lower() == ".dat"
    with wrap_errors(path, "header"), open(path, "rb") as fh:
        lines, pos = _header_lines(path, fh)
        fh.seek(pos)
        type_size = fh.read(2) if is_dat else b""
    keys: dict[str, str] = {}
    for line in lines:
        k, _, v = line.partition(" ")
        keys.setdefault(k.lower(), v.strip())
    fmt_field, *opts = keys.get("format", "").split(";")
    fmt_opts = {}
    for o in opts:
        k, _, v = o.partition("=")
        fmt_opts[k.strip().lower()] = v.strip()
    if is_dat:
        if len(type_size) < 2:
            raise FormatError(path, "event type", "file ends before the event type/size bytes")
        ev_type, ev_size = type_size[0], type_size[1]
        if ev_type not in _DAT_TYPES:
            raise FormatError(path, "event type", f"event type 0x{ev_type:02X} is not a CD event "
                                                  f"(expected one of {sorted(_DAT_TYPES)})")
        if ev_size != 8:
            raise FormatError(path, "event size", f"event size {ev_size}, expected 8")
        version = keys.get("version", "2")
        if version != "2":
            raise FormatError(path, "Version", f"DAT version {version!r} is not supported (only 2)")
        encoding, pos = "dat", pos + 2
    else:
        evt = fmt_field.strip().upper() or ("EVT" + keys["evt"].replace(".0", "") if "evt" in keys else "")
        encoding = {"EVT2": "evt2", "EVT3": "evt3"}.get(evt)
        if encoding is None:
            what = evt or "none"
            raise FormatError(path, "format", f"RAW encoding {what!r} is not supported (EVT 2.0 and EVT 3.0 are; "
                                              "header needs '% evt 2.0|3.0' or '% format EVT2|EVT3')")
    size = _size_from(path, keys, fmt_opts)
    if size is None:
        if sensor_size is None:
            raise FormatError(path, "geometry", "the header gives no sensor size; pass --width/--height")
        size = tuple(int(v) for v in sensor_size)
    else:
        check_sensor_size(path, size, sensor_size)
    w, h = size
    if not (0 < w <= 2048 and 0 < h <= 2048):
        raise FormatError(path, "geometry", f"implausible sensor size {w}x{h}")
    sensor = keys.get("plugin_name", "") or keys.get("sensor_generation", "")
    sensor = f"Prophesee {sensor}".strip() if encoding != "dat" else "Prophesee (DAT)"
    return ProphHeader(encoding, w, h, pos, sensor, keys)


# --- kernels ------------------------------------------------------------------------------
# state (int64): [time_high, overflow, have_time_high, time_low, y, have_y, base_x, polarity]
# counts (int64): [vendor words skipped, events before the first time word]
# each kernel returns (next word index, events filled, error code, error word index, value)

@numba.njit(cache=True)
def _evt2_kernel(words, i, state, t, x, y, p, fill, width, height, counts):
    th, ov, have = state[0], state[1], state[2]
    cap = t.shape[0]
    n = words.shape[0]
    err, err_i, err_v = 0, 0, 0
    while i < n and fill < cap:
        w = np.int64(words[i])
        typ = w >> 28
        if typ == 0 or typ == 1:
            if have == 0:
                counts[1] += 1
            else:
                xx = (w >> 11) & 0x7FF
                yy = w & 0x7FF
                if xx >= width:
                    err, err_i, err_v = 2, i, xx
                    break
                if yy >= height:
                    err, err_i, err_v = 3, i, yy
                    break
                t[fill] = (((ov << 28) + th) << 6) | ((w >> 22) & 0x3F)
                x[fill] = xx
                y[fill] = yy
                p[fill] = typ
                fill += 1
        elif typ == 8:
            nh = w & 0x0FFFFFFF
            if have == 1 and nh < th and th - nh > (1 << 27):
                ov += 1
            th = nh
            have = 1
        elif typ == 0xA or typ == 0xE or typ == 0xF:
            counts[0] += 1
        else:
            err, err_i, err_v = 1, i, typ
            break
        i += 1
    state[0], state[1], state[2] = th, ov, have
    return i, fill, err, err_i, err_v


@numba.njit(cache=True)
def _evt3_kernel(words, i, state, t, x, y, p, fill, width, height, counts):
    th, ov, have, tl = state[0], state[1], state[2], state[3]
    yy, have_y, base_x, pol = state[4], state[5], state[6], state[7]
    cap = t.shape[0]
    n = words.shape[0]
    err, err_i, err_v = 0, 0, 0
    while i < n and fill + 12 <= cap:
        w = np.int64(words[i])
        typ = w >> 12
        if typ == 0x0:                      # EVT_ADDR_Y
            yy = w & 0x7FF
            have_y = 1
            if yy >= height:
                err, err_i, err_v = 3, i, yy
                break
        elif typ == 0x2:                    # EVT_ADDR_X: one event
            if have == 0 or have_y == 0:
                counts[1] += 1
            else:
                xx = w & 0x7FF
                if xx >= width:
                    err, err_i, err_v = 2, i, xx
                    break
                t[fill] = (ov << 24) | (th << 12) | tl
                x[fill] = xx
                y[fill] = yy
                p[fill] = (w >> 11) & 1
                fill += 1
        elif typ == 0x3:                    # VECT_BASE_X
            base_x = w & 0x7FF
            pol = (w >> 11) & 1
        elif typ == 0x4 or typ == 0x5:      # VECT_12 / VECT_8
            nb = 12 if typ == 0x4 else 8
            mask = w & ((1 << nb) - 1)
            if have == 0 or have_y == 0:
                while mask:
                    counts[1] += mask & 1
                    mask >>= 1
            else:
                tt = (ov << 24) | (th << 12) | tl
                k = 0
                while mask:
                    if mask & 1:
                        xx = base_x + k
                        if xx >= width:
                            err, err_i, err_v = 2, i, xx
                            break
                        t[fill] = tt
                        x[fill] = xx
                        y[fill] = yy
                        p[fill] = pol
                        fill += 1
                    mask >>= 1
                    k += 1
                if err:
                    break
            base_x += nb
        elif typ == 0x6:                    # EVT_TIME_LOW
            tl = w & 0xFFF
        elif typ == 0x8:                    # EVT_TIME_HIGH
            nh = w & 0xFFF
            if have == 1 and nh < th and th - nh > (1 << 11):
                ov += 1
            th = nh
            have = 1
        elif typ == 0x7 or typ == 0xA or typ == 0xE or typ == 0xF:
            counts[0] += 1
        else:
            err, err_i, err_v = 1, i, typ
            break
        i += 1
    state[0], state[1], state[2], state[3] = th, ov, have, tl
    state[4], state[5], state[6], state[7] = yy, have_y, base_x, pol
    return i, fill, err, err_i, err_v


@numba.njit(cache=True)
def _dat_kernel(words, i, state, t, x, y, p, fill, width, height, counts):
    # words: uint32 pairs (t, data) flattened; state[0] last raw t, state[1] overflow, state[2] have
    last, ov, have = state[0], state[1], state[2]
    cap = t.shape[0]
    n = words.shape[0] // 2
    err, err_i, err_v = 0, 0, 0
    while i < n and fill < cap:
        raw = np.int64(words[2 * i])
        d = np.int64(words[2 * i + 1])
        xx = d & 0x3FFF
        yy = (d >> 14) & 0x3FFF
        pp = (d >> 28) & 0xF
        if xx >= width:
            err, err_i, err_v = 2, i, xx
            break
        if yy >= height:
            err, err_i, err_v = 3, i, yy
            break
        if pp > 1:
            err, err_i, err_v = 4, i, pp
            break
        if have == 1 and raw < last and last - raw > (1 << 31):
            ov += 1
        last = raw
        have = 1
        t[fill] = (ov << 32) | raw
        x[fill] = xx
        y[fill] = yy
        p[fill] = pp
        fill += 1
        i += 1
    state[0], state[1], state[2] = last, ov, have
    return i, fill, err, err_i, err_v


_KERNELS = {"evt2": (_evt2_kernel, "<u4"), "evt3": (_evt3_kernel, "<u2"), "dat": (_dat_kernel, "<u4")}


class ProphReader:
    """Streaming decoder of one Prophesee file (a context manager).

    :meth:`units` yields the decoded events unit by unit (at most :data:`DECODE_EVENTS`
    each, time-sorted, sorted across units); :meth:`chunks` cuts them to at most a
    requested size. Memory stays at one byte block plus one unit whatever the file size."""

    def __init__(self, path: str | Path, *, sensor_size: tuple[int, int] | None = None,
                 block_bytes: int = BLOCK_BYTES, decode_events: int = DECODE_EVENTS):
        self.header = read_header(path, sensor_size=sensor_size)
        self.path = Path(path)
        self.width, self.height = self.header.width, self.header.height
        self.sensor = self.header.sensor
        self._block = max(int(block_bytes) // 8 * 8, 8)
        self._unit = max(int(decode_events), 64)
        self.vendor_words = 0
        self.skipped_events = 0
        self.clamped_events = 0

    def __enter__(self) -> "ProphReader":
        return self

    def __exit__(self, *exc) -> None:
        pass

    def _error(self, code: int, offset: int, value: int) -> FormatError:
        what, msg = _ERRORS.get(code, ("p", "polarity {v} is not 0/1"))
        field = {"dat": "event", "evt2": "word", "evt3": "word"}[self.header.encoding]
        return FormatError(self.path, f"{what} ({field} at byte {offset})", msg.format(v=value))

    def units(self) -> Iterator[Events]:
        """Decode the whole file, yielding time-sorted :class:`Events` of at most one unit."""
        h = self.header
        kernel, dtype = _KERNELS[h.encoding]
        wb = h.word_bytes
        state = np.zeros(8, np.int64)
        counts = np.zeros(2, np.int64)
        unit = self._new_unit()
        fill = 0
        last_t = None
        consumed = 0           # bytes of data decoded before the current block
        with wrap_errors(self.path, "data"), open(self.path, "rb") as fh:
            fh.seek(h.data_offset)
            while True:
                raw = fh.read(self._block)
                if not raw:
                    break
                if len(raw) % wb:   # blocks are whole words, so only the end can be short
                    raise FormatError(self.path, "data", f"truncated: {len(raw) % wb} trailing byte(s) at byte "
                                                         f"{h.data_offset + consumed + len(raw) // wb * wb} "
                                                         f"(not a whole {wb}-byte word)")
                words = np.frombuffer(raw, dtype=dtype)
                n_items = len(raw) // wb
                i = 0
                while i < n_items:
                    i, fill, err, err_i, err_v = kernel(words, i, state, unit["t"], unit["x"], unit["y"],
                                                        unit["p"], fill, self.width, self.height, counts)
                    if err:
                        raise self._error(err, h.data_offset + consumed + err_i * wb, err_v)
                    if i < n_items:        # unit full
                        out, last_t = self._finish(unit, fill, last_t)
                        yield out
                        unit, fill = self._new_unit(), 0
                consumed += len(raw)
        if fill:
            out, last_t = self._finish(unit, fill, last_t)
            yield out
        self.vendor_words, self.skipped_events = int(counts[0]), int(counts[1])
        log.debug("%s: skipped %d vendor words (triggers, others, continued) and %d events before the "
                  "first time word", self.path, self.vendor_words, self.skipped_events)
        if self.clamped_events:
            log.warning("%s: %d events earlier than the previous decode unit were clamped to its last time",
                        self.path, self.clamped_events)

    def _new_unit(self) -> np.ndarray:
        # a fresh buffer per unit: the Events handed out are views of it, never overwritten
        return np.empty(self._unit, EVENT_DTYPE)

    def _finish(self, unit: np.ndarray, fill: int, last_t):
        arr = unit[:fill]
        t = arr["t"]
        if fill > 1 and np.any(t[1:] < t[:-1]):
            arr = arr[np.argsort(t, kind="stable")]
            t = arr["t"]
        if last_t is not None and fill and t[0] < last_t:
            late = t < last_t
            self.clamped_events += int(late.sum())
            t[late] = last_t
        if fill:
            last_t = int(t[-1])
        return Events(arr, self.width, self.height, validate=False), last_t

    def chunks(self, max_events: int = 1_000_000) -> Iterator[Events]:
        """Time-sorted chunks of at most ``max_events`` events: the decode units cut to size
        (views, no copy; a unit's last piece may be shorter)."""
        if max_events <= 0:
            raise ValidationError("max_events", f"must be > 0, got {max_events}")
        for unit in self.units():
            for i in range(0, len(unit), max_events):
                yield unit[i:i + max_events]

    def read(self) -> Events:
        """The whole file as one :class:`Events` (for files that fit in memory)."""
        parts = [u.array for u in self.units()]
        arr = (parts[0] if len(parts) == 1 else np.concatenate(parts)) if parts else np.empty(0, EVENT_DTYPE)
        return Events(arr, self.width, self.height, validate=False)


def read_prophesee(path: str | Path, *, sensor_size: tuple[int, int] | None = None):
    """Whole Prophesee RAW/DAT file as a :class:`~rdnet.events.Recording` (events only)."""
    from rdnet.events.recording import Recording
    with ProphReader(path, sensor_size=sensor_size) as r:
        ev = r.read()
        return Recording(r.width, r.height, events=ev, sensor=r.sensor,
                         attrs={"source_format": r.header.encoding})
