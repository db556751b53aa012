"""EDI: the Event-based Double Integral (Pan, Scheerlinck, Yu, Hartley, Liu, Dai,
"Bringing a Blurry Frame Alive at High Frame-Rate with an Event Camera", CVPR 2019).

Model (Pan et al., Eq. 3-6): an event camera fires when the log intensity changes by the
contrast threshold ``c``, so the latent image at time t is ``L(t) = L(f) exp(c E(t))``
with ``E(t)`` the signed event integral from the reference time f to t at each pixel. A
blurry frame is the mean of L over its exposure, hence::

    L(f) = B / ( 1/T * integral_exposure exp(c E(t)) dt )          (EDI, Eq. 6)

Discretisation (ours): the exposure is cut into ``n_steps`` equal steps; the per-step
signed event counts (a voxel grid with ``n_steps`` bins, :func:`rdnet.events.voxel_grid`)
are cumulated to give E at the step boundaries, E at the reference time is interpolated
linearly between boundaries, and the integral is the trapezoid rule over the boundaries.
:func:`edi_from_voxel` applies the same formula to a voxel grid of B bins: the event
times inside a bin are unknown, so E is known only at bin boundaries and is taken as
varying linearly inside each bin (trapezoid rule) -- an approximation at bin resolution.

The contrast ``c`` is unknown; as in Pan et al. (Sec. 4.3) it is chosen per image by
minimising an energy of the result combining an edge term and total variation::

    energy(c) = -NCC(|Sobel L(f; c)|, |events near f|) + tv_weight * TV(L(f; c)) / TV(B)

NCC is the normalised cross-correlation between the gradient magnitude of the latent
image and the event count in a short window (``window`` x exposure) around the
reference time -- edges of the sharp image sit where events fire at f; the TV term
penalises the ghost edges of a too-large ``c`` (TV alone is minimal at c -> 0, the blurry
image; the edge term alone overshoots ~1.5-2x). ``tv_weight = 0.1`` is our choice
(Pan et al. do not give theirs); on synthetic translating textures it finds ``c``
within 10 % of the true threshold for moderate blur (12 px) and within ~0.75-1.4x for
6-20 px. The search is a log-spaced grid over ``c_range`` refined by golden-section
search in the bracket around the best grid point.

Images are linear intensity; a colour image (H, W, 3) shares the per-pixel denominator
(one monochrome event stream) across channels.
"""
from __future__ import annotations

import math

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events
from rdnet.events.voxel import voxel_grid

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def _boundaries(counts: np.ndarray) -> np.ndarray:
    """(S, H, W) per-step signed counts -> (S + 1, H, W) cumulative E at step boundaries."""
    S, H, W = counts.shape
    E = np.zeros((S + 1, H, W), np.float64)
    np.cumsum(counts, axis=0, out=E[1:])
    return E


def _denominator(E: np.ndarray, ref_pos: float, c: float) -> np.ndarray:
    """1/T * integral exp(c (E(t) - E(ref))) dt by the trapezoid rule on the boundaries."""
    S = E.shape[0] - 1
    k = min(int(math.floor(ref_pos)), S - 1)
    w = ref_pos - k
    Eref = (1.0 - w) * E[k] + w * E[k + 1]
    ex = np.exp(c * (E - Eref))
    return (ex[1:-1].sum(axis=0) + 0.5 * (ex[0] + ex[-1])) / S


def _apply(blurry: np.ndarray, den: np.ndarray) -> np.ndarray:
    return blurry / (den[..., None] if blurry.ndim == 3 else den)


def _sobel_mag(img: np.ndarray) -> np.ndarray:
    import cv2
    g = img.mean(axis=-1) if img.ndim == 3 else img
    g = g.astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    return np.sqrt(gx * gx + gy * gy)


def _tv(img: np.ndarray) -> float:
    return float(np.abs(np.diff(img, axis=0)).mean() + np.abs(np.diff(img, axis=1)).mean())


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    d = math.sqrt(float((a * a).sum()) * float((b * b).sum()))
    return float((a * b).sum()) / d if d > 0 else 0.0


def _event_frame(counts: np.ndarray, ref: float, window: float) -> np.ndarray:
    """Number of events in the steps within +-window*S/2 of the reference time."""
    S = counts.shape[0]
    half = max(window * S / 2.0, 0.5)
    lo, hi = int(max(math.floor(ref - half), 0)), int(min(math.ceil(ref + half), S))
    hi = max(hi, lo + 1)
    return np.abs(counts[lo:hi]).sum(axis=0)


