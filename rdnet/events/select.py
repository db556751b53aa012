"""Events of a restored voxel grid that keep the recording's own timestamps.

A restorer that works on voxel grids (RDNet's stage 1, :mod:`rdnet.restore.learned`) decides
how many ON and OFF events each (bin, pixel) voxel holds. :func:`rdnet.events.voxel.entry_events`
turns such counts into events spread evenly over the bin: every timestamp is rounded to the
bin (5 ms for a 50 ms window of 10 bins), and not one output event is an event of the
recording, even where the restorer only kept what came in.

:func:`select_events` reads the same counts against the window's input events instead. In a
voxel whose restored count is ``k`` and which holds ``n`` input events of that polarity:

* ``min(n, k)`` of its input events are kept as they are (time, pixel, polarity): all of
  them when ``k >= n``, else ``k`` spread evenly over their time order (ranks
  ``floor((2 j + 1) n / (2 k))``, ``j = 0 .. k - 1``: one of one, the middle one of three);
* the ``k - n`` events a voxel has beyond its input (``k > n``, the restorer added them)
  are spread over the bin as :func:`~rdnet.events.voxel.entry_events` spreads them.

The voxel grid of the result is the restored grid exactly (hard binning, the project's
``voxel.mode``), so every voxel-level score is unchanged; what changes is that the kept
events are the recording's events, with their microsecond timestamps. Only hard binning
is supported: with ``"bilinear"`` an event weighs on two bins and has no one voxel to be
kept in, so a ``bilinear`` network's events are spread over the bins whatever the setting asks
(:func:`times_used` says which rule applies, and what the outputs record).

:func:`capped_entries` caps each voxel's count at its input count (a restorer that only
deletes), :func:`floored_entries` raises it to at least its input count (one that only
adds); :func:`shared_count` counts the events two streams share (``rdnet restore``'s
``events_not_recorded``).
"""
from __future__ import annotations

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events
from rdnet.events.voxel import entry_events


def times_used(event_times: str, mode: str) -> str:
    """The timestamp rule that applies to a restorer's events: ``"input"`` (the window's own
    events kept, :func:`select_events`) only when it is asked for and the voxels are hard
    binned; ``"bins"`` otherwise (``restore.event_times`` / ``deblur.event_times`` against
    ``voxel.mode``)."""
    return "input" if event_times == "input" and mode == "hard" else "bins"


