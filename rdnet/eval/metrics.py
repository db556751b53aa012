"""Image and event-restoration metrics.

Images (:func:`evaluate_images`): PSNR and SSIM of scikit-image
(``skimage.metrics.peak_signal_noise_ratio`` / ``structural_similarity``) on the 8-bit
range: images (N, C, H, W) in linear [0, 1] are clipped to [0, 1], scaled by 255 and
rounded to uint8, then compared with ``data_range=255``; colour (C = 3) with
``channel_axis``, grey (C = 1) as 2-D images; no border crop. SSIM uses the settings of
Wang et al. 2004 as documented by scikit-image (Gaussian window sigma 1.5,
``use_sample_covariance=False``; images need at least 11 x 11 pixels). Identical
images have PSNR = +inf (reported as such; means over a set containing one are +inf
too). Per-image values are averaged.

Samples without motion (:func:`has_motion`): a still camera filming a scene in which
nothing moves during the exposure gives a blurry frame equal to the sharp one at 8 bits.
There is nothing to deblur, and the blurry input itself scores PSNR = +inf there. The
study's image means (:func:`rdnet.eval.predict.evaluate_row`, EDI) are taken over the
samples with motion only, for every row alike (:func:`image_means`); the per-sample
values keep every sample, with its ``moving`` flag. Restoration metrics use every sample.

Event restoration (:func:`restoration_metrics`), against the undegraded voxels E_u, on
the *response locations* M = {E_u != 0 or E_d != 0} of each sample (the mask of the
restoration loss, :func:`rdnet.nn.losses.event_mask`):

* ``voxel_l1``: mean |E - E_u| over M;
* ``voxel_psnr``: 10 log10(peak^2 / MSE over M) with ``peak = max |E_u|`` over the
  sample's M (1 when E_u is empty there), in dB; +inf when E = E_u on M;
* ``voxel_l1_all``: mean |E - E_u| over all voxels (penalises events outside M);

each per sample, then averaged. Apply it to the degraded voxels for the "no
restoration" reference.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np


#: smallest image side for SSIM: the 11x11 window of a Gaussian with sigma 1.5 (skimage).
SSIM_MIN_SIZE = 11


def _numpy(a) -> np.ndarray:
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    return np.asarray(a)


def to_uint8(images) -> np.ndarray:
    """[0, 1] float images -> uint8 (clip, x 255, round half to even)."""
    a = _numpy(images).astype(np.float64)
    return np.round(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)


def psnr_ssim(pred, target) -> tuple[float, float]:
    """PSNR (dB) and SSIM of one (C, H, W) or (H, W) [0, 1] image pair (module docstring)."""
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    p, t = to_uint8(pred), to_uint8(target)
    if p.shape != t.shape:
        raise ValueError(f"image shapes differ: {p.shape} vs {t.shape}")
    if p.ndim == 3:
        if p.shape[0] == 1:
            p, t = p[0], t[0]
            channel_axis = None
        else:
            p, t = np.moveaxis(p, 0, -1), np.moveaxis(t, 0, -1)
            channel_axis = -1
    else:
        channel_axis = None
    if min(p.shape[:2]) < SSIM_MIN_SIZE:
        raise ValueError(f"SSIM needs images of at least {SSIM_MIN_SIZE}x{SSIM_MIN_SIZE} pixels "
                         f"(Gaussian window, sigma 1.5), got {p.shape[:2]}")
    if np.array_equal(p, t):
        psnr = float("inf")
    else:
        psnr = float(peak_signal_noise_ratio(t, p, data_range=255))
    ssim = float(structural_similarity(t, p, data_range=255, channel_axis=channel_axis,
                                       gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False))
    return psnr, ssim


def image_metrics_per_sample(preds, targets) -> dict[str, np.ndarray]:
    """Per-image ``psnr`` and ``ssim`` arrays of (N, C, H, W) batches."""
    p, t = _numpy(preds), _numpy(targets)
    if p.shape != t.shape or p.ndim != 4:
        raise ValueError(f"expected two (N, C, H, W) arrays of one shape, got {p.shape} and {t.shape}")
    vals = np.array([psnr_ssim(p[i], t[i]) for i in range(p.shape[0])], dtype=np.float64).reshape(-1, 2)
    return {"psnr": vals[:, 0], "ssim": vals[:, 1]}


def has_motion(blurry, sharp) -> np.ndarray:
    """Per sample of two (N, C, H, W) batches, whether the blurry input differs from the
    sharp target anywhere at 8 bits (:func:`to_uint8`; module docstring)."""
    b, s = to_uint8(blurry), to_uint8(sharp)
    if b.shape != s.shape or b.ndim != 4:
        raise ValueError(f"expected two (N, C, H, W) arrays of one shape, got {b.shape} and {s.shape}")
    return (b != s).reshape(b.shape[0], -1).any(axis=1)


def image_means(per: Mapping[str, Sequence[float]], moving) -> dict:
    """``psnr`` and ``ssim`` means over the samples with motion (``moving``, from
    :func:`has_motion`), with ``n_images`` (how many) and ``still_excluded`` (how many
    were left out). Means are None when no sample moves."""
    mv = np.asarray(moving, bool)
    out = {"n_images": int(mv.sum()), "still_excluded": int((~mv).sum())}
    for k in ("psnr", "ssim"):
        v = np.asarray(per[k], np.float64)[mv]
        out[k] = float(np.mean(v)) if v.size else None
    return out


def motion_only(per: Mapping[str, Sequence[float]], moving) -> dict[str, np.ndarray]:
    """``per`` with ``psnr``/``ssim`` set to NaN where a sample has no motion, so that
    :func:`group_means` and :func:`by_level` average image metrics over moving samples
    (and restoration metrics over all)."""
    mv = np.asarray(moving, bool)
    return {k: (np.where(mv, np.asarray(v, np.float64), np.nan) if k in ("psnr", "ssim") else v)
            for k, v in per.items()}


def evaluate_images(preds, targets) -> dict:
    """Mean PSNR/SSIM of (N, C, H, W) predictions against targets, with the per-image
    values: ``{"psnr", "ssim", "n", "psnr_per_image", "ssim_per_image"}``."""
    per = image_metrics_per_sample(preds, targets)
    return {"psnr": float(np.mean(per["psnr"])), "ssim": float(np.mean(per["ssim"])),
            "n": int(per["psnr"].size), "psnr_per_image": per["psnr"].tolist(),
            "ssim_per_image": per["ssim"].tolist()}


def restoration_per_sample(restored, undegraded, degraded) -> dict[str, np.ndarray]:
    """Per-sample ``voxel_l1``, ``voxel_psnr``, ``voxel_l1_all`` and ``mask_fraction``
    of (N, B, H, W) voxel grids (module docstring)."""
    r = _numpy(restored).astype(np.float64)
    u = _numpy(undegraded).astype(np.float64)
    d = _numpy(degraded).astype(np.float64)
    if not (r.shape == u.shape == d.shape) or r.ndim != 4:
        raise ValueError(f"expected three (N, B, H, W) arrays of one shape, got {r.shape}, {u.shape}, {d.shape}")
    n = r.shape[0]
    m = ((u != 0) | (d != 0)).reshape(n, -1)
    err = (r - u).reshape(n, -1)
    cnt = m.sum(1)
    safe = np.maximum(cnt, 1)
    l1 = np.where(cnt > 0, (np.abs(err) * m).sum(1) / safe, 0.0)
    mse = np.where(cnt > 0, (err ** 2 * m).sum(1) / safe, 0.0)
    peak = np.where(m, np.abs(u.reshape(n, -1)), 0.0).max(1)
    peak = np.where(peak > 0, peak, 1.0)
    with np.errstate(divide="ignore"):
        psnr = np.where(mse > 0, 10.0 * np.log10(peak ** 2 / np.where(mse > 0, mse, 1.0)), np.inf)
    return {"voxel_l1": l1, "voxel_psnr": psnr, "voxel_l1_all": np.abs(err).mean(1),
            "mask_fraction": cnt / max(m.shape[1], 1)}


def restoration_metrics(restored, undegraded, degraded) -> dict:
    """Mean restoration metrics over samples (:func:`restoration_per_sample`) and ``n``."""
    per = restoration_per_sample(restored, undegraded, degraded)
    out = {k: float(np.mean(v)) for k, v in per.items()}
    out["n"] = int(per["voxel_l1"].size)
    return out


# --- breakdowns -----------------------------------------------------------------------
def level_edges(levels, bins: int = 5) -> np.ndarray:
    """``bins + 1`` equal-width edges spanning the degradation levels (one bin when all
    levels are equal)."""
    lv = np.asarray(levels, np.float64)
    lo, hi = float(lv.min()), float(lv.max())
    if hi <= lo:
        return np.array([lo, lo])
    return np.linspace(lo, hi, int(bins) + 1)


def group_means(values: Mapping[str, Sequence[float]], labels: Sequence) -> list[dict]:
    """Mean of every per-sample metric within each group label: a list of
    ``{"group": label, "n": count, <metric>: mean}`` in sorted label order. NaN values
    (image metrics of samples without motion, :func:`motion_only`) are left out of a
    metric's mean; a metric with no value in the group is None."""
    labels = np.asarray(labels)
    out = []
    for g in sorted(set(labels.tolist()), key=lambda x: (str(type(x)), x)):
        sel = labels == g
        row = {"group": g, "n": int(sel.sum())}
        for k, v in values.items():
            x = np.asarray(v, np.float64)[sel]
            x = x[~np.isnan(x)]
            row[k] = float(np.mean(x)) if x.size else None
        out.append(row)
    return out


