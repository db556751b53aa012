"""``load`` / ``save`` a recording, choosing the format by file suffix.

=================  ==========================  ============
suffix             format                      read / write
=================  ==========================  ============
.h5, .hdf5         rdnet HDF5 layout           both
.aedat4            AEDAT 4 (iniVation DV)      read
.txt               ECD / RPG text              both
.npz               NumPy arrays                both
.raw               Prophesee RAW (EVT 2/3)     read
.dat               Prophesee DAT               read
.npy               x, y, t, p structured array both (reading needs the sensor size)
=================  ==========================  ============
"""
from __future__ import annotations

import logging
from pathlib import Path

from rdnet.errors import FormatError
from rdnet.events.io._common import check_sensor_size, require_file
from rdnet.events.recording import Recording

log = logging.getLogger(__name__)

FORMATS = {".h5": "hdf5", ".hdf5": "hdf5", ".aedat4": "aedat4", ".txt": "text", ".npz": "npz",
           ".raw": "prophesee_raw", ".dat": "prophesee_dat", ".npy": "npy"}
WRITABLE = ("hdf5", "text", "npz", "npy")


def format_of(path: str | Path) -> str:
    """Format name for ``path``'s suffix; :class:`FormatError` for an unknown suffix."""
    suffix = Path(path).suffix.lower()
    try:
        return FORMATS[suffix]
    except KeyError:
        raise FormatError(path, None, f"unknown recording suffix {suffix!r}; "
                                      f"known: {', '.join(sorted(FORMATS))}") from None


def _check_size(path: Path, rec: Recording, sensor_size: tuple[int, int] | None) -> Recording:
    check_sensor_size(path, (rec.width, rec.height), sensor_size)
    return rec


def load(path: str | Path, *, sensor_size: tuple[int, int] | None = None) -> Recording:
    """Read a recording. ``sensor_size=(width, height)`` is needed for text files without a
    size header (when absent it is inferred from the coordinates, with a warning) and for
    .npy files (required); for
    formats that store the size it is checked against the file."""
    fmt = format_of(path)
    path = require_file(path)
    if fmt == "text":
        from rdnet.events.io.text import read_text
        w, h = sensor_size if sensor_size is not None else (None, None)
        return read_text(path, w, h, infer_size=sensor_size is None)
    if fmt == "hdf5":
        from rdnet.events.io.hdf5 import read_recording
        rec = read_recording(path)
    elif fmt in ("prophesee_raw", "prophesee_dat"):
        from rdnet.events.io.prophesee import read_prophesee
        rec = read_prophesee(path, sensor_size=sensor_size)
    elif fmt == "npy":
        from rdnet.events.io.npy import read_npy
        rec = read_npy(path, sensor_size)
    elif fmt == "aedat4":
        from rdnet.events.io.aedat4 import read_aedat4
        rec = read_aedat4(path)
    else:
        from rdnet.events.io.npz import read_npz
        rec = read_npz(path)
    return _check_size(path, rec, sensor_size)


def save(path: str | Path, rec: Recording, **kw) -> None:
    """Write ``rec`` in the format of ``path``'s suffix (atomically); ``kw`` go to the
    format's writer (e.g. ``extra_events``/``attrs``/``compression`` for HDF5)."""
    fmt = format_of(path)
    if fmt not in WRITABLE:
        raise FormatError(path, None, f"{fmt} is read-only; write .h5, .txt, .npz or .npy")
    if fmt == "hdf5":
        from rdnet.events.io.hdf5 import write_recording
        write_recording(path, rec, **kw)
    elif fmt == "text":
        from rdnet.events.io.text import write_text
        write_text(path, rec, **kw)
    elif fmt == "npy":
        from rdnet.events.io.npy import write_npy
        write_npy(path, rec, **kw)
    else:
        from rdnet.events.io.npz import write_npz
        write_npz(path, rec, **kw)
