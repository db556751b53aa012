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

**Support** (optional, ``decision["support"]``): a voxel is *unsupported* when none of
the 8 neighbouring pixels holds an input event anywhere in the window (either polarity,
any bin; :func:`input_support`). An isolated input event is one; so is an event the network
moves or adds at such a pixel. The decision drops the unsupported voxels it would keep when,
on the validation rows, the unsupported voxels the threshold keeps are matched by
undegraded events less often than the threshold itself (their calibrated probability is
below it: :func:`fit_support`); the threshold is then refitted to the count target without
them. Why: the trained count networks keep about 80 % of the isolated input events while
3 % of them are real (validation rows of the study's restorers; docs/restoration.md, "Events
with no neighbour"): the identity start (+4 on the logit of every occupied input voxel)
and a class that is 1 % of the events leave them miscalibrated. Decisions without the key
(checkpoints written before it) do not apply it. The paths that decide voxel entries
(:func:`decided_entries`, :func:`sparse_decided_entries`: inference) read the input's
occupancy at the kept voxels' neighbours only (:func:`entry_support`); those that decide
whole grids (:func:`decide_counts`, the fits) use the whole-frame map (:func:`input_support`).

**Count gain** (optional, ``decision["count_gain"]``, ``train.fit_count_gain``, off in the
study): the count head's excess over one event scaled, ``1 + g (mu - 1)``
(:func:`gained`), with ``g`` the gain of :data:`COUNT_GAINS` whose decided events score the
best F1 on the validation rows, the threshold refitted for each (:func:`fit_count_gain`).
It raised the simulated test F1 but lost real motion (docs/restoration.md), so the study's
decisions have none; without the key the gain is 1 and the counts keep their bits.

The signed output of the paper has no fitted decision: ``round(v)`` events of sign
``sign(v)`` per voxel (:func:`rdnet.events.voxel.voxel_events`), ``{"rule": "round"}``.

The rule is stated on probabilities (the stored threshold, :func:`decide_counts`), where a
float32 probability is compared with the threshold rounded to float32. Inference
(:func:`decided_events`, :func:`decided_entries`) applies it to the logits instead,
``logit >= logit_threshold(threshold)``, which skips the sigmoid and, since only the few
kept voxels are read afterwards, every dense pass but one comparison:
:func:`logit_threshold` is the smallest float32 logit whose ``torch.sigmoid`` reaches the
threshold, searched with torch's own sigmoid, so both forms keep the same voxels
(``tests/nn/test_decision_logits.py`` checks every float32 near the boundary).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Mapping

import numpy as np

from rdnet.errors import ValidationError

RULE_THRESHOLD = "occupancy_threshold"
RULE_ROUND = "round"


def decide_counts(mu: np.ndarray, prob: np.ndarray, threshold: float, supported=None,
                  gain: float = 1.0) -> np.ndarray:
    """Whole non-negative event counts (int64, the shape of ``mu``): ``round(mu)`` where
    ``prob >= threshold``, else 0; with ``supported`` (bool, broadcastable to ``mu``, e.g.
    (n, 1, H, W) from :func:`input_support`) also 0 where it is False; ``gain``: the count
    head's excess over one event scaled (:func:`gained`)."""
    mu, prob = np.asarray(mu), np.asarray(prob)
    if mu.shape != prob.shape:
        raise ValidationError("decision", f"mu {mu.shape} and probabilities {prob.shape} differ")
    keep = prob >= threshold
    if supported is not None:
        keep = keep & np.asarray(supported, bool)
    return np.where(keep, np.rint(np.maximum(gained(mu, gain), 1.0)), 0).astype(np.int64)


def gained(mu, gain: float):
    """The count head with its excess over one event scaled: ``1 + gain (mu - 1)``; ``mu``
    itself (the same object) for gain 1, so decisions without a fitted gain keep their bits."""
    return mu if gain == 1.0 else 1.0 + gain * (mu - 1.0)


#: the count gains :func:`fit_count_gain` tries (1 = the count head as it is).
COUNT_GAINS = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)


