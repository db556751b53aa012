"""ECD / RPG text format (Event Camera Dataset, Mueggler et al., IJRR 2017), read and write.

``events.txt``: one event per line, ``t x y p`` separated by white space, t in seconds
(float), p 0 = OFF / 1 = ON (-1 is read as OFF). An optional first line of two integers
``width height`` gives the sensor size (the rpg_e2vid convention); the writer emits it so
that files round-trip, the reader accepts files with or without it. Lines starting with
``#`` are comments.

``images.txt`` (optional, beside ``events.txt``): ``t path`` per line (t in seconds, path
relative to the folder of images.txt), optionally a third column with the exposure in
seconds (written by rdnet when known, absent in ECD). The t of a frame is taken as the
middle of its exposure. Images are read with OpenCV (8-bit grey or colour PNG/JPEG, or
32-bit float TIFF for float32 frames).

The text format does not always carry the sensor size and it is never inferred silently:
:func:`read_text` needs ``width``/``height`` (or the header line); only with
``infer_size=True`` (what ``rdnet.events.io.load`` does when no ``sensor_size`` is given)
is it taken as max(x) + 1, max(y) + 1, with a logged warning.
"""
from __future__ import annotations

import contextlib
import logging
from pathlib import Path

import numpy as np

from rdnet.errors import FormatError, ValidationError
from rdnet.events.core import EVENT_DTYPE, Events
from rdnet.events.io._common import (as_format_error, atomic_output, check_frame_image, remove_quietly, require_file,
                                     wrap_errors)
from rdnet.events.recording import Frames, Recording

log = logging.getLogger(__name__)

IMAGES_TXT = "images.txt"
IMAGES_DIR = "images"
#: the UTF-8 byte order mark some editors write first (pandas skips it in the table)
_BOM = b"\xef\xbb\xbf"


def _size_header(path: Path) -> tuple[int, int] | None:
    """(width, height) if the first non-comment line is two integers, else None."""
    with open(path, "rb") as fh:
        for raw in fh:
            line = raw.removeprefix(_BOM).strip()     # an editor's UTF-8 byte order mark
            if not line or line.startswith(b"#"):
                continue
            tok = line.split()
            if len(tok) == 2 and all(t.isdigit() for t in tok):
                w, h = int(tok[0]), int(tok[1])
                if w <= 0 or h <= 0:
                    raise FormatError(path, "width/height", f"header gives sensor size {w}x{h}")
                return w, h
            return None
    return None


def _read_table(path: Path, ncols: int | tuple[int, ...], skip_header: bool, names: str, dtype=np.float64):
    """Vectorized parse of a white-space separated table (pandas C parser)."""
    import pandas as pd

    ok = (ncols,) if isinstance(ncols, int) else ncols
    try:
        df = pd.read_csv(path, sep=r"\s+", header=None, comment="#", skiprows=_skip_rows(path) if skip_header else None,
                         dtype=dtype, engine="c", quoting=3)  # 3 = csv.QUOTE_NONE
    except pd.errors.EmptyDataError:
        return None
    except (ValueError, pd.errors.ParserError) as e:
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise FormatError(path, names, f"cannot parse ({msg})") from None
    if df.shape[1] not in ok:
        raise FormatError(path, names, f"expected {' or '.join(map(str, ok))} columns, got {df.shape[1]}")
    return df


def _skip_rows(path: Path) -> int:
    """Number of leading lines up to and including the size header."""
    with open(path, "rb") as fh:
        for i, raw in enumerate(fh):
            line = raw.removeprefix(_BOM).strip()
            if line and not line.startswith(b"#"):
                return i + 1
    return 0


