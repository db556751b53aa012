"""A small synthetic pairs file (same layout as ``data/pairs/{split}.h5``, DATA.md) for
tests, smoke runs and timing benchmarks; not a substitute for the simulated data.

Each sample is a smooth random texture translated horizontally during the exposure:
``K = bins + 1`` sub-frames ``S_0 .. S_bins`` (shift ``k * speed`` pixels), blurry = their
mean (box motion blur), sharp = the middle sub-frame, ``frame_first``/``frame_last`` =
``S_0``/``S_bins`` (the window's end frames). The undegraded voxel bin ``b``
holds ``round((log(S_{b+1} + eps) - log(S_b + eps)) / threshold)`` (signed event
counts of an ideal pixel with contrast threshold ``threshold``). The degraded voxels
drop each count with probability ``drop`` and add +-1 noise with probability
``noise``; ``drop``/``noise`` per sample grow with ``/level`` in [0, 1] and are stored
as ``/degrade/refractory_us`` and ``/degrade/shot_noise_hz`` (proxies, all other
DegradeConfig keys 0 or 1 for onoff_ratio). ``noise_free=True`` writes degraded ==
undegraded. With ``polarity=True`` (default) the per-polarity count voxels
(``voxel_*_on``/``_off``: the positive and negative parts of the signed voxels) are
written too.
"""
from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np


def _smooth_texture(rng: np.random.Generator, channels: int, h: int, w: int) -> np.ndarray:
    """(C, h, w) float32 in [0.05, 0.95]: sum of a few random 2-D sinusoids."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    out = np.zeros((channels, h, w), np.float32)
    for c in range(channels):
        for _ in range(4):
            fy, fx = rng.uniform(0.02, 0.25, 2)
            ph = rng.uniform(0, 2 * np.pi)
            out[c] += np.sin(2 * np.pi * (fy * yy + fx * xx) + ph).astype(np.float32)
    out = (out - out.min()) / max(float(out.max() - out.min()), 1e-6)
    return (0.05 + 0.9 * out).astype(np.float32)


def write_synthetic_pairs(path: str | Path, n: int = 8, *, channels: int = 1, bins: int = 4,
                          height: int = 32, width: int = 32, seed: int = 0, speed: float = 1.0,
                          threshold: float = 0.2, eps: float = 0.01, split: str = "train",
                          noise_free: bool = False, polarity: bool = True) -> Path:
    """Write ``n`` synthetic samples to ``path`` (atomic, with
    :func:`rdnet.sim.blur.write_pairs`) and return the path."""
    from rdnet.sim.blur import write_pairs
    from rdnet.sim.settings import DegradeConfig

    rng = np.random.default_rng(seed)
    K = bins + 1
    pad = int(np.ceil(speed * K)) + 1
    blurry = np.empty((n, channels, height, width), np.float32)
    sharp = np.empty_like(blurry)
    first, last = np.empty_like(blurry), np.empty_like(blurry)        # the window's end frames
    vu = np.empty((n, bins, height, width), np.float32)
    vd = np.empty_like(vu)
    level = rng.uniform(0, 1, n)
    for i in range(n):
        tex = _smooth_texture(rng, channels, height, width + pad)
        subs = np.stack([tex[:, :, int(round(k * speed)):int(round(k * speed)) + width] for k in range(K)])
        blurry[i] = subs.mean(0)
        sharp[i] = subs[K // 2]
        first[i], last[i] = subs[0], subs[-1]
        logi = np.log(subs.mean(1) + eps)                     # (K, h, w) luminance proxy
        vu[i] = np.round(np.diff(logi, axis=0) / threshold)
        drop = rng.random(vu[i].shape) < 0.5 * level[i]
        noise = (rng.random(vu[i].shape) < 0.05 * level[i]) * rng.choice([-1.0, 1.0], vu[i].shape)
        vd[i] = vu[i] if noise_free else np.where(drop, 0.0, vu[i]) + noise
    degrade = {}
    for fl in fields(DegradeConfig):
        v = np.full(n, 1.0 if fl.name == "onoff_ratio" else 0.0)
        if fl.name == "refractory_us":
            v = 1000.0 * level
        elif fl.name == "shot_noise_hz":
            v = np.where(level > 0.5, 5.0 * level, 0.0)
        degrade[fl.name] = v
    samples = {"blurry": blurry, "sharp": sharp, "frame_first": first, "frame_last": last,
               "voxel_undegraded": vu, "voxel_degraded": vd,
               "sequence": np.arange(n, dtype=np.int32) // 2,
               "t0_us": np.arange(n, dtype=np.int64) * 10000, "duration_us": np.full(n, 5000, np.int64),
               "level": level, "degrade": degrade}
    if polarity:
        for kind, v in (("undegraded", vu), ("degraded", vd)):
            samples[f"voxel_{kind}_on"], samples[f"voxel_{kind}_off"] = np.maximum(v, 0), np.maximum(-v, 0)
    attrs = {"bins": bins, "voxel_mode": "hard", "channels": channels, "split": split}
    return write_pairs(path, [samples], attrs)
