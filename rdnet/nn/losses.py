"""Losses of RDNet (Sec. 3.4 of "Restoring Real-World Degraded Events Improves Deblurring
Quality", ACM MM 2024).

Event restoration (stage 1), paper Eq. (9)::

    L_er = alpha * L1(E_r - E_u) + beta * L1(F(E_r) - F(E_u))

computed only where the undegraded ``E_u`` or the degraded ``E_d`` voxel is non-zero
(elsewhere the restored voxel is left unconstrained). ``F`` is the event encoder of the
stage-2 network (:meth:`rdnet.nn.models.DeblurNet.event_features`), a list of multi-scale
feature maps. Paper: alpha = beta = 0.5.

Masking details (our choices, the paper states only "where events exist"):

* voxel term: mask ``M = (E_u != 0) | (E_d != 0)`` per voxel (B, N_e, H, W);
* feature term: a pixel counts if ``M`` is set in any bin; that (B, 1, H, W) mask is
  max-pooled (``adaptive_max_pool2d``, i.e. a 2**l x 2**l max-pool at level l for sizes
  divisible by 2**l) to each feature map's size and broadcast over its channels; the
  per-scale masked L1 values are averaged over the scales;
* masked L1 = ``sum(|diff| * mask) / max(sum(mask), 1)`` (0 when nothing is masked);
* the target features ``F(E_u)`` are computed without gradient (a fixed target), so
  gradients of the feature term reach only ``E_r`` (and F's weights through ``F(E_r)``
  if they require grad; freeze F to use it as a fixed perceptual encoder).

Extension ``empty_weight`` (not in the paper, default 0): weight of an extra L1 term on
the voxels where both ``E_u`` and ``E_d`` are zero (pulls the restored voxel to zero
there). A prototype found that this term hurts, hence off by default.

Count output (not in the paper; ``train.restore_output: counts``,
:class:`rdnet.nn.models.RestoreNet` with ``output="counts"``), per polarity voxel with
occupancy logit ``z``, count given occupied ``mu`` and undegraded count ``u``::

    L = occupancy_weight * mean_all BCE(z, [u > 0]) + alpha * masked C(mu, u; u > 0)

with the count term ``C`` (``train.count_loss``) either the L1 ``|mu - u|`` (default; it
aims ``mu`` at the *median* count of an occupied voxel, as the paper's L1 does for the
signed voxel) or the Poisson half-deviance ``mu - u + u log(u / mu)`` (zero at ``mu = u``,
gradient ``1 - u / mu``; it aims ``mu`` at the *mean* count, which a count ratio of one
needs: counts are skewed to the right, so their median is below their mean).
The occupancy term covers EVERY voxel, so a voxel without undegraded events is pushed to
"empty" (the masked loss above leaves it free, which is why rounding the signed output
invents events); ``mu`` is the count where events are, learnt only there.

Deblurring (stage 2), paper Eq. (10): ``L_d = L1(I_d - I_s)`` (mean absolute error).
"""
from __future__ import annotations

from typing import Callable, Sequence

import torch
import torch.nn.functional as F

FeatureFn = Callable[[torch.Tensor], Sequence[torch.Tensor]]


def masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``sum(values * mask) / max(sum(mask), 1)``; ``mask`` broadcasts against ``values``."""
    mask = mask.to(values.dtype).expand_as(values)
    return (values * mask).sum() / mask.sum().clamp_min(1.0)


def masked_l1(diff: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``sum(|diff| * mask) / max(sum(mask), 1)`` (:func:`masked_mean` of ``|diff|``)."""
    return masked_mean(diff.abs(), mask)


def event_mask(undegraded: torch.Tensor, degraded: torch.Tensor) -> torch.Tensor:
    """Boolean (B, N_e, H, W): where E_u or E_d holds events."""
    return (undegraded != 0) | (degraded != 0)


