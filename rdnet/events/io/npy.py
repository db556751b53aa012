"""Plain NumPy ``.npy`` event files: one structured array with fields ``x, y, t, p``.

This is the layout tonic and most Python event tools use (field names and order
``("x", "y", "t", "p")``): ``x``, ``y`` uint16 (y from the top), ``t`` int64
microseconds, ``p`` uint8 (1 = ON, 0 = OFF). The sensor size is NOT stored (a ``.npy``
holds one array only), so reading one back needs ``sensor_size`` (``--width/--height``);
frames are not stored either.

:func:`write_npy_chunks` streams: the header is written with a fixed length, events are
appended chunk by chunk, then the header is rewritten with the final count, all in a
temporary file that replaces the target only on success.
"""
from __future__ import annotations

import logging
import struct
from pathlib import Path
from typing import Iterable

import numpy as np

from rdnet.errors import FormatError
from rdnet.events.core import Events
from rdnet.events.io._common import atomic_output, checked_cast, require_file, wrap_errors
from rdnet.events.recording import Recording

log = logging.getLogger(__name__)

#: The tonic-style structured dtype.
NPY_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "u1")])
#: Header bytes (NPY 1.0, padded with spaces): room for any 1-D count.
_HEADER_BYTES = 128


def _header(n: int) -> bytes:
    body = repr({"descr": np.lib.format.dtype_to_descr(NPY_DTYPE), "fortran_order": False,
                 "shape": (int(n),)}).encode("latin1")
    magic = b"\x93NUMPY\x01\x00"
    hlen = _HEADER_BYTES - len(magic) - 2
    if len(body) + 1 > hlen:  # pragma: no cover - cannot happen for a 1-D shape
        raise ValueError("npy header too long")
    return magic + struct.pack("<H", hlen) + body + b" " * (hlen - len(body) - 1) + b"\n"


def to_npy_array(events: Events) -> np.ndarray:
    out = np.empty(len(events), NPY_DTYPE)
    for k in "xytp":
        out[k] = events.array[k]
    return out


def write_npy_chunks(path: str | Path, chunks: Iterable[Events]) -> int:
    """Write time-sorted event chunks to ``path`` atomically; returns the event count."""
    n = 0
    with wrap_errors(path, what="cannot write"), atomic_output(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(_header(0))
            for ch in chunks:
                fh.write(to_npy_array(ch).tobytes())
                n += len(ch)
            fh.seek(0)
            fh.write(_header(n))
    log.info("%s: .npy holds x, y, t (us), p only; sensor size and frames are not stored", path)
    return n


def write_npy(path: str | Path, rec: Recording) -> None:
    """Write the events of ``rec`` (sensor size and frames are not stored)."""
    if rec.events is None:
        raise FormatError(path, "events", "recording has no events (.npy holds events only)")
    if rec.frames is not None:
        log.warning("%s: %d frames not written (.npy holds events only)", path, len(rec.frames))
    write_npy_chunks(path, [rec.events])


def read_npy(path: str | Path, sensor_size: tuple[int, int] | None) -> Recording:
    """Read a structured ``.npy`` with fields x, y, t, p (any integer types); the sensor
    size is not in the file and must be given."""
    path = require_file(path)
    if sensor_size is None:
        raise FormatError(path, "width/height", ".npy files do not store the sensor size; pass --width/--height")
    with wrap_errors(path):
        try:
            a = np.load(path, mmap_mode="r", allow_pickle=False)
        except ValueError as e:
            raise FormatError(path, "header", f"not a plain .npy array ({e})") from None
        names = a.dtype.names or ()
        missing = [k for k in "xytp" if k not in names]
        if missing:
            raise FormatError(path, missing[0], f"missing field (need x, y, t, p; got {', '.join(names) or a.dtype})")
        if a.ndim != 1:
            raise FormatError(path, "shape", f"expected a 1-D array, got shape {a.shape}")
        cols = {k: checked_cast(np.asarray(a[k]), {"t": np.int64, "p": np.uint8}.get(k, np.uint16), path, k)
                for k in "txyp"}
        ev = Events.from_columns(cols["t"], cols["x"], cols["y"], cols["p"], *sensor_size)
    return Recording(ev.width, ev.height, events=ev)
