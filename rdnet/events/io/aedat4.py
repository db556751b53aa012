"""AEDAT 4 (iniVation DV) reader, via the ``aedat`` package (read only).

``aedat.Decoder(path)`` yields packets holding "events" (structured t, x, y, on),
"frame" (t, exposure_begin_t, exposure_end_t, pixels, format...), "imus" or "triggers";
``id_to_stream()`` describes each stream (type, width, height). Mapping to
:class:`~rdnet.events.recording.Recording`:

- events of the first events stream: t (us, int64), x, y, p = on;
- frames of the first frame stream: t = middle of the exposure
  ((exposure_begin_t + exposure_end_t) // 2), exposure_us = end - begin; grey ("L") frames
  are (H, W) uint8, colour ("RGB"/"RGBA", alpha dropped) are (H, W, 3) uint8;
- width/height from the stream description (never from max(x) + 1);
- sensor: the camera name of the DV header's ``source`` attribute without its serial
  number (e.g. "DAVIS346_00000002" -> "DAVIS346"); the full string is in
  ``attrs["aedat_source"]``. IMU samples and triggers are skipped.

DV writes packets in time order and events within a packet are sorted, so the event
stream is normally globally sorted (the bundled DAVIS346 file is). If timestamps do
decrease across packets the events are sorted stably by time (equal times keep file
order) and a warning is logged. Any failure of the decoder on a corrupt or truncated file
(including a Rust panic surfacing as ``PanicException``) becomes a
:class:`~rdnet.errors.FormatError`. Before decoding, the header flatbuffer is checked here
(a non-UTF-8 description makes aedat 2.3 abort the interpreter) and so is the LZ4 frame of
the trailing file data table (a file cut inside it would otherwise decode silently).
"""
from __future__ import annotations

import logging
import re
import struct
from pathlib import Path

import numpy as np

from rdnet.errors import FormatError, RdnetError, ValidationError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.io._common import as_format_error, require_file
from rdnet.events.recording import Frames, Recording

log = logging.getLogger(__name__)

_MAGIC = b"#!AER-DAT4.0\r\n"
_SOURCE_RE = re.compile(r'<attr key="source" type="string">([^<]{1,200})</attr>')
#: Index of the description string (XML) in the IOHeader flatbuffer table
#: (dv-processing ``IOHeader {compression; dataTablePosition; infoNode: string}``).
_DESCRIPTION_FIELD = 2
_TABLE_POSITION_FIELD = 1
_LZ4_MAGIC = b"\x04\x22\x4d\x18"
_MAX_HEADER_BYTES = 1 << 26


def _field_pos(buf: bytes, table: int, vtable: int, index: int) -> int | None:
    """Absolute position of field ``index`` of a flatbuffer table (None if absent)."""
    vt_size = struct.unpack_from("<H", buf, vtable)[0]
    slot = 4 + 2 * index
    off = struct.unpack_from("<H", buf, vtable + slot)[0] if slot + 2 <= vt_size else 0
    return table + off if off else None