def restoration_loss_terms(restored: torch.Tensor, undegraded: torch.Tensor,
                           degraded: torch.Tensor, feature_fn: FeatureFn | None = None,
                           ) -> dict[str, torch.Tensor]:
    """The unweighted terms of L_er: ``voxel`` (masked L1 on voxels), ``feature`` (masked
    multi-scale feature L1; only when ``feature_fn`` is given), ``empty`` (L1 on voxels
    with neither E_u nor E_d events)."""
    if restored.shape != undegraded.shape or restored.shape != degraded.shape:
        raise ValueError(f"shapes differ: restored {tuple(restored.shape)}, undegraded "
                         f"{tuple(undegraded.shape)}, degraded {tuple(degraded.shape)}")
    mask = event_mask(undegraded, degraded)
    diff = restored - undegraded
    terms = {"voxel": masked_l1(diff, mask), "empty": masked_l1(diff, ~mask)}
    if feature_fn is not None:
        pix = mask.any(dim=1, keepdim=True).to(restored.dtype)
        feats_r = feature_fn(restored)
        with torch.no_grad():
            feats_u = feature_fn(undegraded)
        per_scale = []
        for fr, fu in zip(feats_r, feats_u):
            m = F.adaptive_max_pool2d(pix, fr.shape[-2:])
            per_scale.append(masked_l1(fr - fu, m))
        terms["feature"] = torch.stack(per_scale).mean()
    return terms


def restoration_loss(restored: torch.Tensor, undegraded: torch.Tensor, degraded: torch.Tensor,
                     alpha: float = 0.5, feature_fn: FeatureFn | None = None, beta: float = 0.0,
                     empty_weight: float = 0.0) -> torch.Tensor:
    """L_er (paper Eq. 9) + optional ``empty_weight`` extension; a scalar tensor.

    ``restored``/``undegraded``/``degraded``: (B, N_e, H, W) voxel grids. The feature
    term is used when ``feature_fn`` is given and ``beta > 0``.
    """
    use_feat = feature_fn is not None and beta > 0
    t = restoration_loss_terms(restored, undegraded, degraded, feature_fn if use_feat else None)
    loss = alpha * t["voxel"]
    if use_feat:
        loss = loss + beta * t["feature"]
    if empty_weight > 0:
        loss = loss + empty_weight * t["empty"]
    return loss


def poisson_half_deviance(mu: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``mu - t + t log(t / mu)`` per element (``t log t = 0`` at ``t = 0``): the Poisson
    negative log-likelihood of ``t`` at rate ``mu`` less its minimum, so >= 0 and 0 at
    ``mu = t``; minimised in expectation by ``mu = E[t]``. ``mu`` must be positive."""
    t = target.to(mu.dtype)
    return mu - t + torch.xlogy(t, t) - t * torch.log(mu)


def count_loss_terms(mu: torch.Tensor, logit: torch.Tensor, undegraded: torch.Tensor,
                     count_loss: str = "l1") -> dict[str, torch.Tensor]:
    """Unweighted terms of the count-output loss (module docstring): ``occupancy`` (BCE
    over every voxel) and ``count`` (``count_loss`` of mu where the undegraded voxel has
    events: ``l1`` or ``poisson``).
    All tensors are per-polarity grids of one shape, e.g. (B, 2 * bins, H, W)."""
    if mu.shape != undegraded.shape or logit.shape != undegraded.shape:
        raise ValueError(f"shapes differ: mu {tuple(mu.shape)}, logit {tuple(logit.shape)}, "
                         f"undegraded {tuple(undegraded.shape)}")
    occupied = undegraded > 0
    if count_loss == "l1":
        count = masked_l1(mu - undegraded, occupied)
    elif count_loss == "poisson":
        count = masked_mean(poisson_half_deviance(mu, undegraded), occupied)
    else:
        raise ValueError(f"count_loss must be l1 or poisson, got {count_loss!r}")
    return {"occupancy": F.binary_cross_entropy_with_logits(logit, occupied.to(logit.dtype)),
            "count": count}


def count_restoration_loss(mu: torch.Tensor, logit: torch.Tensor, undegraded: torch.Tensor,
                           alpha: float = 0.5, occupancy_weight: float = 1.0,
                           count_loss: str = "l1") -> torch.Tensor:
    """``occupancy_weight * occupancy + alpha * count`` (:func:`count_loss_terms`)."""
    t = count_loss_terms(mu, logit, undegraded, count_loss)
    return occupancy_weight * t["occupancy"] + alpha * t["count"]


def deblur_loss(pred: torch.Tensor, sharp: torch.Tensor) -> torch.Tensor:
    """L_d = L1(I_d - I_s) (paper Eq. 10), mean absolute error."""
    if pred.shape != sharp.shape:
        raise ValueError(f"shapes differ: pred {tuple(pred.shape)}, sharp {tuple(sharp.shape)}")
    return F.l1_loss(pred, sharp)
