"""NumPy ``.npz`` recordings (read and write).

Arrays: ``t`` (int64 us), ``x``, ``y`` (uint16), ``p`` (uint8, 1 = ON) when there are
events; ``frames_images`` ((N,H,W) or (N,H,W,3), uint8 or float32), ``frames_t`` (int64
us, mid exposure), ``frames_exposure_us`` (int64) when there are frames; ``width``,
``height`` (int scalars), ``sensor`` (str scalar) and ``attrs_json`` (JSON of
``Recording.attrs``). Read with ``allow_pickle=False``; written compressed.
"""
from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from rdnet.errors import FormatError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.io._common import atomic_output, checked_cast, require_file, wrap_errors
from rdnet.events.recording import Frames, Recording

_EVENT_KEYS = ("t", "x", "y", "p")
_FRAME_KEYS = ("frames_images", "frames_t", "frames_exposure_us")


def _scalar(z, key: str, path: Path, kind: str):
    if key not in z:
        raise FormatError(path, key, "missing array")
    a = z[key]
    if a.ndim != 0 or a.dtype.kind not in kind:
        raise FormatError(path, key, f"expected a scalar of kind {kind!r}, got {a.dtype} {a.shape}")
    return a.item()


def _load(path: Path, z) -> Recording:
    keys = set(z.files)
    width = _scalar(z, "width", path, "iu")
    height = _scalar(z, "height", path, "iu")
    sensor = _scalar(z, "sensor", path, "U") if "sensor" in keys else ""
    attrs = {}
    if "attrs_json" in keys:
        try:
            attrs = json.loads(_scalar(z, "attrs_json", path, "U"))
        except json.JSONDecodeError as e:
            raise FormatError(path, "attrs_json", f"invalid JSON ({e})") from None
        if not isinstance(attrs, dict):
            raise FormatError(path, "attrs_json", "expected a JSON object")
    events = frames = None
    present = [k for k in _EVENT_KEYS if k in keys]
    if present:
        missing = [k for k in _EVENT_KEYS if k not in keys]
        if missing:
            raise FormatError(path, missing[0], "missing array (t, x, y, p go together)")
        cols = {k: z[k] for k in _EVENT_KEYS}
        n = cols["t"].shape
        arr = np.empty(n[0] if len(n) == 1 else 0, EVENT_DTYPE)
        for k in _EVENT_KEYS:
            if cols[k].ndim != 1 or cols[k].shape != n:
                raise FormatError(path, k, f"expected shape {n} like t, got {cols[k].shape}")
            arr[k] = checked_cast(cols[k], EVENT_DTYPE[k], path, k)
        events = Events(arr, width, height)
    if any(k in keys for k in _FRAME_KEYS):
        missing = [k for k in _FRAME_KEYS if k not in keys]
        if missing:
            raise FormatError(path, missing[0],
                              "missing array (frames_images, frames_t, frames_exposure_us go together)")
        frames = Frames(z["frames_images"], checked_cast(z["frames_t"], np.int64, path, "frames_t"),
                        checked_cast(z["frames_exposure_us"], np.int64, path, "frames_exposure_us"))
    if events is None and frames is None:
        raise FormatError(path, "t", "neither events (t, x, y, p) nor frames")
    return Recording(width, height, events=events, frames=frames, sensor=sensor, attrs=attrs)


def read_npz(path: str | Path) -> Recording:
    """Read a recording written by :func:`write_npz` (or any npz with that layout)."""
    path = require_file(path)
    with wrap_errors(path):
        try:
            with np.load(path, allow_pickle=False) as z:
                return _load(path, z)
        except (zipfile.BadZipFile, zlib.error) as e:
            raise FormatError(path, None, f"corrupt npz ({e})") from None


def _json_default(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"attribute of type {type(v).__name__} is not JSON serializable")


def write_npz(path: str | Path, rec: Recording, *, compressed: bool = True) -> None:
    """Write ``rec`` atomically (temporary file + ``os.replace``)."""
    arrays: dict[str, np.ndarray] = {
        "width": np.int64(rec.width), "height": np.int64(rec.height), "sensor": np.str_(rec.sensor),
        "attrs_json": np.str_(json.dumps(rec.attrs or {}, default=_json_default))}
    if rec.events is not None:
        for k in _EVENT_KEYS:
            arrays[k] = np.ascontiguousarray(rec.events.array[k])
    if rec.frames is not None:
        arrays.update(frames_images=rec.frames.images, frames_t=rec.frames.t_us,
                      frames_exposure_us=rec.frames.exposure_us)
    with wrap_errors(path, what="cannot write"), atomic_output(path) as tmp:
        with open(tmp, "wb") as fh:
            (np.savez_compressed if compressed else np.savez)(fh, **arrays)
