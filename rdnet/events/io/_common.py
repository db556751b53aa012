"""Helpers shared by the recording formats: atomic output files and error wrapping.

Every reader turns whatever goes wrong with a file (missing, unreadable, corrupt,
inconsistent) into one :class:`~rdnet.errors.FormatError` naming the file and the field;
every writer writes to a temporary name in the target folder and ``os.replace``-s it
on success, so a failure never leaves a partial output file.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from rdnet.errors import FormatError, RdnetError, ValidationError

#: Exceptions that third-party decoders (h5py, zipfile, pandas, aedat, cv2) raise on bad
#: input. ``MemoryError`` is included because a corrupt header may claim a huge array.
DECODE_ERRORS: tuple[type[BaseException], ...] = (
    OSError, ValueError, KeyError, TypeError, RuntimeError, IndexError, EOFError,
    MemoryError, OverflowError, UnicodeDecodeError)


def require_file(path: str | Path) -> Path:
    """``path`` as a Path; :class:`FormatError` if it is not an existing regular file."""
    p = Path(path)
    if not p.exists():
        raise FormatError(p, None, "no such file")
    if not p.is_file():
        raise FormatError(p, None, "not a regular file")
    if not os.access(p, os.R_OK):
        raise FormatError(p, None, "permission denied")
    return p


def as_format_error(path: str | Path, exc: BaseException, field: str | None = None,
                    what: str = "cannot read") -> FormatError:
    """Convert ``exc`` into a :class:`FormatError` naming ``path`` (and the field)."""
    if isinstance(exc, FormatError):
        return exc
    if isinstance(exc, ValidationError):
        return FormatError(path, field or exc.field, str(exc).split(": ", 1)[-1])
    if isinstance(exc, RdnetError):
        return FormatError(path, field, str(exc))
    msg = str(exc).strip() or type(exc).__name__
    if isinstance(exc, MemoryError):
        msg = "data too large to load (corrupt header?)"
    return FormatError(path, field, f"{what} ({type(exc).__name__}: {msg.splitlines()[0]})")


@contextlib.contextmanager
def wrap_errors(path: str | Path, field: str | None = None, what: str = "cannot read") -> Iterator[None]:
    """Context manager: re-raise :data:`DECODE_ERRORS` and :class:`ValidationError`
    as :class:`FormatError` for ``path``."""
    try:
        yield
    except FormatError:
        raise
    except (ValidationError, RdnetError) + DECODE_ERRORS as e:
        raise as_format_error(path, e, field, what) from e


def check_sensor_size(path: str | Path, size: tuple[int, int], requested: tuple[int, int] | None) -> None:
    """:class:`FormatError` naming ``width/height`` when a requested sensor size (width, height)
    differs from the one the file states (``requested`` None: nothing to check)."""
    if requested is not None and tuple(int(v) for v in requested) != tuple(int(v) for v in size):
        raise FormatError(path, "width/height", f"file says {size[0]}x{size[1]}, "
                                                f"requested {requested[0]}x{requested[1]}")


def check_frame_image(path: str | Path, img: np.ndarray, first: np.dtype | None, source: str) -> None:
    """A decoded image of a list of frames (a frame folder, an ``images.txt``): the bit depth
    of the first image of the list (``first``; None for the first itself), since each is scaled
    by its own full scale and mixed depths are two sources, and a float image within [0, 1]
    (float frames are linear intensity; 255.0 is an 8-bit value stored as a float).
    :class:`FormatError` naming the image otherwise."""
    if first is not None and img.dtype != first:
        raise FormatError(path, None, f"image is {img.dtype} ({8 * img.dtype.itemsize}-bit), the first "
                          f"is {first} ({8 * first.itemsize}-bit): one bit depth per {source}")
    if img.dtype.kind == "f":
        bad = ~((img >= 0) & (img <= 1))                      # NaN too
        if bad.any():
            raise FormatError(path, None, f"{img.dtype} image holds values outside [0, 1] (e.g. "
                              f"{img[bad].flat[0]:g}): float frames are linear intensity in [0, 1]")


#: bytes of the output name a temporary name keeps: file systems take 255 a name and the
#: temporary one adds 14 (".", "." + 8 random characters, ".tmp")
TEMP_NAME_KEEP_BYTES = 200


def _short(name: str) -> str:
    """``name`` cut to :data:`TEMP_NAME_KEEP_BYTES` of UTF-8 (whole characters), so a name
    that fits the file system still does with the temporary name's additions."""
    return name.encode()[:TEMP_NAME_KEEP_BYTES].decode(errors="ignore")