def event_voxels(events: Events, bins: int, t0_us: int, duration_us: int) -> np.ndarray:
    """(n,) int64 flat index of each event's voxel in the per-polarity (2, bins, H, W) grid
    of the window ``[t0_us, t0_us + duration_us]`` (hard binning, as
    :func:`rdnet.events.voxel.voxel_grid` with ``polarity="split"``: ON in plane 0, OFF in
    plane 1, the last bin closed on the right). Every event must lie in the window."""
    a = events.array
    H, W = events.height, events.width
    dt = a["t"] - np.int64(t0_us)
    if a.size and (dt[0] < 0 or dt[-1] > duration_us):
        raise ValidationError("events", f"events from {int(a['t'][0])} to {int(a['t'][-1])} us lie outside the "
                                        f"window [{int(t0_us)}, {int(t0_us) + int(duration_us)}] us")
    b = np.minimum(dt * bins // int(duration_us), bins - 1)
    plane = (a["p"] == 0).astype(np.int64)
    return ((plane * bins + b) * H + a["y"].astype(np.int64)) * W + a["x"].astype(np.int64)


def signed_entries(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple]:
    """A rounded signed (bins, H, W) or per-polarity (2, bins, H, W) grid as per-polarity
    entries ``(index, counts, shape)`` (increasing flat positions in the (2, bins, H, W)
    grid, counts > 0): a signed value ``v`` is ``v`` ON events when positive, ``-v`` OFF
    events when negative (what :func:`rdnet.events.voxel.voxel_events` writes)."""
    g = np.rint(np.asarray(grid)).astype(np.int64)
    if g.ndim == 3:
        g = np.stack([np.maximum(g, 0), np.maximum(-g, 0)])
    elif not (g.ndim == 4 and g.shape[0] == 2):
        raise ValidationError("voxel", f"expected (bins, H, W) or (2, bins, H, W), got shape {g.shape}")
    elif (g < 0).any():
        raise ValidationError("voxel", "a per-polarity (2, bins, H, W) grid holds negative counts")
    flat = g.reshape(-1)
    index = np.flatnonzero(flat)
    return index, flat[index], g.shape


def select_events(inputs: Events, index: np.ndarray, counts: np.ndarray, shape: tuple,
                  t0_us: int, duration_us: int) -> Events:
    """The events of the per-polarity voxel entries ``(index, counts)`` of a grid of
    ``shape`` (2, bins, H, W) over ``[t0_us, t0_us + duration_us]``, taken from ``inputs``
    (the window's input events) where they have them (module docstring). ``index``:
    increasing flat positions; ``counts``: whole event counts >= 0. Returns time-sorted
    events; an input event and an added one at the same time keep input-first order."""
    shape = tuple(int(s) for s in shape)
    if len(shape) != 4 or shape[0] != 2:
        raise ValidationError("voxel", f"expected a (2, bins, H, W) grid shape, got {shape}")
    bins, H, W = shape[1:]
    if (inputs.height, inputs.width) != (H, W):
        raise ValidationError("events", f"sensor {(inputs.height, inputs.width)} (H, W) != grid {(H, W)}")
    index = np.asarray(index, np.int64).ravel()
    counts = np.asarray(counts, np.int64).ravel()
    if index.shape != counts.shape:
        raise ValidationError("voxel", f"{index.size} entry positions and {counts.size} counts differ")
    if (counts < 0).any():
        raise ValidationError("voxel", "negative event counts")
    if index.size > 1 and np.any(np.diff(index) <= 0):
        raise ValidationError("voxel", "entry positions must be increasing")
    vox = event_voxels(inputs, bins, t0_us, duration_us)
    order = np.argsort(vox, kind="stable")               # by voxel, in time order inside one
    voxels, first, n_in = np.unique(vox[order], return_index=True, return_counts=True)
    k = _lookup(index, counts, voxels)                    # restored count of each input voxel
    keep = np.minimum(n_in, k)
    group = np.repeat(np.arange(voxels.size), keep)
    j = np.arange(group.size, dtype=np.int64) - np.repeat(np.cumsum(keep) - keep, keep)
    rank = ((2 * j + 1) * n_in[group]) // (2 * keep[group])
    kept = inputs.array[np.sort(order[first[group] + rank])]
    extra = counts - _lookup(voxels, n_in, index)         # beyond the voxel's input events
    add = extra > 0
    added = entry_events(index[add], extra[add], shape, t0_us, duration_us, mode="hard").array
    if not added.size:
        return Events(kept, W, H, validate=False)
    out = np.concatenate([kept, added])
    return Events(out[np.argsort(out["t"], kind="stable")], W, H, validate=False)


def capped_entries(inputs: Events, index: np.ndarray, counts: np.ndarray, shape: tuple,
                   t0_us: int, duration_us: int) -> tuple[np.ndarray, np.ndarray]:
    """The per-polarity entries ``(index, counts)`` of a (2, bins, H, W) grid over
    ``[t0_us, t0_us + duration_us]`` with every count capped at the number of ``inputs``
    events in its voxel (entries left at 0 dropped): a restoration that may delete events
    but not add any (``restore.add_events: false``)."""
    index = np.asarray(index, np.int64).ravel()
    voxels, n_in = _input_voxels(inputs, shape, t0_us, duration_us)
    capped = np.minimum(np.asarray(counts, np.int64).ravel(), _lookup(voxels, n_in, index))
    keep = capped > 0
    return index[keep], capped[keep]


def floored_entries(inputs: Events, index: np.ndarray, counts: np.ndarray, shape: tuple,
                    t0_us: int, duration_us: int) -> tuple[np.ndarray, np.ndarray]:
    """The per-polarity entries ``(index, counts)`` of a (2, bins, H, W) grid over
    ``[t0_us, t0_us + duration_us]`` with every count raised to at least the number of
    ``inputs`` events in its voxel (an input voxel the restorer emptied comes back), in
    increasing index order: a restoration that may add events but not delete any
    (``restore.delete_events: false``); the counterpart of :func:`capped_entries`."""
    index = np.asarray(index, np.int64).ravel()
    counts = np.asarray(counts, np.int64).ravel()
    voxels, n_in = _input_voxels(inputs, shape, t0_us, duration_us)
    order = np.argsort(index, kind="stable")
    every = np.union1d(index, voxels)
    floored = np.maximum(_lookup(index[order], counts[order], every), _lookup(voxels, n_in, every))
    keep = floored > 0
    return every[keep], floored[keep]


def _input_voxels(inputs: Events, shape: tuple, t0_us: int, duration_us: int) -> tuple[np.ndarray, np.ndarray]:
    """The (increasing) flat voxel indices of ``inputs`` on a (2, bins, H, W) grid and the
    number of events in each."""
    bins = int(tuple(shape)[1])
    return np.unique(event_voxels(inputs, bins, t0_us, duration_us), return_counts=True)


def event_keys(events: Events) -> np.ndarray:
    """(n,) int64: one integer per event, equal for two events exactly when their time,
    pixel and polarity are (``((t H + y) W + x) 2 + p``; times up to about 2e12 us at
    1280 x 720)."""
    a = events.array
    return ((a["t"].astype(np.int64) * events.height + a["y"]) * events.width + a["x"]) * 2 + a["p"]


def shared_count(a: Events, b: Events) -> int:
    """How many events of ``a`` are events of ``b`` (same time, pixel and polarity), counted
    as multisets: an event twice in ``a`` and once in ``b`` counts once."""
    if not len(a) or not len(b):
        return 0
    ua, ca = np.unique(event_keys(a), return_counts=True)
    ub, cb = np.unique(event_keys(b), return_counts=True)
    _, ia, ib = np.intersect1d(ua, ub, assume_unique=True, return_indices=True)
    return int(np.minimum(ca[ia], cb[ib]).sum())


def _lookup(keys: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``values`` of the increasing ``keys`` at the positions ``at`` (0 where absent)."""
    if not keys.size:
        return np.zeros(at.size, np.int64)
    i = np.minimum(np.searchsorted(keys, at), keys.size - 1)
    return np.where(keys[i] == at, values[i], 0).astype(np.int64)