def decision_gain(decision: Mapping | None) -> float:
    """The fitted count gain of ``decision`` (1 when it has none)."""
    g = (decision or {}).get("count_gain")
    return 1.0 if g is None else float(g["gain"])


def fit_count_gain(mu: np.ndarray, prob: np.ndarray, target: np.ndarray, supported, score,
                   gains=COUNT_GAINS) -> tuple[float, float, dict]:
    """The count gain of the decision, fitted on validation rows: for each gain the
    threshold is refitted to the count target (:func:`fit_threshold`, over the supported
    voxels when ``supported`` is given) and the decided events scored by ``score(counts) ->
    F1``; the gain with the highest F1 wins (the smallest on ties). Returns ``(gain,
    threshold, info)``."""
    mu, prob = np.asarray(mu), np.asarray(prob)
    p = prob if supported is None else np.where(np.broadcast_to(np.asarray(supported, bool), prob.shape), prob, 0.0)
    total = int(np.rint(np.asarray(target)).sum())
    tried = []
    for g in gains:
        t = fit_threshold(gained(mu, g), p, total)
        tried.append((float(score(decide_counts(mu, prob, t, supported, g))), -float(g), float(t)))
    f1, neg_g, t = max(tried)
    info = {"gain": -neg_g, "val_f1": {f"{-ng:g}": f for f, ng, _ in tried},
            "thresholds": {f"{-ng:g}": tt for _, ng, tt in tried}}
    return -neg_g, t, info


#: ``decision["support"]["rule"]``: the one support rule (module docstring).
SUPPORT_RULE = "neighbour_in_window"


def neighbour_support(occupied: np.ndarray) -> np.ndarray:
    """For a bool (..., H, W) map of pixels with input events: whether any of each pixel's 8
    neighbours has one (the pixel itself does not count; outside the sensor counts as empty)."""
    occ = np.asarray(occupied, bool)
    H, W = occ.shape[-2:]
    pad = np.zeros(occ.shape[:-2] + (H + 2, W + 2), np.int16)
    pad[..., 1:-1, 1:-1] = occ
    total = np.zeros(occ.shape, np.int16)
    for dy in range(3):
        for dx in range(3):
            total += pad[..., dy:dy + H, dx:dx + W]
    return (total - occ) > 0


def input_occupancy(counts) -> np.ndarray:
    """(n, H, W) bool: the pixels with an input event anywhere in the window, from a stage-1
    count input: an array or torch tensor (n, C, H, W) (any channel > 0 is an event), or a
    :class:`rdnet.nn.sparse.SparseVoxels` (one sample)."""
    from rdnet.nn.sparse import SparseVoxels
    if isinstance(counts, SparseVoxels):
        _, H, W = counts.shape
        _, y, x = counts.coords()
        occ = np.zeros((1, H, W), bool)
        v = counts.values > 0
        occ[0, y[v], x[v]] = True
        return occ
    if hasattr(counts, "detach"):
        return (counts.detach() > 0).any(1).cpu().numpy()
    return (np.asarray(counts) > 0).any(1)


def input_support(counts) -> np.ndarray:
    """(n, 1, H, W) bool: the pixels with an input event among their 8 neighbours in the window
    (:func:`neighbour_support` of :func:`input_occupancy`), for every pixel of the frame (the
    dense decision paths: :func:`decide_counts`, the fits)."""
    return neighbour_support(input_occupancy(counts))[:, None]


