"""Event-level restoration metrics: does a restored stream hold the events of the
undegraded one, and no others?

Both streams are counted per voxel and polarity (:func:`polarity_counts`): a (2, bins,
H, W) int32 grid, channel 0 = OFF and 1 = ON, the window [t0, t0 + T] split into
``bins`` equal bins exactly as :func:`rdnet.events.voxel.voxel_grid` does in mode
``"hard"`` (bin k = [t0 + k T / bins, t0 + (k + 1) T / bins), the last bin closed on the
right). With r = restored counts and u = reference (undegraded) counts,
:func:`match_metrics` reports

* ``matched`` = sum over voxels and polarities of min(r, u): events present in both,
* ``precision`` = matched / sum r (1 when nothing was restored: no event was invented),
* ``recall`` = matched / sum u (1 when the reference is empty: nothing to find),
* ``f1`` = 2 P R / (P + R) (0 when P + R = 0),
* ``count_ratio`` = sum r / sum u (1 when both are empty, ``inf`` when only u is empty),
* ``voxel_l1_all`` = mean over all (bin, pixel) voxels of |s_r - s_u|, s = ON - OFF the
  signed voxel (what the networks see); ``voxel_l1_event`` = the same mean over the
  *event voxels* only, those where r or u has an event of either polarity (0 when there
  are none),
* ``polarity_l1_all`` / ``polarity_l1_event``: mean |r - u| per polarity channel over all
  2 x bins x H x W entries / over the entries of the event voxels (both channels of a
  voxel count when the voxel is an event voxel).

Inputs may be one sample (2, bins, H, W) or a batch (N, 2, bins, H, W); batches are
pooled (sums over every sample; means over every voxel of the batch) unless
``per_sample=True``, which returns one value per sample.
"""
from __future__ import annotations

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events
from rdnet.events.voxel import voxel_grid

#: Keys of :func:`match_metrics` (in report order).
KEYS = ("precision", "recall", "f1", "count_ratio", "matched", "restored", "reference",
        "voxel_l1_all", "voxel_l1_event", "polarity_l1_all", "polarity_l1_event", "event_voxels")


def polarity_counts(events: Events, bins: int, t0_us: int, duration_us: int) -> np.ndarray:
    """(2, bins, H, W) int32 event counts per polarity (0 = OFF, 1 = ON) and bin of the
    events in [t0, t0 + duration]: :func:`rdnet.events.voxel.voxel_grid` with
    ``polarity="split"`` (ON, OFF) in mode ``"hard"``, channels reversed."""
    split = voxel_grid(events, bins, t0_us, duration_us, mode="hard", polarity="split")
    return np.rint(split[::-1]).astype(np.int32)


def _ratio(num: np.ndarray, den: np.ndarray, empty: float) -> np.ndarray:
    """num / den with ``empty`` where den == 0."""
    num, den = np.asarray(num, np.float64), np.asarray(den, np.float64)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), empty)


def match_metrics(restored: np.ndarray, reference: np.ndarray, *, per_sample: bool = False) -> dict:
    """Precision, recall, F1, count ratio and voxel L1 of ``restored`` against
    ``reference`` polarity counts (module docstring for the definitions and edge cases).
    Values are floats, or (N,) arrays with ``per_sample=True`` on a batch."""
    r = np.asarray(restored)
    u = np.asarray(reference)
    if r.shape != u.shape:
        raise ValidationError("counts", f"restored {r.shape} and reference {u.shape} differ in shape")
    if r.ndim not in (4, 5) or r.shape[-4] != 2:
        raise ValidationError("counts", f"expected (2, bins, H, W) or (N, 2, bins, H, W), got {r.shape}")
    if r.size and (r.min() < 0 or u.min() < 0):
        raise ValidationError("counts", "event counts must be >= 0")
    batched = r.ndim == 5
    if not batched:
        r, u = r[None], u[None]
    r = r.astype(np.int64)
    u = u.astype(np.int64)
    axes = (1, 2, 3, 4) if per_sample and batched else (0, 1, 2, 3, 4)
    vox_axes = (1, 2, 3) if per_sample and batched else (0, 1, 2, 3)
    n_r, n_u = r.sum(axes), u.sum(axes)
    matched = np.minimum(r, u).sum(axes)
    precision = _ratio(matched, n_r, 1.0)
    recall = _ratio(matched, n_u, 1.0)
    f1 = _ratio(2 * precision * recall, precision + recall, 0.0)
    count_ratio = np.where(n_u > 0, _ratio(n_r, n_u, 1.0), np.where(n_r > 0, np.inf, 1.0))
    s_err = np.abs((r[:, 1] - r[:, 0]) - (u[:, 1] - u[:, 0]))          # (N, bins, H, W)
    p_err = np.abs(r - u).sum(1)                                      # both channels per voxel
    ev = (r.sum(1) + u.sum(1)) > 0
    n_vox = np.prod(s_err.shape[1:]) * (1 if vox_axes == (1, 2, 3) else s_err.shape[0])
    n_ev = ev.sum(vox_axes)
    out = {
        "precision": precision, "recall": recall, "f1": f1, "count_ratio": count_ratio,
        "matched": matched, "restored": n_r, "reference": n_u,
        "voxel_l1_all": s_err.sum(vox_axes) / max(int(n_vox), 1),
        "voxel_l1_event": _ratio((s_err * ev).sum(vox_axes), n_ev, 0.0),
        "polarity_l1_all": p_err.sum(vox_axes) / max(2 * int(n_vox), 1),
        "polarity_l1_event": _ratio((p_err * ev).sum(vox_axes), 2 * n_ev, 0.0),
        "event_voxels": n_ev,
    }
    if per_sample and batched:
        return {k: np.asarray(v, np.float64 if k not in ("matched", "restored", "reference", "event_voxels")
                              else np.int64) for k, v in out.items()}
    return {k: (int(v) if k in ("matched", "restored", "reference", "event_voxels") else float(v))
            for k, v in out.items()}


def event_metrics(restored: Events, reference: Events, bins: int, t0_us: int, duration_us: int) -> dict:
    """:func:`match_metrics` of two event streams over one window."""
    return match_metrics(polarity_counts(restored, bins, t0_us, duration_us),
                         polarity_counts(reference, bins, t0_us, duration_us))