def temp_path_for(path: str | Path) -> Path:
    """A fresh, unused temporary file name in the folder of ``path`` (same file system,
    so ``os.replace`` is atomic). The file is created empty."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise FormatError(path, None, f"output folder {str(folder)!r} {what}")
    try:
        fd, name = tempfile.mkstemp(prefix=f".{_short(path.name)}.", suffix=".tmp", dir=folder)
        os.close(fd)
        os.chmod(name, 0o666 & ~_umask())   # mkstemp makes 0600; give the final file the usual mode
    except OSError as e:
        raise FormatError(path, None, f"cannot write ({e.strerror or e})") from None
    return Path(name)


def remove_quietly(path: str | Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on normal exit it replaces ``path``
    (``os.replace``), on an exception it is deleted and ``path`` is left untouched."""
    path = Path(path)
    if path.is_dir():
        raise _taken_by_folder(path)
    tmp = temp_path_for(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        remove_quietly(tmp)
        raise


@contextlib.contextmanager
def atomic_directory(path: str | Path) -> Iterator[Path]:
    """Yield a fresh staging folder next to ``path``; on normal exit its content lands in
    ``path``, on an exception it is deleted and ``path`` is left untouched.

    When ``path`` does not exist the staging folder is renamed to it (one atomic step);
    otherwise each staged file replaces its namesake inside ``path`` (``os.replace``)
    and files of ``path`` that were not staged are kept."""
    import shutil
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FormatError(path, None, "exists and is not a folder")
    parent = path.parent if str(path.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{_short(path.name)}.", suffix=".tmp", dir=parent))
    except OSError as e:
        raise FormatError(path, None, f"cannot write ({e.strerror or e})") from None
    try:
        yield stage
        if not path.exists():
            os.chmod(stage, 0o777 & ~_umask())
            os.replace(stage, path)
            return
        staged = sorted(stage.rglob("*"))
        for src in staged:              # every clash first: a failed merge moves nothing
            dst = path / src.relative_to(stage)
            if src.is_dir() and dst.exists() and not dst.is_dir():
                raise FormatError(dst, None, "exists and is not a folder (a folder is written there)")
            if not src.is_dir() and dst.is_dir():
                raise _taken_by_folder(dst)
        try:
            for src in staged:
                dst = path / src.relative_to(stage)
                if src.is_dir():
                    dst.mkdir(exist_ok=True)
                else:
                    os.replace(src, dst)
        except OSError as e:
            raise FormatError(path, None, f"cannot write ({e.strerror or e})") from None
        shutil.rmtree(stage, ignore_errors=True)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise


def _taken_by_folder(path: Path) -> FormatError:
    """The error for an output file whose name a folder already takes."""
    return FormatError(path, None, "exists and is a folder (a file is written there)")


def refuse_input_as_output(output: str | Path, *inputs: str | Path) -> None:
    """FormatError when ``output`` is one of ``inputs`` (after resolving links): writing it
    would replace the data being read."""
    out = Path(output)
    try:
        resolved = out.resolve()                   # also when it does not exist: a loop is refused here
        same = any(Path(i).exists() and resolved == Path(i).resolve() for i in inputs)
    except (OSError, RuntimeError) as e:          # a symlink loop (RuntimeError before Python 3.13)
        raise FormatError(out, None, f"cannot resolve the path ({e})") from None
    if same:
        raise FormatError(out, None, "output is the input file")


def check_output_folder(path: str | Path, files: Iterable[str] = (), inputs: Iterable[str | Path] = ()) -> Path:
    """Fail early, before the work, for an output folder that cannot take the output:
    ``path`` exists and is not a folder, one of the ``files`` it will hold exists there as a
    folder or is one of the ``inputs`` (:func:`refuse_input_as_output`), or its nearest
    existing ancestor cannot be written to (FormatError naming it). Creates nothing (the
    write probe is an unnamed temporary file)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FormatError(path, None, "exists and is not a folder (the output folder)")
    for name in files:
        if (path / name).is_dir():
            raise _taken_by_folder(path / name)
        refuse_input_as_output(path / name, *inputs)
    probe = path
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise FormatError(probe, None, f"is not a folder, so {path} cannot be created")
    try:                                       # a real probe: os.access says yes to root on a read-only mount
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as e:
        raise FormatError(probe, None, f"cannot be written to ({e.strerror or e})") from None
    return path


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def checked_cast(values: np.ndarray, target, path, field: str) -> np.ndarray:
    """Cast an integer column to ``target``; values that do not fit raise FormatError."""
    target = np.dtype(target)
    if values.dtype.kind not in "iub":
        raise FormatError(path, field, f"expected an integer dtype ({target}), got {values.dtype}")
    if values.dtype == target:
        return values
    if values.size and values.dtype.kind != "b":
        info = np.iinfo(target)
        lo, hi = int(values.min()), int(values.max())
        if lo < info.min or hi > info.max:
            raise FormatError(path, field, f"value {lo if lo < info.min else hi} does not fit {target}")
    return values.astype(target)