def edi_from_counts(blurry: np.ndarray, counts: np.ndarray, ref_pos: float | None = None,
                    c: float | None = None, c_range: tuple[float, float] = (0.05, 1.0),
                    grid: int = 16, iters: int = 20, window: float = 0.1,
                    tv_weight: float = 0.1) -> tuple[np.ndarray, float]:
    """EDI on per-step signed event counts (S, H, W) covering the exposure evenly.

    ``ref_pos`` is the reference time in steps from the exposure start (default S/2, the
    middle). ``c`` fixed skips the search. Returns (latent sharp image float32, c).
    """
    blurry = np.asarray(blurry, np.float64)
    counts = np.asarray(counts, np.float64)
    if counts.ndim != 3 or counts.shape[1:] != blurry.shape[:2]:
        raise ValidationError("events", f"voxel/count shape {counts.shape} does not match image {blurry.shape}")
    if blurry.ndim == 3 and blurry.shape[2] != 3 or blurry.ndim not in (2, 3):
        raise ValidationError("blurry", f"expected (H, W) or (H, W, 3), got {blurry.shape}")
    S = counts.shape[0]
    ref = S / 2.0 if ref_pos is None else float(ref_pos)
    if not 0.0 <= ref <= S:
        raise ValidationError("t_ref_us", f"reference {ref} steps outside the exposure [0, {S}]")
    E = _boundaries(counts)

    def result(cc):
        return _apply(blurry, _denominator(E, ref, cc))

    evf = _event_frame(counts, ref, window)
    tv0 = max(_tv(blurry), 1e-12)

    def energy(cc):
        r = result(cc)
        return -_ncc(_sobel_mag(r), evf) + tv_weight * _tv(r) / tv0

    if c is None:
        lo, hi = float(c_range[0]), float(c_range[1])
        if not 0 < lo < hi:
            raise ValidationError("c_range", f"need 0 < low < high, got {c_range}")
        cs = np.geomspace(lo, hi, grid)
        energies = [energy(cc) for cc in cs]
        i = int(np.argmin(energies))
        a, b = cs[max(i - 1, 0)], cs[min(i + 1, grid - 1)]
        # golden-section search on [a, b] (in log c)
        la, lb = math.log(a), math.log(b)
        x1, x2 = lb - _GOLDEN * (lb - la), la + _GOLDEN * (lb - la)
        f1, f2 = energy(math.exp(x1)), energy(math.exp(x2))
        for _ in range(iters):
            if f1 < f2:
                lb, x2, f2 = x2, x1, f1
                x1 = lb - _GOLDEN * (lb - la)
                f1 = energy(math.exp(x1))
            else:
                la, x1, f1 = x1, x2, f2
                x2 = la + _GOLDEN * (lb - la)
                f2 = energy(math.exp(x2))
        c = math.exp(0.5 * (la + lb))
    return result(float(c)).astype(np.float32), float(c)


def edi_deblur(blurry: np.ndarray, events: Events, t0_us: int, t1_us: int,
               t_ref_us: int | None = None, c_range: tuple[float, float] = (0.05, 1.0),
               n_steps: int = 100, c: float | None = None, **search) -> tuple[np.ndarray, float]:
    """Latent sharp image at ``t_ref_us`` (default: mid exposure) of a blurry frame
    exposed over [t0_us, t1_us], from the events of that window (EDI, Pan et al. 2019).

    ``blurry``: (H, W) or (H, W, 3) linear intensity. ``search``: keyword arguments of
    the c search (grid, iters, window, tv_weight; see :func:`edi_from_counts`).
    Returns (sharp float32, c).
    """
    if t1_us <= t0_us:
        raise ValidationError("t1_us", f"exposure end {t1_us} must follow start {t0_us}")
    if (events.height, events.width) != tuple(np.shape(blurry)[:2]):
        raise ValidationError("events", f"sensor {events.height}x{events.width} does not match image {np.shape(blurry)}")
    counts = voxel_grid(events, n_steps, int(t0_us), int(t1_us - t0_us), mode="hard")
    ref = None if t_ref_us is None else (t_ref_us - t0_us) / (t1_us - t0_us) * n_steps
    return edi_from_counts(blurry, counts, ref, c, c_range, **search)


def edi_from_voxel(blurry: np.ndarray, voxel: np.ndarray, ref_pos: float | None = None,
                   c_range: tuple[float, float] = (0.05, 1.0), c: float | None = None,
                   **search) -> tuple[np.ndarray, float]:
    """EDI from a signed-count voxel grid (B, H, W) of the exposure (hard binning, as in
    the pairs files), at bin resolution (module docstring). ``blurry`` (H, W), (H, W, 3)
    or (C, H, W) with C in {1, 3} (the pairs layout; the output keeps the input layout).
    ``ref_pos`` in bins from the start, default B/2 (mid exposure)."""
    blurry, voxel = np.asarray(blurry), np.asarray(voxel)
    chw = blurry.ndim == 3 and blurry.shape[1:] == voxel.shape[1:] and blurry.shape[:2] != voxel.shape[1:]
    if chw:
        img = blurry[0] if blurry.shape[0] == 1 else np.moveaxis(blurry, 0, -1)
        out, cc = edi_from_counts(img, voxel, ref_pos, c, c_range, **search)
        return (out[None] if blurry.shape[0] == 1 else np.moveaxis(out, -1, 0)), cc
    return edi_from_counts(blurry, voxel, ref_pos, c, c_range, **search)
