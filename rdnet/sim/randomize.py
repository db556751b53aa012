"""Per-sequence randomized degradation (``randomize`` section, :class:`RandomizeConfig`).

RDNet trains the restoration stage on events simulated with varied real-sensor
degradations; to measure generalisation, training and test sequences draw their
degradation strengths from *disjoint* ranges around the ``degrade`` section:

    value = base * m            (onoff_ratio: base ** m, i.e. scaled in log space)
    m ~ U(train_scale)  for split "train",  m ~ U(test_scale)  for split "test"

independently per key and per sequence. Only effects active in ``base`` are randomized
(an effect that is off stays off), so ``dvc exp run -S degrade.threshold_sigma=0.05``
changes both splits around the new value. ``hot_pixel_fraction`` and ``threshold_sigma``
are capped at 1 (their valid range).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from rdnet.errors import ConfigError
from rdnet.sim.settings import EFFECT_KEYS, DegradeConfig, RandomizeConfig

__all__ = ["RandomizeConfig", "draw_degrade", "scale_degrade", "degradation_level", "degrade_factors"]

_CAPPED = {"hot_pixel_fraction": 1.0, "threshold_sigma": 1.0}


def scale_degrade(base: DegradeConfig, factors: dict[str, float]) -> DegradeConfig:
    """``base`` with each key of ``factors`` scaled (``onoff_ratio`` in log space)."""
    new = {}
    for k, m in factors.items():
        if k not in EFFECT_KEYS:
            raise ConfigError(f"degrade.{k}", "not a degradation effect")
        v = getattr(base, k)
        v = v ** m if k == "onoff_ratio" else v * m
        new[k] = min(v, _CAPPED[k]) if k in _CAPPED else v
    return dataclasses.replace(base, **new)


def draw_degrade(base: DegradeConfig, cfg: RandomizeConfig, split: str,
                 rng: np.random.Generator) -> DegradeConfig:
    """Degradation of one sequence of ``split`` ("train" or "test").

    One factor is drawn for every key of :data:`EFFECT_KEYS` in order (so the draws of a
    key do not depend on which other keys are active); it is applied to the keys that are
    randomized (``cfg.keys``, default all) and active in ``base``."""
    if split not in ("train", "test"):
        raise ConfigError("split", f"must be 'train' or 'test', got {split!r}")
    if not cfg.enabled:
        return base
    lo, hi = cfg.train_scale if split == "train" else cfg.test_scale
    draws = rng.uniform(lo, hi, size=len(EFFECT_KEYS))
    keys = set(cfg.keys) if cfg.keys else set(EFFECT_KEYS)
    active = set(base.active())
    factors = {k: float(m) for k, m in zip(EFFECT_KEYS, draws) if k in keys and k in active}
    return scale_degrade(base, factors)


def degrade_factors(d: DegradeConfig, base: DegradeConfig) -> dict[str, float]:
    """Per active key of ``base``: the factor m with d = base * m (onoff_ratio: base ** m)."""
    out = {}
    for k in base.active():
        b, v = getattr(base, k), getattr(d, k)
        out[k] = math.log(v) / math.log(b) if k == "onoff_ratio" else v / b
    return out


def degradation_level(d: DegradeConfig, base: DegradeConfig) -> float:
    """Scalar degradation strength of ``d`` relative to ``base`` (for "quality vs
    degradation" plots): the mean of :func:`degrade_factors` over the effects active in
    ``base`` (1.0 = the ``degrade`` section itself, 0.0 = ideal); 0.0 when ``base`` is ideal."""
    f = degrade_factors(d, base)
    return float(np.mean(list(f.values()))) if f else 0.0
