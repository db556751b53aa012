"""Per-sequence randomized degradation (``randomize`` section, :class:`RandomizeConfig`).

RDNet trains the restoration stage on events simulated with varied real-sensor
degradations; to measure generalisation, training and test sequences draw their
degradation strengths from *disjoint* ranges around the ``degrade`` section:

    value = base * m            (onoff_ratio: base ** m, i.e. scaled in log space;
                                 cutoff_hz: base / m, i.e. its time constant scaled)
    m ~ U(train_scale)  for split "train",  m ~ U(test_scale)  for split "test"

(a scale may be a union of ranges, drawn uniformly over the union: :func:`draw_scale`)

independently per key and per sequence. Only effects active in ``base`` are randomized
(an effect that is off stays off), so ``dvc exp run -S degrade.threshold_sigma=0.05``
changes both splits around the new value. ``hot_pixel_fraction`` and ``threshold_sigma``
are capped at 1 (their valid range), every other key at its bound
(:data:`rdnet.sim.settings.DEGRADE_UPPER_BOUNDS`; ``onoff_ratio`` also below).

For every key m = 0 is the ideal sensor and a larger m a stronger degradation. A bandwidth
limit is stronger the *lower* its cutoff (its time constant 1 / (2 pi cutoff_hz) sets the
lag), so its factor scales the time constant: m = 1.5 gives cutoff_hz / 1.5, and m -> 0 an
infinite cutoff, the limit switched off (cutoff_hz = 0). Until 2026-11-29 the cutoff was
scaled like the other keys (base * m), which gave the test split (m 1.0-1.5) a *weaker*
bandwidth limit than the training split (m 0.5-0.9), and a training range reaching towards
0 a lag growing without bound (docs/restoration.md, "The bandwidth limit's scale").
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from rdnet.errors import ConfigError
from rdnet.sim.settings import (DEGRADE_LOWER_BOUNDS, DEGRADE_UPPER_BOUNDS, EFFECT_KEYS, EFFECT_SCALING, DegradeConfig,
                                RandomizeConfig)

__all__ = ["RandomizeConfig", "draw_degrade", "draw_scale", "scale_degrade", "degradation_level", "degrade_factors"]

_CAPPED = {"hot_pixel_fraction": 1.0, "threshold_sigma": 1.0, **DEGRADE_UPPER_BOUNDS}

#: per kind of :data:`rdnet.sim.settings.EFFECT_SCALING`: (value scaled by m, the m that turns
#: ``base`` into ``value``)
_SCALE = {
    "linear": (lambda v, m: v * m, lambda base, v: v / base),
    "log": (lambda v, m: v ** m, lambda base, v: math.log(v) / math.log(base)),
    "inverse": (lambda v, m: v / m if m > 0 else 0.0, lambda base, v: base / v if v else 0.0),
}


def scale_degrade(base: DegradeConfig, factors: dict[str, float]) -> DegradeConfig:
    """``base`` with each key of ``factors`` scaled (``onoff_ratio`` in log space,
    ``cutoff_hz`` inversely: module docstring), capped at the key's valid range."""
    new = {}
    for k, m in factors.items():
        if k not in EFFECT_KEYS:
            raise ConfigError(f"degrade.{k}", "not a degradation effect")
        v = _SCALE[EFFECT_SCALING[k]][0](getattr(base, k), m)
        v = min(v, _CAPPED[k]) if k in _CAPPED else v
        new[k] = max(v, DEGRADE_LOWER_BOUNDS[k]) if k in DEGRADE_LOWER_BOUNDS else v
    return dataclasses.replace(base, **new)


def draw_scale(ranges, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` factors drawn uniformly over the union of ``ranges`` ((lo, hi) pairs; a
    range is picked with probability proportional to its length). One range is one
    ``rng.uniform(lo, hi, n)`` call (the draws of a single-range config do not change)."""
    ranges = [(float(a), float(b)) for a, b in ranges]
    if len(ranges) == 1:
        lo, hi = ranges[0]
        return rng.uniform(lo, hi, size=n)
    lengths = np.array([b - a for a, b in ranges])
    if lengths.sum() <= 0:                       # only points: pick one per draw
        return np.array([a for a, _ in ranges])[rng.integers(0, len(ranges), size=n)]
    u = rng.uniform(0.0, lengths.sum(), size=n)  # a position along the ranges laid end to end
    edges = np.cumsum(lengths)
    k = np.minimum(np.searchsorted(edges, u, side="right"), len(ranges) - 1)
    lo = np.array([a for a, _ in ranges])
    return lo[k] + (u - (edges[k] - lengths[k]))


def draw_degrade(base: DegradeConfig, cfg: RandomizeConfig, split: str,
                 rng: np.random.Generator) -> DegradeConfig:
    """Degradation of one sequence of ``split`` ("train" or "test").

    One factor is drawn for every key of :data:`EFFECT_KEYS` in order (so the draws of a
    key do not depend on which other keys are active); it is applied to the keys that are
    randomized (``cfg.keys``, default all) and active in ``base``. In the training split a
    key with a scale of its own (``cfg.train_scale_keys``) then draws once more, from that
    scale, in :data:`EFFECT_KEYS` order, and that factor replaces its shared one."""
    if split not in ("train", "test"):
        raise ConfigError("split", f"must be 'train' or 'test', got {split!r}")
    if not cfg.enabled:
        return base
    draws = draw_scale(cfg.train_ranges if split == "train" else cfg.test_ranges, len(EFFECT_KEYS), rng)
    m = dict(zip(EFFECT_KEYS, draws))
    if split == "train":
        for k in (k for k in EFFECT_KEYS if k in cfg.train_scale_keys):
            m[k] = draw_scale(cfg.train_ranges_of(k), 1, rng)[0]
    keys = set(cfg.keys) if cfg.keys else set(EFFECT_KEYS)
    active = set(base.active())
    factors = {k: float(m[k]) for k in EFFECT_KEYS if k in keys and k in active}
    return scale_degrade(base, factors)


def degrade_factors(d: DegradeConfig, base: DegradeConfig) -> dict[str, float]:
    """Per active key of ``base``: the factor m with d = base * m (onoff_ratio: base ** m;
    cutoff_hz: base / m, 0 when ``d`` has no bandwidth limit)."""
    return {k: _SCALE[EFFECT_SCALING[k]][1](getattr(base, k), getattr(d, k)) for k in base.active()}


def degradation_level(d: DegradeConfig, base: DegradeConfig) -> float:
    """Scalar degradation strength of ``d`` relative to ``base`` (for "quality vs
    degradation" plots): the mean of :func:`degrade_factors` over the effects active in
    ``base`` (1.0 = the ``degrade`` section itself, 0.0 = ideal); 0.0 when ``base`` is ideal."""
    f = degrade_factors(d, base)
    return float(np.mean(list(f.values()))) if f else 0.0
