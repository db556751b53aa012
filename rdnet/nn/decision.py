"""The voxel -> event decision of the count-output restoration network.

:class:`rdnet.nn.models.RestoreNet` with ``output="counts"`` gives, per polarity voxel,
an occupancy probability ``p = sigmoid(logit)`` and a count given occupied ``mu >= 1``.
The decision turns them into whole events::

    n = round(mu)   where p >= threshold,   0 elsewhere

The threshold is *fitted* after training on held-out validation rows of the training
split (never the test split, :func:`fit_threshold`): the lowest threshold at which the
restored event count does not exceed the undegraded event count of those rows (count
ratio 1 on validation). It is stored in the checkpoint (``extra["decision"]``, a plain
dict :func:`decision_dict`) so that inference applies the same rule.

The signed output of the paper has no fitted decision: ``round(v)`` events of sign
``sign(v)`` per voxel (:func:`rdnet.events.voxel.voxel_events`), ``{"rule": "round"}``.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from rdnet.errors import ValidationError

RULE_THRESHOLD = "occupancy_threshold"
RULE_ROUND = "round"


def decide_counts(mu: np.ndarray, prob: np.ndarray, threshold: float) -> np.ndarray:
    """Whole non-negative event counts (int64, the shape of ``mu``): ``round(mu)`` where
    ``prob >= threshold``, else 0."""
    mu, prob = np.asarray(mu), np.asarray(prob)
    if mu.shape != prob.shape:
        raise ValidationError("decision", f"mu {mu.shape} and probabilities {prob.shape} differ")
    return np.where(prob >= threshold, np.rint(np.maximum(mu, 1.0)), 0).astype(np.int64)


def fit_threshold(mu: np.ndarray, prob: np.ndarray, target_total: int) -> float:
    """The lowest occupancy threshold whose decided count does not exceed ``target_total``
    (exact over the given voxels: voxels sorted by probability, counts accumulated).
    Returns a value in (0, 1]; 1.0 + tiny when even the most confident voxel overshoots."""
    p = np.asarray(prob, np.float64).ravel()
    n = np.rint(np.maximum(np.asarray(mu, np.float64).ravel(), 1.0))
    if p.shape != n.shape:
        raise ValidationError("decision", f"mu {np.shape(mu)} and probabilities {np.shape(prob)} differ")
    order = np.argsort(-p, kind="stable")
    ps, cum = p[order], np.cumsum(n[order])
    # keeping the k most probable voxels keeps cum[k - 1] events; ties must go together
    last_of_tie = np.r_[ps[1:] != ps[:-1], True]
    ok = np.flatnonzero(last_of_tie & (cum <= target_total))
    if ok.size == 0:
        return float(np.nextafter(ps[0], np.inf)) if ps.size else 0.5
    return float(ps[ok[-1]])


def decision_dict(threshold: float | None, **info) -> dict:
    """The ``extra["decision"]`` entry of a checkpoint: the rule, its threshold (None for
    the signed output's rounding) and plain provenance values (``info``)."""
    if threshold is None:
        return {"rule": RULE_ROUND, "threshold": None, **info}
    return {"rule": RULE_THRESHOLD, "threshold": float(threshold), **info}


def read_decision(decision: Mapping | None, output: str) -> dict:
    """Validate the stored decision of a checkpoint whose stage-1 output is ``output``."""
    if output == "signed":
        return dict(decision) if decision else decision_dict(None)
    if not decision or decision.get("rule") != RULE_THRESHOLD or decision.get("threshold") is None:
        raise ValidationError("extra.decision", f"a counts restorer needs a fitted "
                              f"{RULE_THRESHOLD!r} decision, got {decision!r}")
    t = float(decision["threshold"])
    if not 0.0 <= t <= 1.0 + 1e-6:
        raise ValidationError("extra.decision.threshold", f"must be in [0, 1], got {t}")
    return dict(decision)


def split_signed(signed: np.ndarray, axis: int = -3) -> np.ndarray:
    """Per-polarity counts of a signed grid: ``[max(v, 0), max(-v, 0)]`` concatenated
    along the bin axis (ON bins then OFF bins, the count network's channel layout)."""
    v = np.asarray(signed)
    return np.concatenate([np.maximum(v, 0), np.maximum(-v, 0)], axis=axis)


def polarity_grid(counts: np.ndarray) -> np.ndarray:
    """The count network's channel layout (..., 2 * bins, H, W) (ON bins then OFF bins) as
    (..., 2, bins, H, W) polarity grids, the layout of :func:`rdnet.eval.events.match_metrics`
    (a view; which polarity comes first does not change its metrics)."""
    c = np.asarray(counts)
    if c.ndim < 3 or c.shape[-3] % 2:
        raise ValidationError("counts", f"expected (..., 2 * bins, H, W) per-polarity counts, got {c.shape}")
    return c.reshape(c.shape[:-3] + (2, c.shape[-3] // 2) + c.shape[-2:])


def events_from_heads(mu, prob, decision: Mapping | None) -> np.ndarray:
    """(n, 2, bins, H, W) int64 ON/OFF events of a count-output stage 1 from its heads
    ``mu`` and ``prob = sigmoid(logit)`` (torch tensors (n, 2 * bins, H, W)): the fitted
    occupancy threshold of ``decision`` (:func:`decide_counts`)."""
    threshold = float(read_decision(decision, "counts")["threshold"])
    return polarity_grid(decide_counts(mu.float().cpu().numpy(), prob.float().cpu().numpy(), threshold))


def events_from_signed(restored) -> np.ndarray:
    """(n, 2, bins, H, W) int64 ON/OFF events of the signed output ``restored`` (a torch
    tensor (n, bins, H, W)): ``round(v)`` events of sign ``v`` per voxel."""
    return polarity_grid(split_signed(np.rint(restored.float().cpu().numpy())).astype(np.int64))


def decided_events(stage1, image, x, decision: Mapping | None) -> np.ndarray:
    """(n, 2, bins, H, W) int64 ON/OFF event counts decided from a stage-1 network's
    output on the torch inputs ``image`` (None for events-only) and ``x`` (the signed
    voxel, or ON-then-OFF counts for the count output): the count output applies the
    fitted occupancy threshold of ``decision`` (:func:`events_from_heads`), the signed
    output rounds (:func:`events_from_signed`)."""
    import torch
    with torch.inference_mode():
        if stage1.output == "counts":
            mu, logit = stage1(image, x, return_heads=True)
            return events_from_heads(mu, torch.sigmoid(logit), decision)
        return events_from_signed(stage1(image, x))