def _read_header(path: Path) -> tuple[str, int]:
    """Check the AEDAT 4 header; return its XML description and the position of the file
    data table (-1 if the file has none).

    Done before handing the file to ``aedat.Decoder``: with a description that is not
    valid UTF-8, aedat 2.3 raises inside its constructor and then aborts the whole
    process (a Rust panic in a destructor), which no ``except`` can catch. Parsing the
    IOHeader flatbuffer here turns that case into a :class:`FormatError`.
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(_MAGIC) + 4)
            if len(head) < len(_MAGIC) + 4 or not head.startswith(_MAGIC):
                raise FormatError(path, "header", "not an AEDAT 4.0 file (magic '#!AER-DAT4.0' missing)")
            (length,) = struct.unpack_from("<I", head, len(_MAGIC))
            if length > _MAX_HEADER_BYTES:
                raise FormatError(path, "header", f"implausible header length {length}")
            buf = fh.read(length)
        if len(buf) != length:
            raise FormatError(path, "header", "file ends inside the header")
        table = struct.unpack_from("<I", buf, 0)[0]
        vtable = table - struct.unpack_from("<i", buf, table)[0]
        pos = _field_pos(buf, table, vtable, _TABLE_POSITION_FIELD)
        table_pos = struct.unpack_from("<q", buf, pos)[0] if pos is not None else -1
        pos = _field_pos(buf, table, vtable, _DESCRIPTION_FIELD)
        if pos is None:
            return "", table_pos
        pos += struct.unpack_from("<I", buf, pos)[0]
        (n,) = struct.unpack_from("<I", buf, pos)
        if pos < 0 or vtable < 0 or pos + 4 + n > len(buf):
            raise FormatError(path, "header", "description string outside the header")
        raw = buf[pos + 4:pos + 4 + n]
    except struct.error:
        raise FormatError(path, "header", "corrupt header (offsets outside the header)") from None
    except OSError as e:
        raise FormatError(path, None, f"cannot read ({e.strerror})") from None
    try:
        return raw.decode("utf-8"), table_pos
    except UnicodeDecodeError:
        raise FormatError(path, "header", "corrupt header (description is not UTF-8)") from None


def _check_data_table(path: Path, table_pos: int) -> None:
    """A file truncated inside its trailing data table (the file index, after the last
    packet) still decodes; detect it by walking the LZ4 frame of the table to its end
    mark (LZ4 frame format spec: header, blocks of u32 size, end mark 0, checksums)."""
    if table_pos < 0:
        return
    size = path.stat().st_size
    if table_pos >= size:
        raise FormatError(path, "data table", f"file is truncated (data table at byte {table_pos} "
                                              f"of a {size}-byte file)")
    with open(path, "rb") as fh:
        fh.seek(table_pos)
        buf = fh.read(min(size - table_pos, _MAX_HEADER_BYTES))
    if not buf.startswith(_LZ4_MAGIC):
        return  # uncompressed or zstd table: not checked
    try:
        flg = buf[4]
        i = 7 + (8 if flg & 0x08 else 0) + (4 if flg & 0x01 else 0)
        while True:
            (block,) = struct.unpack_from("<I", buf, i)
            i += 4
            if block == 0:
                break
            i += (block & 0x7FFFFFFF) + (4 if flg & 0x10 else 0)
        i += 4 if flg & 0x04 else 0
        complete = i <= len(buf)
    except (struct.error, IndexError):
        complete = False
    if not complete:
        raise FormatError(path, "data table", "file is truncated (incomplete data table at the end)")


def sensor_name(source: str) -> str:
    """Camera model from a DV source string ("DAVIS346_00000002" -> "DAVIS346")."""
    return re.sub(r"_\d+$", "", source)


def _frame_pixels(frame: dict, path: Path) -> np.ndarray:
    px = np.asarray(frame["pixels"])
    fmt = str(frame.get("format", "L"))
    if fmt == "L" and px.ndim == 2:
        out = px
    elif fmt in ("RGB", "RGBA") and px.ndim == 3 and px.shape[2] in (3, 4):
        out = px[:, :, :3]
    else:
        raise FormatError(path, "frame/pixels", f"unsupported frame format {fmt!r} with shape {px.shape}")
    if out.dtype != np.uint8:
        raise FormatError(path, "frame/pixels", f"expected 8-bit pixels, got {out.dtype}")
    return out


def _decode(path: Path) -> Recording:
    import aedat

    description, table_pos = _read_header(path)
    _check_data_table(path, table_pos)
    decoder = aedat.Decoder(str(path))
    streams = decoder.id_to_stream()
    by_type: dict[str, list[int]] = {}
    for sid in sorted(streams):
        by_type.setdefault(str(streams[sid].get("type")), []).append(sid)
    ev_ids, fr_ids = by_type.get("events", []), by_type.get("frame", [])
    if not ev_ids and not fr_ids:
        raise FormatError(path, "streams", f"no events or frame stream (streams: {streams})")
    desc = streams[(ev_ids or fr_ids)[0]]
    if "width" not in desc or "height" not in desc:
        raise FormatError(path, "width", "stream description has no sensor size")
    width, height = int(desc["width"]), int(desc["height"])
    if len(ev_ids) > 1 or len(fr_ids) > 1:
        log.warning("%s: several event/frame streams; reading the first of each", path)
    ev_id, fr_id = (ev_ids or [None])[0], (fr_ids or [None])[0]

    parts, images, t_mid, exposure = [], [], [], []
    for packet in decoder:
        sid = packet.get("stream_id")
        if "events" in packet and sid == ev_id:
            parts.append(packet["events"])
        elif "frame" in packet and sid == fr_id:
            fr = packet["frame"]
            b, e = int(fr["exposure_begin_t"]), int(fr["exposure_end_t"])
            images.append(_frame_pixels(fr, path))
            t_mid.append((b + e) // 2)
            exposure.append(e - b)

    events = None
    if ev_id is not None:
        raw = np.concatenate(parts) if parts else np.empty(0, [("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("on", "?")])
        arr = np.empty(raw.shape[0], EVENT_DTYPE)
        t = raw["t"]
        if t.size and int(t.max()) > np.iinfo(np.int64).max:
            raise FormatError(path, "events/t", "timestamp beyond int64 range")
        arr["t"], arr["x"], arr["y"], arr["p"] = t.astype(np.int64), raw["x"], raw["y"], raw["on"]
        if arr.size > 1 and np.any(np.diff(arr["t"]) < 0):
            log.warning("%s: event timestamps decrease across packets; sorting stably by time", path)
            arr = arr[np.argsort(arr["t"], kind="stable")]
        try:
            events = Events(arr, width, height)
        except ValidationError as e:
            raise FormatError(path, f"events/{e.field}", str(e).split(": ", 1)[-1]) from None

    frames = None
    if fr_id is not None and images:
        shapes = {im.shape for im in images}
        if len(shapes) > 1:
            raise FormatError(path, "frame/pixels", f"frames of different sizes: {sorted(shapes)}")
        frames = Frames(np.stack(images), np.asarray(t_mid, np.int64), np.asarray(exposure, np.int64))

    m = _SOURCE_RE.search(description)
    source = m.group(1).strip() if m else ""
    return Recording(width, height, events=events, frames=frames, sensor=sensor_name(source) or "AEDAT4",
                     attrs={"aedat_source": source} if source else {})


def read_aedat4(path: str | Path) -> Recording:
    """Read an AEDAT 4 file (see the module docstring for the mapping)."""
    path = require_file(path)
    try:
        import aedat  # noqa: F401
    except ImportError:  # pragma: no cover - aedat is a dependency
        raise FormatError(path, None, "reading AEDAT 4 needs the 'aedat' package (pip install aedat)") from None
    try:
        return _decode(path)
    except FormatError:
        raise
    except RdnetError as e:
        raise as_format_error(path, e) from e
    except (KeyboardInterrupt, SystemExit, GeneratorExit):
        raise
    except BaseException as e:  # noqa: BLE001 - the Rust decoder may panic (PanicException is a BaseException)
        raise as_format_error(path, e, what="corrupt or unsupported AEDAT 4 file") from e
