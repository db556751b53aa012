"""Frame sources for the simulator: HDF5 recordings, video files, image folders.

Everything comes out as :class:`rdnet.events.Frames` with float32 *linear* intensity in
[0, 1]. 8-bit video and image files are gamma-encoded (GOPRO frames are sRGB-like PNGs,
Nah et al. 2017 synthesised their blur after approximately undoing the camera response),
so by default (``linearize=None`` -> True for video/images) they are decoded with the sRGB
transfer function (IEC 61966-2-1); ``linearize=False`` only divides by the full scale.
HDF5 recordings are taken as stored (float32 linear, or uint8 / 255 as :meth:`Frames.linear`
does; APS frames of a DAVIS are close to linear) unless ``linearize=True``.

Timestamps (integer microseconds, frame centres; ``exposure_us`` = 0 when unknown):
HDF5 -> stored (or ``i * 1e6 / fps_hz`` when given); video -> ``i * 1e6 / fps`` with ``fps``
= ``fps_hz`` if given, else the container's ``CAP_PROP_FPS``; when the container has no
rate, the decoder's ``CAP_PROP_POS_MSEC`` (must increase);
folders -> ``i * 1e6 / fps_hz`` with ``fps_hz`` defaulting to 240 (GOPRO).
"""
from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from rdnet.errors import ConfigError, FormatError
from rdnet.events.io._common import check_frame_image
from rdnet.events.io.dispatch import FORMATS
from rdnet.events.recording import Frames
from rdnet.sim.scenes import srgb_to_linear

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".avi", ".mp4", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")
#: the HDF5 names the event readers take (rdnet.events.io.dispatch.FORMATS), so a frame
#: source and a recording are named alike
HDF5_SUFFIXES = tuple(s for s, kind in FORMATS.items() if kind == "hdf5")
#: frames a video may decode short of the count its container declares (some containers
#: round it); more missing means a truncated or corrupt file, an error
VIDEO_FRAME_COUNT_SLACK = 1
#: GOPRO (Nah et al. 2017) was recorded at 240 frames per second.
GOPRO_FPS_HZ = 240.0


def _natural_key(p: Path):
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]


def _to_linear(img: np.ndarray, linearize: bool) -> np.ndarray:
    """uint8/uint16 BGR(A)/grey image -> float32 RGB/grey in [0, 1]."""
    if img.ndim == 3:
        img = img[..., :3][..., ::-1] if img.shape[2] >= 3 else img[..., 0]
    if img.dtype == np.uint8:
        v = img.astype(np.float32) / np.float32(255.0)
    elif img.dtype == np.uint16:
        v = img.astype(np.float32) / np.float32(65535.0)
    else:
        v = np.clip(img.astype(np.float32), 0, 1)
    return srgb_to_linear(v) if linearize else np.ascontiguousarray(v)


def _times(n0: int, n: int, fps_hz: float) -> np.ndarray:
    return np.rint(np.arange(n0, n0 + n) * (1e6 / fps_hz)).astype(np.int64)


def _check_args(max_frames, fps_hz, chunk_frames=1):
    if max_frames is not None and max_frames < 1:
        raise ConfigError("max_frames", f"must be >= 1, got {max_frames}")
    if fps_hz is not None and not (fps_hz > 0 and np.isfinite(fps_hz)):
        raise ConfigError("fps_hz", f"must be > 0, got {fps_hz}")
    if chunk_frames < 1:
        raise ConfigError("chunk_frames", f"must be >= 1, got {chunk_frames}")


def source_kind(path: str | Path) -> str:
    """'hdf5', 'video' or 'folder' (FormatError for anything else / missing)."""
    p = Path(path)
    if p.is_dir():
        return "folder"
    if not p.exists():
        raise FormatError(p, None, "no such file or folder")
    suf = p.suffix.lower()
    if suf in HDF5_SUFFIXES:
        return "hdf5"
    if suf in VIDEO_SUFFIXES:
        return "video"
    raise FormatError(p, None, f"unsupported frame source '{suf}'; use an HDF5 recording, "
                      f"a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of images")


def folder_images(path: str | Path) -> list[Path]:
    """Image files of a frame folder in natural order; a GOPRO sequence folder
    (``<seq>/sharp/*.png``) is read from its ``sharp`` subfolder."""
    p = Path(path)
    if (p / "sharp").is_dir():
        p = p / "sharp"
    named = [q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES]
    broken = sorted((q for q in named if q.is_symlink() and not q.exists()), key=_natural_key)
    if broken:       # a frame that silently went missing would shift every later timestamp
        raise FormatError(broken[0], None, f"broken symbolic link in the frame folder ({len(broken)} such)")
    files = sorted((q for q in named if q.is_file()), key=_natural_key)
    if not files:
        raise FormatError(p, None, f"folder has no image files ({', '.join(IMAGE_SUFFIXES)})")
    return files