def by_level(values: Mapping[str, Sequence[float]], levels, bins: int = 5,
             edges: np.ndarray | None = None) -> list[dict]:
    """Per-sample metrics averaged within equal-width degradation-level bins
    (:func:`level_edges`, or the given ``edges``): a list of
    ``{"level_bin": centre, "level_lo", "level_hi", "n", <metric>: mean}`` for the
    non-empty bins, lowest level first. The last bin is closed on the right."""
    lv = np.asarray(levels, np.float64)
    e = level_edges(lv, bins) if edges is None else np.asarray(edges, np.float64)
    idx = np.clip(np.searchsorted(e, lv, side="right") - 1, 0, len(e) - 2)
    out = []
    for row in group_means(values, idx):
        b = int(row.pop("group"))
        out.append({"level_bin": float((e[b] + e[b + 1]) / 2), "level_lo": float(e[b]),
                    "level_hi": float(e[b + 1]), **row})
    return out


def dominant_degradation(degrade: Mapping[str, Sequence[float]]) -> np.ndarray:
    """Per sample, the name of the degradation with the largest *relative* strength:
    each ``/degrade/<key>`` column is scaled by its maximum over the file
    (``onoff_ratio`` as ``|log ratio|``, so 1 = off); "none" where all are off.
    A coarse grouping for per-degradation tables (values have different units).
    A column that holds one value for every sample is left out: it tells the samples
    nothing apart, and scaled by its maximum it would read 1 everywhere and name every
    sample whose randomised degradations are all below their maxima (the shape keys
    such as ``leak_spread_decades`` or ``hot_pixel_on_fraction``, which the study does not
    randomise, did so: 9 of the 37 test samples)."""
    keys = sorted(degrade)
    if not keys:
        raise ValueError("no degradation columns")
    cols = []
    for k in keys:
        v = np.asarray(degrade[k], np.float64)
        v = np.abs(np.log(np.where(v > 0, v, 1.0))) if k == "onoff_ratio" else np.abs(v)
        mx = float(v.max()) if v.size else 0.0
        constant = v.size > 1 and bool(np.all(v == v[0]))
        cols.append(v / mx if mx > 0 and not constant else np.zeros_like(v))
    s = np.stack(cols, 1)
    names = np.array(keys, dtype=object)[np.argmax(s, 1)]
    names[s.max(1) <= 0] = "none"
    return names.astype(str)
