"""GOPRO-style blurry/sharp pairs with their event voxel grids, and the pairs file.

Blur synthesis follows GOPRO (Nah et al., "Deep Multi-scale CNN for Dynamic Scene
Deblurring", CVPR 2017): a blurry frame is the mean of ``n`` consecutive sharp frames in
*linear* intensity (n odd, drawn uniformly in [min_frames, max_frames]: GOPRO uses 7..13),
and the sharp target is the middle one. Exposure window (the convention of this module):
from the timestamp of the first averaged frame to that of the last, inclusive,
``[t0_us, t0_us + duration_us]`` with ``duration_us = t_last - t_first`` -- exactly the
span over which the averaged latent frames vary, so the events of the window explain the
blur (EDI model, Pan et al. CVPR 2019). The voxel grids are
``rdnet.events.voxel_grid(events, bins, t0_us, duration_us)``, which selects the events with
``t0_us <= t <= t0_us + duration_us`` (paper Eq. 7 for ``mode='hard'``). Consecutive
windows are separated by ``gap_frames`` unused sharp frames (0: back to back).

The pairs file layout is the contract of DATA.md (``data/pairs/{split}.h5``). Besides the
signed voxels, the file holds the per-polarity count voxels ``voxel_{kind}_on`` /
``voxel_{kind}_off`` (N, bins, H, W) (ON and OFF event counts per bin,
``voxel_grid(..., polarity="split")``; ``voxel_{kind} == _on - _off`` in ``hard`` mode):
the input and target of the count-output restoration network. They are optional for
readers (files written before them stay readable; :data:`POLARITY_KEYS`).
"""
from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Iterable, Mapping, Optional

import h5py
import numpy as np

from rdnet.config import check_bounds
from rdnet.errors import ConfigError, FormatError, ValidationError
from rdnet.events.core import Events
from rdnet.events.recording import Frames
from rdnet.events.voxel import voxel_grid
from rdnet.sim.settings import DegradeConfig

log = logging.getLogger(__name__)

DEGRADE_KEYS = tuple(f.name for f in fields(DegradeConfig))
#: degrade keys added after pairs files were written: files without them read the default
LATER_DEGRADE_KEYS = {"cutoff_floor": DegradeConfig.cutoff_floor}
ARRAY_KEYS = ("blurry", "sharp", "voxel_undegraded", "voxel_degraded", "sequence", "t0_us",
              "duration_us", "level")
#: optional per-polarity count voxels (written by :func:`make_samples`; older files lack them).
POLARITY_KEYS = ("voxel_undegraded_on", "voxel_undegraded_off", "voxel_degraded_on", "voxel_degraded_off")
#: the sharp frames at the start and the end of each blur window (optional datasets; the
#: ``frame_pair`` guide of stage 1, :mod:`rdnet.nn.guide`)
FRAME_KEYS = ("frame_first", "frame_last")
_DTYPES = {**{k: np.float32 for k in POLARITY_KEYS + FRAME_KEYS}, "blurry": np.float32, "sharp": np.float32, "voxel_undegraded": np.float32,
           "voxel_degraded": np.float32, "sequence": np.int32, "t0_us": np.int64,
           "duration_us": np.int64, "level": np.float64}

#: bounds of the ``blur`` keys (checked by :func:`rdnet.config.check_bounds`)
UPPER_BOUNDS = {
    # sharp frames averaged per blurry frame (GOPRO: 7-13), held in memory at once; every count
    # in between is listed (1e9 would exhaust the memory); odd: the target is the middle frame
    "min_frames": 1001, "max_frames": 1001,
    # frames of a sequence at most (``scenes.n_frames``' bound): more skip or more samples
    # than a sequence has frames
    "gap_frames": 1_000_000, "max_samples": 1_000_000}