def _iter_folder(path, max_frames, fps_hz, linearize, chunk_frames) -> Iterator[Frames]:
    files = folder_images(path)
    if max_frames is not None:
        files = files[:max_frames]
    fps = GOPRO_FPS_HZ if fps_hz is None else fps_hz
    shape = dtype = None
    for s in range(0, len(files), chunk_frames):
        ims = []
        for q in files[s:s + chunk_frames]:
            img = cv2.imread(str(q), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise FormatError(q, None, "cannot decode image")
            check_frame_image(q, img, dtype, "frame folder")
            dtype = img.dtype
            img = _to_linear(img, linearize)
            if shape is None:
                shape = img.shape
            elif img.shape != shape:
                raise FormatError(q, None, f"image shape {img.shape} differs from the first's {shape}")
            ims.append(img)
        yield Frames(np.stack(ims), _times(s, len(ims), fps), np.zeros(len(ims), np.int64))


def _iter_video(path, max_frames, fps_hz, linearize, chunk_frames) -> Iterator[Frames]:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise FormatError(path, None, "cannot open video")
    try:
        fps = fps_hz if fps_hz is not None else float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        n_read, last_t = 0, None
        buf, ts = [], []
        while max_frames is None or n_read < max_frames:
            ok, img = cap.read()
            if not ok:
                break
            if fps > 0:
                t = int(round(n_read * 1e6 / fps))
            else:
                t = int(round(cap.get(cv2.CAP_PROP_POS_MSEC) * 1e3))
                if last_t is not None and t <= last_t:
                    raise FormatError(path, "timestamps", "video has no frame rate and its decoder "
                                      "timestamps do not increase; pass fps_hz")
            buf.append(_to_linear(img, linearize))
            ts.append(t)
            last_t = t
            n_read += 1
            if len(buf) == chunk_frames:
                yield Frames(np.stack(buf), np.asarray(ts, np.int64), np.zeros(len(buf), np.int64))
                buf, ts = [], []
        if buf:
            yield Frames(np.stack(buf), np.asarray(ts, np.int64), np.zeros(len(buf), np.int64))
        if n_read == 0:
            raise FormatError(path, None, "video has no decodable frames")
        wanted = declared if max_frames is None else min(declared, max_frames)
        if n_read < wanted - VIDEO_FRAME_COUNT_SLACK:
            raise FormatError(path, None, f"video ends after {n_read} of the {declared} frames its header "
                              "declares (truncated or undecodable)")
    finally:
        cap.release()


def _iter_hdf5(path, max_frames, fps_hz, linearize, chunk_frames, as_stored=False) -> Iterator[Frames]:
    from rdnet.events.io import read_frames
    s = 0
    while max_frames is None or s < max_frames:
        e = s + chunk_frames if max_frames is None else min(s + chunk_frames, max_frames)
        fr = read_frames(path, s, e)
        if fr is None:
            raise FormatError(path, "frames", "recording has no frames")
        n = len(fr)
        if n == 0:
            if s == 0:
                raise FormatError(path, "frames", "recording has no frames")
            break
        ims = fr.images
        if linearize:
            ims = srgb_to_linear(ims.astype(np.float32) / np.float32(255.0 if ims.dtype == np.uint8 else 1.0))
        elif not as_stored:
            ims = fr.linear()
        if fps_hz is None:
            yield Frames(ims, fr.t_us, fr.exposure_us)
        else:
            yield Frames(ims, _times(s, n, fps_hz), np.zeros(n, np.int64))
        if n < e - s:
            break
        s += n


def iter_frames(path: str | Path, *, max_frames: int | None = None, fps_hz: float | None = None,
                linearize: bool | None = None, chunk_frames: int = 256, as_stored: bool = False
                ) -> Iterator[Frames]:
    """Stream the frames of ``path`` in chunks of at most ``chunk_frames`` (timestamps
    continue across chunks). See the module docstring for timestamps and linearization.
    ``as_stored``: frames of an HDF5 recording that is not linearized come as stored
    (uint8 stays uint8, 4x less memory and output; :meth:`Frames.linear` gives the same
    float32 values); video and image frames are float32 linear either way."""
    _check_args(max_frames, fps_hz, chunk_frames)
    kind = source_kind(path)
    lin = (kind != "hdf5") if linearize is None else bool(linearize)
    if kind == "hdf5":
        yield from _iter_hdf5(Path(path), max_frames, fps_hz, lin, chunk_frames, as_stored)
        return
    it = {"video": _iter_video, "folder": _iter_folder}[kind]
    yield from it(Path(path), max_frames, fps_hz, lin, chunk_frames)


def open_frames(path: str | Path, *, max_frames: int | None = None, fps_hz: float | None = None,
                linearize: bool | None = None) -> Frames:
    """All frames of an HDF5 recording, a video file or an image folder as float32 linear
    :class:`Frames` (FormatError when missing, unreadable or empty)."""
    parts = list(iter_frames(path, max_frames=max_frames, fps_hz=fps_hz, linearize=linearize))
    if not parts:
        raise FormatError(path, "frames", "no frames")
    if len(parts) == 1:
        return parts[0]
    return Frames(np.concatenate([p.images for p in parts]), np.concatenate([p.t_us for p in parts]),
                  np.concatenate([p.exposure_us for p in parts]))