def _first_bad_row(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def read_text_events(path: str | Path, width: int | None = None, height: int | None = None, *,
                     infer_size: bool = False) -> Events:
    """Events of an ECD ``events.txt`` (see the module docstring for the sensor size)."""
    path = require_file(path)
    with wrap_errors(path, "events"):
        header = _size_header(path)
        df = _read_table(path, 4, header is not None, "events")
    if df is None or len(df) == 0:
        cols = np.zeros((0, 4))
    else:
        cols = df.to_numpy(np.float64)
    bad = ~np.isfinite(cols).all(axis=1)
    if bad.any():
        raise FormatError(path, "events", f"event {_first_bad_row(bad)}: expected 4 numbers 't x y p'")
    t_s, x, y, p = cols.T
    for name, c in (("x", x), ("y", y)):
        wrong = (c != np.round(c)) | (c < 0) | (c > np.iinfo(np.uint16).max)
        if wrong.any():
            i = _first_bad_row(wrong)
            raise FormatError(path, f"events/{name}", f"event {i}: {name}={c[i]} is not a pixel coordinate")
    wrong = ~np.isin(p, (-1.0, 0.0, 1.0))
    if wrong.any():
        i = _first_bad_row(wrong)
        raise FormatError(path, "events/p", f"event {i}: polarity {p[i]}; must be 0/1 (or -1/1)")
    t_us = np.rint(t_s * 1e6)
    if t_us.size and np.abs(t_us).max() > 2.0 ** 62:
        raise FormatError(path, "events/t", "timestamp out of range")
    if width is None or height is None:
        if header is not None:
            width, height = header
        elif infer_size and x.size:
            width, height = int(x.max()) + 1, int(y.max()) + 1
            log.warning("%s: sensor size not given; inferred %dx%d from the largest coordinates "
                        "(pass --width/--height or sensor_size to set it)", path, width, height)
        else:
            raise FormatError(path, "width/height", "sensor size unknown: the text format has no size header; "
                                                    "pass width and height (--width/--height)")
    elif header is not None and header != (width, height):
        raise FormatError(path, "width/height", f"header says {header[0]}x{header[1]}, caller says {width}x{height}")
    arr = np.empty(t_us.shape[0], EVENT_DTYPE)
    arr["t"], arr["x"], arr["y"], arr["p"] = t_us.astype(np.int64), x, y, p > 0
    try:
        return Events(arr, width, height)
    except ValidationError as e:
        raise FormatError(path, f"events/{e.field}", str(e).split(": ", 1)[-1]) from None


def read_text_frames(images_txt: str | Path) -> Frames:
    """Frames listed in an ``images.txt`` (paths relative to its folder)."""
    import cv2

    images_txt = require_file(images_txt)
    with wrap_errors(images_txt, "images"):
        df = _read_table(images_txt, (2, 3), False, "images", dtype={0: np.float64, 1: str, 2: np.float64})
    if df is None or len(df) == 0:
        raise FormatError(images_txt, "images", "lists no images")
    t_s = df[0].to_numpy(np.float64)
    exp_s = df[2].to_numpy(np.float64) if df.shape[1] == 3 else np.zeros_like(t_s)
    if not (np.isfinite(t_s).all() and np.isfinite(exp_s).all()):
        raise FormatError(images_txt, "images", "missing or non-numeric time/exposure")
    folder = images_txt.parent
    images, first = [], None
    for name in df[1].tolist():
        f = folder / str(name)
        img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED) if f.is_file() else None
        if img is None:
            raise FormatError(f, "images", "missing or unreadable image")
        check_frame_image(f, img, first, f"frame list ({IMAGES_TXT})")
        first = img.dtype
        if img.ndim == 3:
            img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)
        if img.dtype == np.uint16:
            img = img.astype(np.float32) / 65535.0
        if images and img.shape != images[0].shape:
            raise FormatError(f, "images", f"size {img.shape} differs from the first image {images[0].shape}")
        images.append(img)
    with wrap_errors(images_txt, "images"):
        return Frames(np.stack(images), np.rint(t_s * 1e6).astype(np.int64), np.rint(exp_s * 1e6).astype(np.int64))


def read_text(path: str | Path, width: int | None = None, height: int | None = None, *,
              infer_size: bool = False, sensor: str = "") -> Recording:
    """Recording of an ``events.txt`` plus the ``images.txt`` beside it, if any."""
    path = require_file(path)
    events = read_text_events(path, width, height, infer_size=infer_size)
    images_txt = path.parent / IMAGES_TXT
    frames = read_text_frames(images_txt) if images_txt.is_file() and images_txt != path else None
    if len(events) == 0 and frames is None:
        raise FormatError(path, "events", "no events")
    with wrap_errors(path):
        return Recording(events.width, events.height, events=events, frames=frames, sensor=sensor)


def _encode_image(img: np.ndarray) -> tuple[str, bytes]:
    import cv2

    ext = ".png" if img.dtype == np.uint8 else ".tiff"
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(ext, img)
    if not ok:  # pragma: no cover
        raise FormatError(None, "images", f"OpenCV cannot encode {img.dtype} {img.shape} as {ext}")
    return ext, buf.tobytes()


def write_text(path: str | Path, rec: Recording, *, size_header: bool = True) -> None:
    """Write ``rec`` as ``events.txt`` at ``path`` (t in seconds with 6 decimals) and, if it
    has frames, ``images.txt`` + ``images/frame_XXXXXXXX.png`` (uint8) or ``.tiff``
    (float32) beside it. Each file is written atomically; on failure the images written so
    far are removed."""
    import pandas as pd

    path = Path(path)
    written: list[Path] = []
    made_dir = None
    try:
        lines_img = None
        if rec.frames is not None and len(rec.frames):
            fr = rec.frames
            img_dir = path.parent / IMAGES_DIR
            if not img_dir.exists():
                made_dir = img_dir
            img_dir.mkdir(exist_ok=True)
            rows = []
            with_exposure = bool(np.any(fr.exposure_us > 0))
            for i in range(len(fr)):
                ext, data = _encode_image(fr.images[i])
                rel = f"{IMAGES_DIR}/frame_{i:08d}{ext}"
                with atomic_output(path.parent / rel) as tmp:
                    tmp.write_bytes(data)
                written.append(path.parent / rel)
                exp = f" {fr.exposure_us[i] / 1e6:.6f}" if with_exposure else ""
                rows.append(f"{fr.t_us[i] / 1e6:.6f} {rel}{exp}")
            lines_img = "\n".join(rows) + "\n"
        if lines_img is not None:
            with atomic_output(path.parent / IMAGES_TXT) as tmp:
                tmp.write_text(lines_img)
        ev = rec.events if rec.events is not None else Events.empty(rec.width, rec.height)
        df = pd.DataFrame({"t": ev.t / 1e6, "x": ev.x, "y": ev.y, "p": ev.p})
        with atomic_output(path) as tmp:
            with open(tmp, "w", newline="\n") as fh:
                if size_header:
                    fh.write(f"{rec.width} {rec.height}\n")
                df.to_csv(fh, sep=" ", header=False, index=False, float_format="%.6f", lineterminator="\n")
    except BaseException as e:
        for f in written:
            remove_quietly(f)
        if made_dir is not None:
            with contextlib.suppress(OSError):
                made_dir.rmdir()                             # only when empty: nothing of ours left
        if isinstance(e, OSError):
            raise as_format_error(path, e, what="cannot write") from e
        raise


__all__ = ["read_text", "read_text_events", "read_text_frames", "write_text", "IMAGES_TXT"]