@dataclass(frozen=True)
class BlurConfig:
    """``blur`` section: ``min_frames``/``max_frames`` sharp frames averaged per blurry frame
    (odd counts drawn uniformly; GOPRO 7..13); ``gap_frames`` sharp frames skipped between
    consecutive windows; ``max_samples`` per sequence (None: as many as fit)."""

    min_frames: int = 7
    max_frames: int = 13
    gap_frames: int = 0
    max_samples: Optional[int] = None

    def __post_init__(self):
        if self.min_frames < 1:
            raise ConfigError("blur.min_frames", f"must be >= 1, got {self.min_frames}")
        if self.max_frames < self.min_frames:
            raise ConfigError("blur.max_frames", f"must be >= min_frames ({self.min_frames}), got {self.max_frames}")
        check_bounds("blur", self, UPPER_BOUNDS)          # before odd_counts() lists the counts
        if not self.odd_counts():
            raise ConfigError("blur.max_frames", f"no odd frame count in [{self.min_frames}, {self.max_frames}] "
                              "(the sharp target is the middle frame)")
        if self.gap_frames < 0:
            raise ConfigError("blur.gap_frames", f"must be >= 0, got {self.gap_frames}")
        if self.max_samples is not None and self.max_samples < 1:
            raise ConfigError("blur.max_samples", f"must be >= 1 or null, got {self.max_samples}")

    def odd_counts(self) -> list[int]:
        return [n for n in range(self.min_frames, self.max_frames + 1) if n % 2 == 1]


def blur_windows(n_frames: int, cfg: BlurConfig, rng: np.random.Generator) -> list[tuple[int, int]]:
    """``[(first, count), ...]``: back-to-back windows (plus ``gap_frames``) over the frames."""
    counts = np.asarray(cfg.odd_counts())
    out, start = [], 0
    while cfg.max_samples is None or len(out) < cfg.max_samples:
        n = int(rng.choice(counts))
        if start + n > n_frames:
            break
        out.append((start, n))
        start += n + cfg.gap_frames
    return out


def _chw(images: np.ndarray) -> np.ndarray:
    """(N, H, W) -> (N, 1, H, W); (N, H, W, 3) -> (N, 3, H, W)."""
    return images[:, None] if images.ndim == 3 else np.moveaxis(images, -1, 1)


def voxel_discrepancy(vox_undegraded: np.ndarray, vox_degraded: np.ndarray) -> np.ndarray:
    """Per-sample relative voxel discrepancy ``||V_d - V_u||_2 / max(||V_u||_2, 1)``: a scalar
    measure of how much the degradations changed the network input."""
    n = vox_undegraded.shape[0]
    u = vox_undegraded.reshape(n, -1).astype(np.float64)
    d = vox_degraded.reshape(n, -1).astype(np.float64)
    return np.linalg.norm(d - u, axis=1) / np.maximum(np.linalg.norm(u, axis=1), 1.0)


