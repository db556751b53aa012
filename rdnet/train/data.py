"""Learning samples from a pairs file (``data/pairs/{split}.h5``, layout in DATA.md).

:class:`PairsDataset` reads one row lazily: the HDF5 file is opened on first access in
the process that reads (each DataLoader worker opens its own handle; nothing is opened
and kept in ``__init__``, which only checks the layout). When the rows a dataset serves
fit in :data:`PRELOAD_MAX_BYTES` (the embedded study's whole training file is 109 MB), the
first access reads them into memory, in that process; otherwise each sample reads only its
crop window from the file. The samples are the same bytes either way (tested). The pairs
files are compressed in one chunk per row, so a crop read decompresses the row of every
dataset again: on the study's 48-pixel crops that was about a quarter of a stage-1 or
deblurring training stage's wall time (``benchmarks/bench_stages.py``,
``benchmarks/results/stages.json``: the study's settings, the same model bytes;
train_restore 175.3 -> 132.1 s, a deblurring baseline 153.8 -> 112.9 s, RDNet 290.5 ->
258.8 s).

Randomness is explicit and stateless: the crop window and flips of a draw are a pure
function of ``(seed, epoch, index)`` (``numpy.random.default_rng([seed, epoch, index])``),
and :class:`StepSampler` derives which rows make up training step ``s`` from
``(seed, s)`` alone. A run resumed at step ``s`` therefore sees exactly the batches an
uninterrupted run would have seen, whatever the number of workers or processes.

Augmentation (``augment=True``): a random horizontal flip and a random vertical flip,
applied identically to the blurry and sharp images and to both voxel grids. A spatial
flip of the voxel grid keeps the polarity and the bin order: mirroring the scene mirrors
where brightness changes happen, not their sign or time (a time reversal would swap the
bins *and* negate the polarities; it is not used).

Per-polarity counts: when the file holds ``voxel_{kind}_on``/``_off``
(:data:`rdnet.sim.blur.POLARITY_KEYS`), samples also carry ``counts_undegraded`` and
``counts_degraded`` (2 * bins, h, w): the ON counts of the bins, then the OFF counts
(the input and target of the count-output RestoreNet). Files without them still load
(``PairsInfo.has_counts`` is False).

Frame-pair guide (``guide``, a :class:`rdnet.nn.guide.FramePairGuide`; the
``restore_frames`` task): samples also carry ``guide`` (C + 1, h, w), the window's first
sharp frame and the change of log intensity to its last one over the threshold, built
from the file's ``frame_first``/``frame_last`` after the crop and flips
(``PairsInfo.has_frame_pair``; a file without them is refused).

Bad values: :func:`check_finite` refuses a file whose float data hold NaN or inf (the
training loop runs it before the first step); a dataset that is an HDF5 group is refused
by :func:`read_pairs_info` (:func:`pairs_dataset`).

``rows`` restricts a dataset to some rows of the file (e.g. the training rows left after
holding out validation sequences, :func:`split_rows`); crops and flips stay a function
of the file row.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from rdnet.errors import ConfigError, FormatError
from rdnet.events.io._common import require_file
from rdnet.sim.blur import FRAME_KEYS, POLARITY_KEYS

#: datasets every pairs file must hold: name -> number of dimensions.
REQUIRED = {"blurry": 4, "sharp": 4, "voxel_undegraded": 4, "voxel_degraded": 4, "level": 1}
EVENT_KINDS = ("undegraded", "degraded")
#: The datasets a sample reads are held in memory when they fit in this many bytes (module
#: docstring); a speed-memory trade only, the samples do not depend on it.
PRELOAD_MAX_BYTES = 1 << 30
#: :func:`check_finite` reads a dataset in slices of whole rows of about this many bytes.
FINITE_CHUNK_BYTES = 64 << 20


def sample_datasets(info: PairsInfo, frame_pair: bool = False) -> tuple[str, ...]:
    """The per-row image and voxel datasets of a pairs file that a sample reads (by
    :class:`PairsDataset` and :func:`rdnet.eval.predict.iter_predictions`); ``frame_pair``:
    the window's first and last frames too (the frame-pair guide)."""
    return (("blurry", "sharp", "voxel_undegraded", "voxel_degraded") + (POLARITY_KEYS if info.has_counts else ())
            + (FRAME_KEYS if frame_pair else ()))