def entry_support(index: np.ndarray, shape: tuple, inputs) -> np.ndarray:
    """(k,) bool: whether the pixel of each entry ``index`` (flat C-order positions in
    ``shape`` = (n, C, H, W)) has an input event among its 8 neighbours in the window (the rule
    of :func:`input_support`), for the few kept voxels of a decision: the input's occupancy
    (:func:`input_occupancy`) is read at the entries' 8 neighbours only, with no neighbour sum
    over the whole frame."""
    n, C, H, W = shape
    occ = np.zeros((n, H + 2, W + 2), bool)               # one pixel of empty border
    occ[:, 1:-1, 1:-1] = input_occupancy(inputs)
    index = np.asarray(index, np.int64)
    pix = index % (H * W)
    row = W + 2
    at = (index // (C * H * W)) * (H + 2) * row + (pix // W + 1) * row + pix % W + 1
    flat = occ.reshape(-1)
    found = np.zeros(index.size, bool)
    for off in (-row - 1, -row, -row + 1, -1, 1, row - 1, row, row + 1):
        found |= flat[at + off]
    return found


def support_applies(decision: Mapping | None) -> bool:
    """Whether ``decision`` drops unsupported voxels (module docstring)."""
    sup = (decision or {}).get("support")
    if not sup:
        return False
    if sup.get("rule") != SUPPORT_RULE:
        raise ValidationError("extra.decision.support.rule", f"unknown support rule {sup.get('rule')!r}; "
                              f"known: {SUPPORT_RULE!r}")
    return bool(sup.get("drop"))


def fit_support(mu: np.ndarray, prob: np.ndarray, target: np.ndarray, supported: np.ndarray,
                threshold: float) -> tuple[float, dict]:
    """The support part of the decision, fitted on validation rows: ``(threshold, support)``.
    ``mu``, ``prob``, ``target`` (undegraded counts) are (n, C, H, W), ``supported`` (n, 1,
    H, W) from :func:`input_support` of the rows' inputs. The unsupported voxels that
    ``threshold`` keeps are scored by their precision (events matched by undegraded events
    of the same voxel over events kept); when it is below ``threshold`` they are dropped and
    the threshold is refitted (:func:`fit_threshold`) to the same count target over the
    supported voxels alone."""
    mu, prob, target = (np.asarray(a) for a in (mu, prob, target))
    sup = np.broadcast_to(np.asarray(supported, bool), mu.shape)
    kept = decide_counts(mu, prob, threshold)
    un = kept * ~sup
    n_un = int(un.sum())
    matched = int(np.minimum(un, np.rint(target).astype(np.int64)).sum())
    precision = matched / n_un if n_un else None
    drop = precision is not None and precision < threshold
    info = {"rule": SUPPORT_RULE, "drop": bool(drop), "val_precision": precision,
            "val_events": n_un, "val_share_of_kept": n_un / max(int(kept.sum()), 1),
            "threshold_before": float(threshold)}
    if drop:
        threshold = fit_threshold(mu, np.where(sup, prob, 0.0), int(np.rint(target).sum()))
    return float(threshold), info


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
    support_applies(decision)          # an unknown support rule is refused here, before any use
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


def events_from_heads(mu, prob, decision: Mapping | None, inputs=None) -> np.ndarray:
    """(n, 2, bins, H, W) int64 ON/OFF events of a count-output stage 1 from its heads
    ``mu`` and ``prob = sigmoid(logit)`` (torch tensors (n, 2 * bins, H, W)): the fitted
    occupancy threshold of ``decision`` (:func:`decide_counts`) and, when the decision has
    one, its support rule on the network's count ``inputs`` (required then)."""
    threshold = float(read_decision(decision, "counts")["threshold"])
    return polarity_grid(decide_counts(mu.float().cpu().numpy(), prob.float().cpu().numpy(), threshold,
                                       _support_of(decision, inputs), decision_gain(decision)))


def _support_of(decision: Mapping | None, inputs) -> np.ndarray | None:
    """:func:`input_support` of ``inputs`` when ``decision`` applies its support rule, else None."""
    if not support_applies(decision):
        return None
    if inputs is None:
        raise ValidationError("decision", "this decision drops unsupported voxels: pass the network's inputs")
    return input_support(inputs)


def events_from_signed(restored) -> np.ndarray:
    """(n, 2, bins, H, W) int64 ON/OFF events of the signed output ``restored`` (a torch
    tensor (n, bins, H, W)): ``round(v)`` events of sign ``v`` per voxel."""
    return polarity_grid(split_signed(np.rint(restored.float().cpu().numpy())).astype(np.int64))


@lru_cache(maxsize=64)
def logit_threshold(threshold: float) -> float:
    """The occupancy threshold on the logit: for a float32 logit ``x``,
    ``x >= logit_threshold(t)`` keeps the voxels that ``torch.sigmoid(x) >= t`` keeps with
    ``t`` rounded to float32 (how :func:`decide_counts` compares a float32 probability).

    The smallest float32 ``x`` with ``torch.sigmoid(x) >= float32(t)``, found by searching
    the float32 values in order with torch's sigmoid itself (1,025 candidates a round,
    from -inf to +inf), so the rounding of the sigmoid is reproduced, not approximated by
    ``log(t / (1 - t))`` (for ``t = 0.5`` that is 0, while ``sigmoid(-1.7e-7)`` already
    rounds to 0.5). Exact as long as torch's vectorised float32 sigmoid does not decrease
    (the tests check every float32 within 4,096 steps of the answer); the last few
    elements of a tensor, which torch computes in a scalar loop, can round an ulp
    differently. ``-inf`` when every logit passes (``t <= 0``), ``+inf`` when none can
    (``t`` above 1 in float32: :func:`decided_entries` then keeps nothing, also for
    infinite logits)."""
    import torch
    t32 = np.float32(threshold)
    if t32 <= 0:
        return float("-inf")
    if t32 > 1:
        return float("inf")

    def passes(keys: np.ndarray) -> np.ndarray:
        # padded to whole SIMD vectors: torch's scalar tail loop can round its last ulp
        # differently from the vectorised body, which is what a large tensor goes through
        x = _ordered_to_float(np.r_[keys, np.full(-keys.size % 64, keys[-1])])
        return (torch.sigmoid(torch.from_numpy(x)) >= float(t32)).numpy()[:keys.size]

    return _smallest_passing(passes)         # sigmoid(+inf) = 1 >= t: +inf passes


def _smallest_passing(passes) -> float:
    """The smallest float32 ``x`` for which the monotone predicate ``passes`` holds, given
    that it fails at -inf and holds at +inf: the float32 values are searched in order as
    integer keys (:func:`_float_to_ordered`), 1,025 candidates a round. ``passes`` takes an
    int64 array of keys and returns a bool array."""
    lo, hi = int(_float_to_ordered(np.float32(-np.inf))), int(_float_to_ordered(np.float32(np.inf)))
    while hi - lo > 1:
        cand = np.unique(np.linspace(lo, hi, 1025).round().astype(np.int64))
        first = int(np.argmax(passes(cand)))        # the last candidate (hi) passes
        lo, hi = int(cand[first - 1]) if first > 0 else lo, int(cand[first])
    return float(_ordered_to_float(np.array([hi]))[0])


@lru_cache(maxsize=64)
def offset_threshold(threshold: float, offset: float) -> float:
    """The smallest float32 ``o`` with ``float32(o + offset) >= threshold`` (float32
    arithmetic, round to nearest): ``o >= offset_threshold(t, d)`` is ``o + d >= t`` for
    every float32 ``o``, since the rounded sum does not decrease with ``o``.
    :meth:`rdnet.nn.models.RestoreNet.sparse_heads` compares the occupancy conv's output
    with it instead of adding the +-GAIN offset first. Searched over the float32 values in
    order (:func:`_smallest_passing`, as :func:`logit_threshold`), so it is exact also where
    many ``o`` round to the same sum (``o`` near 0 and ``t`` near ``d``). -inf / +inf pass
    through."""
    t, d = np.float32(threshold), np.float32(offset)
    if not np.isfinite(t):
        return float(t)

    def passes(keys: np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore"):
            return (_ordered_to_float(keys) + d) >= t

    return _smallest_passing(passes)         # -inf + d = -inf < t fails, +inf + d passes


def _float_to_ordered(x: np.ndarray) -> np.ndarray:
    """float32 -> int64 keys in the order of the values (-0.0 just below +0.0)."""
    b = np.asarray(x, np.float32).view(np.int32).astype(np.int64)
    return np.where(b < 0, -(b & 0x7FFFFFFF) - 1, b)


def _ordered_to_float(k: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_float_to_ordered`."""
    k = np.asarray(k, np.int64)
    b = np.where(k < 0, (-(k + 1)) | -0x80000000, k)
    return b.astype(np.int32).view(np.float32)


def decided_entries(mu, logit, decision: Mapping | None, inputs=None) -> tuple[np.ndarray, np.ndarray]:
    """The voxels the fitted occupancy threshold of ``decision`` keeps, from the heads
    ``mu`` and ``logit`` of a count-output stage 1 (torch tensors (n, 2 * bins, H, W), any
    memory format, e.g. channels_last): ``(index, counts)``, the flat C-order positions
    of the kept voxels in (n, 2 * bins, H, W), increasing, and their int64 event counts
    ``round(max(mu, 1))`` -- the non-zero entries of :func:`events_from_heads`'s grid
    (:func:`rdnet.events.voxel.entry_events` turns them into events). The comparison
    ``logit >= logit_threshold(threshold)`` is the one dense pass; only the kept voxels
    are read after it. With a support rule (``inputs``: the network's count input), the kept
    voxels at unsupported pixels are left out (:func:`drop_unsupported`)."""
    if mu.shape != logit.shape:
        raise ValidationError("decision", f"mu {tuple(mu.shape)} and logits {tuple(logit.shape)} differ")
    lt = _decision_logit(decision)
    if lt == float("inf"):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return drop_unsupported(*_kept_entries(logit >= lt, lambda *where: mu[where], decision_gain(decision)),
                            tuple(logit.shape), decision, inputs)


def drop_unsupported(index: np.ndarray, counts: np.ndarray, shape: tuple, decision: Mapping | None, inputs):
    """The entries ``(index, counts)`` (flat C-order positions in ``shape`` = (n, C, H, W))
    whose pixel is supported by ``inputs`` (:func:`entry_support`) when ``decision`` applies
    its support rule (``inputs`` required then); every entry otherwise."""
    if not support_applies(decision) or not index.size:
        return index, counts
    if inputs is None:
        raise ValidationError("decision", "this decision drops unsupported voxels: pass the network's inputs")
    keep = entry_support(index, shape, inputs)
    return index[keep], counts[keep]


#: the largest share of a window's pixels with support (:func:`input_support`) at which
#: :func:`sparse_decided_entries` computes the occupancy logits pixel by pixel instead of by
#: the dense conv: at a DAVIS346 window's size the two cost the same at 10-25 % of the pixels
#: (``benchmarks/bench_gated_logits.py``; a DAVIS346 window has 1.6 %)
GATED_MAX_SUPPORT = 0.1


def sparse_decided_entries(stage1, image, counts, decision: Mapping | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`decided_entries` of a count-output stage 1's heads on the torch inputs
    ``image`` (None for events-only) and ``counts`` (ON-then-OFF counts), computed with
    :meth:`rdnet.nn.models.RestoreNet.sparse_heads`: the same voxels (the logits are
    computed as in the dense heads) and their counts from ``mu`` evaluated at those voxels
    only. When the decision applies its support rule and at most
    :data:`GATED_MAX_SUPPORT` of one sample's pixels are supported, the logits are
    computed at the supported pixels alone (``sparse_heads(pixels=...)``): equal to the
    dense conv up to the order of its float32 sums, so a voxel whose logit lies within
    rounding of the cut may go the other way. Inference only (:mod:`rdnet.restore.learned`);
    call it under ``inference_mode``."""
    lt = _decision_logit(decision)
    if lt == float("inf"):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    gain = decision_gain(decision)
    shape = _count_shape(counts)
    if support_applies(decision) and shape[0] == 1:
        supported = neighbour_support(input_occupancy(counts))[0]
        if supported.mean() <= GATED_MAX_SUPPORT:
            where, mu_at = stage1.sparse_heads(image, counts, lt, pixels=np.nonzero(supported))
            return _kept_entries(where, mu_at, gain, shape)      # every one supported
    keep, mu_at = stage1.sparse_heads(image, counts, lt)
    return drop_unsupported(*_kept_entries(keep, mu_at, gain), tuple(keep.shape), decision, counts)


def _count_shape(counts) -> tuple:
    """(n, C, H, W) of a stage-1 count input (a tensor, or a one-sample
    :class:`rdnet.nn.sparse.SparseVoxels`)."""
    from rdnet.nn.sparse import SparseVoxels
    return (1, *counts.shape) if isinstance(counts, SparseVoxels) else tuple(counts.shape)


def _decision_logit(decision: Mapping | None) -> float:
    """The logit cut of a count-output ``decision`` (:func:`logit_threshold` of its
    occupancy threshold; +inf keeps nothing)."""
    return logit_threshold(float(read_decision(decision, "counts")["threshold"]))


def _kept_entries(keep, mu_at, gain: float = 1.0, shape: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(index, counts)`` of :func:`decided_entries` from the bool mask ``keep`` (torch,
    (n, C, H, W), any memory format), or from the kept voxels' ``(n, c, y, x)`` index arrays
    in a voxel grid of ``shape``, and ``mu_at(n, c, y, x)``, the count head at the kept
    voxels (index arrays, in increasing C order); ``gain``: :func:`gained`."""
    if isinstance(keep, tuple):
        where = [np.asarray(a, np.int64) for a in keep]
    else:
        shape = tuple(keep.shape)
        keep = keep.cpu()
        # read the mask in memory order (a channels_last tensor is NHWC in memory), then map
        # the positions back to the C order of (n, C, H, W)
        perm = sorted(range(keep.dim()), key=lambda d: (-keep.stride(d), d))
        view = keep.permute(*perm)
        if not view.is_contiguous():
            perm, view = list(range(keep.dim())), keep.contiguous()
        pos = np.unravel_index(np.flatnonzero(view.numpy()), tuple(view.shape))
        where = [None] * keep.dim()
        for axis, p in zip(perm, pos):
            where[axis] = p
    index = np.ravel_multi_index(tuple(where), shape).astype(np.int64)
    order = np.argsort(index, kind="stable")
    index = index[order]
    if not index.size:
        return index, np.zeros(0, np.int64)
    mu_kept = mu_at(*(w[order] for w in where)).float().cpu().numpy()
    counts = np.rint(np.maximum(gained(mu_kept, gain), 1.0)).astype(np.int64)     # decide_counts' rounding
    return index, counts


def decided_events(stage1, image, x, decision: Mapping | None) -> np.ndarray:
    """(n, 2, bins, H, W) int64 ON/OFF event counts decided from a stage-1 network's
    output on the torch inputs ``image`` (None for events-only) and ``x`` (the signed
    voxel, or ON-then-OFF counts for the count output): the count output applies the
    fitted occupancy threshold of ``decision`` on the logits (:func:`decided_entries`:
    the voxels :func:`events_from_heads` keeps), the signed output rounds
    (:func:`events_from_signed`)."""
    import torch
    with torch.inference_mode():
        if stage1.output == "counts":
            mu, logit = stage1(image, x, return_heads=True)
            index, counts = decided_entries(mu, logit, decision, x)
            out = np.zeros(tuple(logit.shape), np.int64)
            out.reshape(-1)[index] = counts
            return polarity_grid(out)
        return events_from_signed(stage1(image, x))