def make_samples(frames: Frames, ideal: Events, degraded: Events, cfg: BlurConfig, bins: int,
                 rng: np.random.Generator, voxel_mode: str = "hard", *, sequence: int = 0,
                 degrade: Mapping[str, float] | DegradeConfig | None = None,
                 level: float | None = None) -> dict:
    """Blurry/sharp/voxel samples of one sequence (frames and events share a time base).

    Returns a dict of arrays with one row per blurry frame: ``blurry``/``sharp`` (N, C, H, W)
    float32, ``frame_first``/``frame_last`` (N, C, H, W) float32 (the window's first and last
    sharp frame, at ``t0_us`` and ``t0_us + duration_us``), ``voxel_undegraded``/``voxel_degraded`` (N, bins, H, W), their per-polarity
    counts ``voxel_{undegraded,degraded}_{on,off}`` (N, bins, H, W), ``sequence`` int32,
    ``t0_us``/``duration_us`` int64, ``level`` float64 (``level`` if given, e.g.
    ``rdnet.sim.randomize.degradation_level``; else :func:`voxel_discrepancy`) and
    ``degrade``: {DegradeConfig key: (N,) float64} (the values the sequence was simulated
    with; NaN when ``degrade`` is None).
    """
    for name, ev in (("ideal", ideal), ("degraded", degraded)):
        if (ev.width, ev.height) != (frames.width, frames.height):
            raise ValidationError(name, f"sensor {ev.width}x{ev.height} != frames {frames.width}x{frames.height}")
    lin = frames.linear()
    wins = blur_windows(len(frames), cfg, rng)
    n = len(wins)
    c = 3 if frames.is_color else 1
    H, W = frames.height, frames.width
    out = {"blurry": np.empty((n, c, H, W), np.float32), "sharp": np.empty((n, c, H, W), np.float32),
           **{k: np.empty((n, c, H, W), np.float32) for k in FRAME_KEYS},
           "voxel_undegraded": np.empty((n, bins, H, W), np.float32),
           "voxel_degraded": np.empty((n, bins, H, W), np.float32),
           **{k: np.empty((n, bins, H, W), np.float32) for k in POLARITY_KEYS},
           "sequence": np.full(n, sequence, np.int32), "t0_us": np.empty(n, np.int64),
           "duration_us": np.empty(n, np.int64)}
    for j, (i0, k) in enumerate(wins):
        chunk = lin[i0:i0 + k]
        out["blurry"][j] = _chw(chunk.mean(axis=0, dtype=np.float64).astype(np.float32)[None])[0]
        out["sharp"][j] = _chw(chunk[k // 2][None])[0]
        out["frame_first"][j], out["frame_last"][j] = _chw(chunk[[0, -1]])
        t0 = int(frames.t_us[i0])
        dur = int(frames.t_us[i0 + k - 1]) - t0
        if dur <= 0:
            raise ValidationError("frames/t", f"window of {k} frames at frame {i0} has zero duration")
        out["t0_us"][j], out["duration_us"][j] = t0, dur
        for kind, ev in (("undegraded", ideal), ("degraded", degraded)):
            out[f"voxel_{kind}"][j] = voxel_grid(ev, bins, t0, dur, mode=voxel_mode)
            out[f"voxel_{kind}_on"][j], out[f"voxel_{kind}_off"][j] = voxel_grid(
                ev, bins, t0, dur, mode=voxel_mode, polarity="split")
    if level is None:
        out["level"] = voxel_discrepancy(out["voxel_undegraded"], out["voxel_degraded"])
    else:
        out["level"] = np.full(n, float(level), np.float64)
    if isinstance(degrade, DegradeConfig):
        degrade = {k: getattr(degrade, k) for k in DEGRADE_KEYS}
    out["degrade"] = {k: np.full(n, np.nan if degrade is None else float(degrade[k]), np.float64)
                      for k in DEGRADE_KEYS}
    return out


# --- pairs file ------------------------------------------------------------------------

class PairsWriter:
    """Append samples to a pairs file; the file appears (``os.replace``) only on a clean
    ``close()``/context exit. ``attrs`` must hold bins, voxel_mode, channels, split."""

    def __init__(self, path: str | Path, attrs: Mapping):
        missing = [k for k in ("bins", "voxel_mode", "channels", "split") if k not in attrs]
        if missing:
            raise ValidationError("attrs", f"pairs file needs attrs {missing}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        os.close(fd)
        self._tmp = Path(tmp)
        self._f = h5py.File(self._tmp, "w")
        for k, v in attrs.items():
            self._f.attrs[k] = v
        self.attrs = dict(attrs)
        self.n = 0

    def _dataset(self, name: str, row_shape: tuple, dtype) -> h5py.Dataset:
        if name not in self._f:
            comp = {"compression": "lzf"} if len(row_shape) > 0 else {}
            return self._f.create_dataset(name, shape=(0,) + row_shape, maxshape=(None,) + row_shape,
                                          dtype=dtype, chunks=(1,) + row_shape if row_shape else (4096,), **comp)
        return self._f[name]

    def _optional(self, samples: Mapping, keys: tuple, what: str) -> list[str]:
        """The keys of an optional group of datasets that ``samples`` holds: all or none,
        and in every append or in none."""
        present = [k for k in keys if k in samples]
        if present and len(present) != len(keys):
            raise ValidationError("samples", f"{what} incomplete: have {present}")
        if self.n and bool(present) != (keys[0] in self._f):
            raise ValidationError("samples", f"{what} present in some appends only")
        return present

    def append(self, samples: Mapping) -> None:
        n = int(np.asarray(samples["blurry"]).shape[0])
        if n == 0:
            return
        c, b = int(self.attrs["channels"]), int(self.attrs["bins"])
        missing = [k for k in ARRAY_KEYS + ("degrade",) if k not in samples]
        missing += [f"degrade/{k}" for k in DEGRADE_KEYS if k not in samples.get("degrade", {k: 0 for k in DEGRADE_KEYS})]
        if missing:
            raise ValidationError("samples", f"missing {missing}")
        rows = {k: np.asarray(samples[k], _DTYPES[k]) for k in ARRAY_KEYS}
        present = self._optional(samples, POLARITY_KEYS, "per-polarity voxels")
        frames = self._optional(samples, FRAME_KEYS, "window frames")
        rows.update({k: np.asarray(samples[k], _DTYPES[k]) for k in present + frames})
        rows.update({f"degrade/{k}": np.asarray(samples["degrade"][k], np.float64) for k in DEGRADE_KEYS})
        for k, a in rows.items():
            if a.shape[0] != n:
                raise ValidationError(k, f"{a.shape[0]} rows, expected {n}")
        for k, ch in (("blurry", c), ("sharp", c), ("voxel_undegraded", b), ("voxel_degraded", b),
                      *((k, b) for k in present), *((k, c) for k in frames)):
            if rows[k].ndim != 4 or rows[k].shape[1] != ch:
                raise ValidationError(k, f"expected (N, {ch}, H, W), got {rows[k].shape}")
        for k, a in rows.items():
            ds = self._dataset(k, a.shape[1:], a.dtype)
            if ds.shape[1:] != a.shape[1:]:
                raise ValidationError(k, f"row shape {a.shape[1:]} != file's {ds.shape[1:]}")
            ds.resize(self.n + n, axis=0)
            ds[self.n:] = a
        self.n += n

    def close(self) -> Path:
        if self.n == 0:
            self.abort()
            raise ValidationError("samples", f"no samples to write to {self.path}")
        self._f.attrs["n_samples"] = self.n
        self._f.close()
        os.replace(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        try:
            self._f.close()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_pairs(path: str | Path, samples_list: Iterable[Mapping], attrs: Mapping) -> Path:
    """Write the samples (dicts from :func:`make_samples`) as one pairs file (DATA.md
    layout), atomically (temp file in the same folder, then ``os.replace``)."""
    with PairsWriter(path, attrs) as w:
        for s in samples_list:
            w.append(s)
    return Path(path)


class PairsFile:
    """Lazy random access to a pairs file; safe for DataLoader workers (the HDF5 handle is
    opened on the first ``__getitem__`` of each process and never pickled).

    ``ds[i]`` -> dict of numpy arrays: blurry, sharp, voxel_undegraded, voxel_degraded
    (float32 (C|B, H, W)), the per-polarity voxels when the file has them
    (:data:`POLARITY_KEYS`), sequence, t0_us, duration_us, level (scalars) and degrade
    ({key: float}).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise FormatError(self.path, None, "pairs file not found")
        try:
            with h5py.File(self.path, "r") as f:
                for k in ARRAY_KEYS:
                    if k not in f:
                        raise FormatError(self.path, k, "missing dataset")
                for k in DEGRADE_KEYS:
                    if f"degrade/{k}" not in f and k not in LATER_DEGRADE_KEYS:
                        raise FormatError(self.path, f"degrade/{k}", "missing dataset")
                self.attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
                self._len = int(f["blurry"].shape[0])
                self.keys = ARRAY_KEYS + (POLARITY_KEYS if all(k in f for k in POLARITY_KEYS) else ())
                for k in ARRAY_KEYS:
                    if f[k].shape[0] != self._len:
                        raise FormatError(self.path, k, f"{f[k].shape[0]} rows, blurry has {self._len}")
        except OSError as e:
            raise FormatError(self.path, None, f"not a readable HDF5 file ({e})") from None
        self._f = None
        self._pid = None

    def _file(self) -> h5py.File:
        if self._f is None or self._pid != os.getpid():
            self._f = h5py.File(self.path, "r")
            self._pid = os.getpid()
        return self._f

    def __len__(self) -> int:
        return self._len

    def __getitem__(self, i: int) -> dict:
        i = int(i)
        if i < 0:
            i += self._len
        if not 0 <= i < self._len:
            raise IndexError(f"sample {i} out of range (0..{self._len - 1})")
        f = self._file()
        out = {k: f[k][i] for k in self.keys}
        out["degrade"] = {k: float(f[f"degrade/{k}"][i]) if f"degrade/{k}" in f else LATER_DEGRADE_KEYS[k]
                          for k in DEGRADE_KEYS}
        return out

    def column(self, name: str) -> np.ndarray:
        """A whole per-sample column (e.g. 'level', 'sequence', 'degrade/jitter_us')."""
        f = self._file()
        if name not in f:
            raise FormatError(self.path, name, "missing dataset")
        return f[name][...]

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_f"], d["_pid"] = None, None
        return d

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_pairs(path: str | Path) -> PairsFile:
    """Open a pairs file lazily (see :class:`PairsFile`)."""
    return PairsFile(path)
