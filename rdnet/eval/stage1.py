"""Stage 1 (:class:`rdnet.nn.models.RestoreNet`) run once: the restored signed voxel and,
with the checkpoint's voxel -> event decision, the restored *events*, from one forward pass.

:func:`rdnet.nn.decision.decided_events` runs the network itself; evaluation
(:mod:`rdnet.eval.predict`) and ``rdnet deblur`` (:mod:`rdnet.deblur.pipeline`) also need
the restored voxel, so they call :func:`run_stage1`, which applies the same rules
(:func:`rdnet.nn.decision.events_from_heads`, :func:`~rdnet.nn.decision.events_from_signed`)
to the heads of the one pass: the results are identical to a second pass through
``decided_events``, at half the cost.

:func:`signed_counts` is the ON - OFF signed voxel of per-polarity count grids in numpy
(the networks' own outputs go through :meth:`RestoreNet.signed`).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
import torch

from rdnet.errors import ValidationError
from rdnet.nn.decision import events_from_heads, events_from_signed


def run_stage1(stage1, image: torch.Tensor | None, x: torch.Tensor,
               decision: Mapping | None = None) -> tuple[torch.Tensor, np.ndarray | None]:
    """One forward pass of the stage-1 network ``stage1`` on the torch inputs ``image``
    (None for events-only) and ``x`` (the signed voxel, or ON-then-OFF counts for the
    count output). Returns ``(restored, events)``: ``restored`` the signed voxel tensor
    (n, bins, H, W) that stage 2 reads (``stage1.signed(stage1(image, x))``; expected ON -
    OFF counts for the count output) and ``events`` the (n, 2, bins, H, W) int64 restored
    events with ``decision`` applied (what :func:`rdnet.nn.decision.decided_events` gives),
    None without a decision."""
    with torch.inference_mode():
        if stage1.output == "counts":
            mu, logit = stage1(image, x, return_heads=True)
            prob = torch.sigmoid(logit)
            out = prob * mu                          # RestoreNet.forward's expected counts
            events = None if decision is None else events_from_heads(mu, prob, decision, x)
        else:
            out = stage1(image, x)
            events = None if decision is None else events_from_signed(out)
        return stage1.signed(out), events


def signed_counts(counts: np.ndarray) -> np.ndarray:
    """The signed voxel ON - OFF (..., bins, H, W) of per-polarity counts (..., 2, bins,
    H, W), ON first (the layout of ``voxel_grid(polarity="split")`` and
    :func:`rdnet.nn.decision.polarity_grid`); the dtype is kept."""
    c = np.asarray(counts)
    if c.ndim < 4 or c.shape[-4] != 2:
        raise ValidationError("counts", f"expected (..., 2, bins, H, W) per-polarity counts, got {c.shape}")
    return c[..., 0, :, :, :] - c[..., 1, :, :, :]