def read_rows_whole(f, names, rows: np.ndarray | None = None) -> dict | None:
    """``name -> numpy array`` of the datasets ``names`` of the open pairs file ``f`` at the
    file rows ``rows`` (sorted and unique; None: every row), when together they fit in
    :data:`PRELOAD_MAX_BYTES`; None when they do not (read them row by row instead)."""
    n = f[names[0]].shape[0] if rows is None else len(rows)
    nbytes = sum(n * f[k].dtype.itemsize * int(np.prod(f[k].shape[1:])) for k in names)
    if nbytes > PRELOAD_MAX_BYTES:
        return None
    sel = slice(None) if rows is None else rows
    return {k: f[k][sel] for k in names}


def pairs_dataset(f, path: str | Path, name: str):
    """The dataset ``name`` of the open pairs file ``f`` (FormatError naming the file and
    the dataset when it is missing or is an HDF5 group or named type instead)."""
    import h5py
    if name not in f:
        raise FormatError(path, name, "missing dataset")
    obj = f[name]
    if not isinstance(obj, h5py.Dataset):
        what = "an HDF5 group" if isinstance(obj, h5py.Group) else f"an HDF5 {type(obj).__name__}"
        raise FormatError(path, name, f"is {what}, expected a dataset")
    return obj


def check_finite(path: str | Path, info: PairsInfo | None = None,
                 chunk_bytes: int | None = None) -> None:
    """FormatError naming the file and the dataset when a float dataset that a sample
    reads (:func:`sample_datasets` and ``level``) holds NaN or inf, with the index of
    the first one; the training loop would otherwise stop with a non-finite loss.

    The whole file is read once, in slices of whole rows of about ``chunk_bytes``
    (default :data:`FINITE_CHUNK_BYTES`), so memory stays bounded whatever the file size.
    It runs before training rather than per sample in :class:`PairsDataset` because a
    crop only sees part of a row (a bad value outside the crops drawn early would be
    found late or never) and because an error raised from the data loader mid-run comes
    after the output folder, ``dvclive/`` and ``last.pt`` have been written. Integer
    datasets cannot hold NaN or inf and are skipped."""
    import h5py
    path = Path(path)
    info = read_pairs_info(path) if info is None else info
    chunk_bytes = FINITE_CHUNK_BYTES if chunk_bytes is None else int(chunk_bytes)
    with h5py.File(path, "r") as f:
        for name in sample_datasets(info, info.has_frame_pair) + ("level",):
            d = f[name]
            if not np.issubdtype(d.dtype, np.inexact):
                continue
            row_bytes = max(1, d.dtype.itemsize * int(np.prod(d.shape[1:])))
            step = max(1, chunk_bytes // row_bytes)
            for lo in range(0, d.shape[0], step):
                bad = ~np.isfinite(d[lo:lo + step])
                if bad.any():
                    idx = np.unravel_index(int(np.argmax(bad)), bad.shape)
                    idx = (lo + int(idx[0]),) + tuple(int(i) for i in idx[1:])
                    where = idx[0] if len(idx) == 1 else idx
                    raise FormatError(path, name, f"holds NaN or inf values (first at index {where})")


@dataclass(frozen=True)
class PairsInfo:
    """Shape of a pairs file: ``n`` samples of ``channels`` x ``height`` x ``width``
    images with ``bins``-bin voxel grids."""

    n: int
    channels: int
    bins: int
    height: int
    width: int
    has_counts: bool = False
    has_frame_pair: bool = False


def read_pairs_info(path: str | Path) -> PairsInfo:
    """Check the layout of a pairs file and return its shape (FormatError otherwise)."""
    import h5py

    path = Path(path)
    if not path.exists():
        raise FormatError(path, None, "pairs file not found")
    require_file(path)                  # a FIFO or folder: "not a regular file", not "not found"
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise FormatError(path, None, f"not a readable HDF5 file ({e})") from None
    with f:
        for name, ndim in REQUIRED.items():
            if pairs_dataset(f, path, name).ndim != ndim:
                raise FormatError(path, name, f"expected {ndim} dimensions, got shape {f[name].shape}")
        n, c, h, w = f["blurry"].shape
        if f["sharp"].shape != (n, c, h, w):
            raise FormatError(path, "sharp", f"shape {f['sharp'].shape} != blurry {(n, c, h, w)}")
        b = f["voxel_undegraded"].shape[1]
        for name in ("voxel_undegraded", "voxel_degraded"):
            if f[name].shape != (n, b, h, w):
                raise FormatError(path, name, f"shape {f[name].shape}, expected {(n, b, h, w)}")
        if f["level"].shape != (n,):
            raise FormatError(path, "level", f"shape {f['level'].shape}, expected ({n},)")
        if "bins" in f.attrs and int(f.attrs["bins"]) != b:
            raise FormatError(path, "bins", f"attribute {int(f.attrs['bins'])} != voxel bins {b}")
        if n == 0:
            raise FormatError(path, "blurry", "no samples")
        present = [k for k in POLARITY_KEYS if k in f]
        if present and len(present) != len(POLARITY_KEYS):
            raise FormatError(path, sorted(set(POLARITY_KEYS) - set(present))[0],
                              "missing (the file has only some per-polarity voxels)")
        for k in present:
            if pairs_dataset(f, path, k).shape != (n, b, h, w):
                raise FormatError(path, k, f"shape {f[k].shape}, expected {(n, b, h, w)}")
        frames = [k for k in FRAME_KEYS if k in f]
        for k in frames:
            if pairs_dataset(f, path, k).shape != (n, c, h, w):
                raise FormatError(path, k, f"shape {f[k].shape}, expected {(n, c, h, w)}")
        if frames and len(frames) != len(FRAME_KEYS):
            raise FormatError(path, sorted(set(FRAME_KEYS) - set(frames))[0], "missing (the file has only one "
                              "of the window frames)")
    return PairsInfo(n=int(n), channels=int(c), bins=int(b), height=int(h), width=int(w),
                     has_counts=bool(present), has_frame_pair=bool(frames))


def split_rows(path: str | Path, val_sequences: int) -> tuple[np.ndarray, np.ndarray]:
    """(train_rows, val_rows) of a pairs file: the rows of its last ``val_sequences``
    sequences (column ``sequence``) are held out for validation; whole sequences, so no
    validation window shares a recording with a training window."""
    import h5py
    info = read_pairs_info(path)
    if val_sequences <= 0:
        return np.arange(info.n), np.arange(0)
    with h5py.File(path, "r") as f:
        if "sequence" not in f:
            raise FormatError(Path(path), "sequence", "missing dataset (needed to hold out validation sequences)")
        seq = np.asarray(pairs_dataset(f, path, "sequence")[...])
    ids = np.unique(seq)
    if ids.size <= val_sequences:
        raise ConfigError("train.val_sequences", f"{val_sequences} validation sequences leave no "
                          f"training sequence in {path} ({ids.size} sequences)")
    val = np.isin(seq, ids[-val_sequences:])
    return np.flatnonzero(~val), np.flatnonzero(val)


def read_pairs_voxel(path: str | Path) -> dict:
    """How the voxels of a pairs file were made: ``bins``, ``mode`` (attribute
    ``voxel_mode``; None when absent) and ``normalize`` (attribute ``voxel_normalize``;
    None = raw signed counts, what :func:`rdnet.study.data.make_pairs` writes). Stored
    in checkpoints so that inference builds the same voxels."""
    import h5py
    info = read_pairs_info(path)
    with h5py.File(path, "r") as f:
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    mode = attrs.get("voxel_mode")
    norm = attrs.get("voxel_normalize")
    return {"bins": info.bins, "mode": None if mode is None else str(mode),
            "normalize": None if norm in (None, "none", "") else str(norm)}


def draw_augment(seed: int, epoch: int, index: int, height: int, width: int,
                 crop: int | None, augment: bool) -> tuple[int, int, int, int, bool, bool]:
    """(y0, x0, ch, cw, flip_h, flip_v) of a draw: a pure function of (seed, epoch, index)."""
    rng = np.random.default_rng([int(seed), int(epoch), int(index)])
    if crop is None:
        y0, x0, ch, cw = 0, 0, height, width
    else:
        ch, cw = min(crop, height), min(crop, width)
        y0 = int(rng.integers(0, height - ch + 1))
        x0 = int(rng.integers(0, width - cw + 1))
    flips = rng.random(2) < 0.5 if augment else np.zeros(2, bool)
    return y0, x0, ch, cw, bool(flips[0]), bool(flips[1])


def draw_clean(seed: int, epoch: int, index: int, fraction: float) -> bool:
    """Whether sample ``(seed, epoch, index)`` is an identity pair (probability ``fraction``;
    its own random stream, so the crops and flips of :func:`draw_augment` do not change)."""
    if fraction <= 0.0:
        return False
    return bool(np.random.default_rng([int(seed), int(epoch), int(index), 1]).random() < fraction)


class PairsDataset(Dataset):
    """Samples of a pairs file as dicts of tensors.

    ``dataset[i]`` or ``dataset[(i, epoch)]`` returns ``blurry``/``sharp`` (C, h, w)
    float32, ``voxel_undegraded``/``voxel_degraded`` (B, h, w) float32, ``voxel`` (the
    network's input events: the ``events`` kind), ``level`` float64 scalar and ``index``
    int64 scalar (the file row), plus ``counts_undegraded``/``counts_degraded``
    (2 * bins, h, w) when the file has per-polarity voxels. ``crop`` (pixels, square;
    None = full frame) and flips are drawn from ``(seed, epoch, row)`` (see
    :func:`draw_augment`); a crop larger than the frame is an error. ``rows``: the file
    rows this dataset serves (default all); ``dataset[i]`` is file row ``rows[i]``.
    ``clean_fraction``: the share of samples (drawn by :func:`draw_clean`) whose degraded
    events are replaced by the undegraded ones (``level`` 0): identity pairs for stage 1.
    ``guide``: a :class:`rdnet.nn.guide.FramePairGuide`: samples also carry ``guide``
    (module docstring); the file must hold the window frames.
    """

    def __init__(self, path: str | Path, events: str = "degraded", crop: int | None = None,
                 augment: bool = False, *, seed: int = 0, rows=None, clean_fraction: float = 0.0,
                 guide=None):
        if events not in EVENT_KINDS:
            raise ConfigError("events", f"must be one of {list(EVENT_KINDS)}, got {events!r}")
        self.path = Path(path)
        self.info = read_pairs_info(self.path)
        if crop is not None:
            if crop < 1:
                raise ConfigError("train.crop", f"must be >= 1, got {crop}")
            if crop > min(self.info.height, self.info.width):
                raise ConfigError("train.crop", f"{crop} is larger than the frames "
                                  f"({self.info.height}x{self.info.width}) of {self.path}")
        if not 0.0 <= clean_fraction < 1.0:
            raise ConfigError("clean_fraction", f"must be in [0, 1), got {clean_fraction}")
        self.events, self.crop, self.augment, self.seed = events, crop, bool(augment), int(seed)
        self.clean_fraction = float(clean_fraction)
        if guide is not None and not self.info.has_frame_pair:
            raise FormatError(self.path, FRAME_KEYS[0], "missing: the frame-pair guide reads each window's first "
                              "and last frame (a pairs file written before they existed: rerun the blur step)")
        self.guide = guide
        self.rows = np.arange(self.info.n) if rows is None else np.asarray(rows, np.int64)
        if self.rows.size and (self.rows.min() < 0 or self.rows.max() >= self.info.n):
            raise ConfigError("rows", f"row out of range [0, {self.info.n}) of {self.path}")
        self._file = None
        self._pid = None
        self._arrays = self._at = None

    def __len__(self) -> int:
        return int(self.rows.size)

    # --- lazy per-process handle ------------------------------------------------------
    def _h5(self):
        if self._file is None or self._pid != os.getpid():
            import h5py
            self._file = h5py.File(self.path, "r")
            self._pid = os.getpid()
            self._arrays = self._at = None
        return self._file

    def _source(self, row: int) -> tuple:
        """``(source, i)``: where file row ``row`` is read from in this process -- the file's
        datasets at row ``row``, or, when this dataset's rows fit in
        :data:`PRELOAD_MAX_BYTES`, numpy copies of them (:func:`read_rows_whole`, on first
        use) at their position ``i`` among the sorted rows."""
        f = self._h5()
        if self._arrays is None:
            rows = np.unique(self.rows)
            names = sample_datasets(self.info, self.guide is not None) + ("level",)
            arrays = read_rows_whole(f, names, None if rows.size == self.info.n else rows)
            if arrays is None:
                self._arrays, self._at = f, None
            else:
                self._arrays, self._at = arrays, np.zeros(self.info.n, np.int64)
                self._at[rows] = np.arange(rows.size)
        return self._arrays, (row if self._at is None else int(self._at[row]))

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_file"], state["_pid"], state["_arrays"], state["_at"] = None, None, None, None
        return state

    def close(self) -> None:
        if self._file is not None and self._pid == os.getpid():
            self._file.close()
        self._file = None
        self._arrays = self._at = None

    # --- samples ----------------------------------------------------------------------
    def __getitem__(self, key) -> dict:
        index, epoch = (key if isinstance(key, tuple) else (key, 0))
        if not 0 <= int(index) < len(self):
            raise IndexError(f"sample {index} out of range [0, {len(self)})")
        index = int(self.rows[int(index)])
        y0, x0, ch, cw, fh, fv = draw_augment(self.seed, epoch, index, self.info.height,
                                              self.info.width, self.crop, self.augment)
        f, at = self._source(index)
        win = (at, slice(None), slice(y0, y0 + ch), slice(x0, x0 + cw))
        out, frames = {}, {}
        for name in sample_datasets(self.info, self.guide is not None):
            a = np.array(f[name][win], dtype=np.float32)     # a copy: never a view of the preloaded arrays
            if fh:
                a = a[:, :, ::-1]
            if fv:
                a = a[:, ::-1, :]
            if name in FRAME_KEYS:
                frames[name] = a
            else:
                out[name] = torch.from_numpy(np.ascontiguousarray(a))
        if self.guide is not None:
            out["guide"] = torch.from_numpy(self.guide.image(*(frames[k] for k in FRAME_KEYS)))
        if self.info.has_counts:
            for kind in EVENT_KINDS:
                out[f"counts_{kind}"] = torch.cat([out.pop(f"voxel_{kind}_on"), out.pop(f"voxel_{kind}_off")])
        level = float(f["level"][at])
        if draw_clean(self.seed, epoch, index, self.clean_fraction):
            for name in ("voxel", "counts"):
                if f"{name}_undegraded" in out:
                    out[f"{name}_degraded"] = out[f"{name}_undegraded"].clone()
            level = 0.0
        out["voxel"] = out[f"voxel_{self.events}"]
        out["level"] = torch.tensor(level, dtype=torch.float64)
        out["index"] = torch.tensor(index, dtype=torch.int64)
        return out


def step_indices(seed: int, step: int, batch_size: int, n: int) -> list[tuple[int, int]]:
    """The (index, epoch) pairs of global training step ``step``: sample position
    ``g = step * batch_size + j`` is row ``perm_e[g % n]`` of epoch ``e = g // n``, with
    ``perm_e`` the permutation drawn from ``default_rng([seed, e])`` (each epoch visits
    every row once)."""
    g = np.arange(step * batch_size, (step + 1) * batch_size, dtype=np.int64)
    epochs = g // n
    out = []
    cache: dict[int, np.ndarray] = {}
    for gi, e in zip(g.tolist(), epochs.tolist()):
        if e not in cache:
            cache[e] = np.random.default_rng([int(seed), int(e)]).permutation(n)
        out.append((int(cache[e][gi % n]), int(e)))
    return out


class StepSampler(Sampler):
    """Yields the (index, epoch) keys of steps ``start_step .. stop_step - 1``; with
    ``world_size`` processes, rank ``r`` takes the contiguous slice
    ``[r * b, (r + 1) * b)`` (``b = batch_size // world_size``) of every global batch, so
    the union over ranks is the single-process batch (DistributedSampler-equivalent
    sharding, but of each step rather than of the epoch). Use with
    ``DataLoader(batch_size=batch_size // world_size)``."""

    def __init__(self, n: int, batch_size: int, seed: int, start_step: int, stop_step: int,
                 rank: int = 0, world_size: int = 1):
        if batch_size % world_size:
            raise ConfigError("train.batch_size",
                              f"{batch_size} is not divisible by the {world_size} processes")
        self.n, self.batch_size, self.seed = n, batch_size, seed
        self.start_step, self.stop_step = start_step, stop_step
        self.rank, self.world_size = rank, world_size
        self.local = batch_size // world_size

    def __len__(self) -> int:
        return max(0, self.stop_step - self.start_step) * self.local

    def __iter__(self) -> Iterator[tuple[int, int]]:
        lo = self.rank * self.local
        for s in range(self.start_step, self.stop_step):
            yield from step_indices(self.seed, s, self.batch_size, self.n)[lo:lo + self.local]
