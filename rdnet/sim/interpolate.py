"""Adaptive frame upsampling before event simulation (``interpolate`` section).

An event camera fires when log(I + eps) at a pixel moves by a contrast threshold; a
simulator that only sees frames must therefore be fed frames close enough in time that
the log intensity changes little between them. As in vid2e (Gehrig et al., "Video to
Events: Recycling Video Datasets for Event Cameras", CVPR 2020), the number of frames
inserted between two input frames is chosen *adaptively* per pair: here so that the
largest per-pixel change of log luminance between consecutive output frames stays below
``max_log_step`` (checked on the produced frames and refined, up to ``max_upsample``).

Interpolators:

* ``flow``: optical flow in both directions (OpenCV DIS, Kroeger et al. ECCV 2016, or
  Farneback, SCIA 2003); the flow from time t to the inputs is approximated as in Super
  SloMo (Jiang et al., CVPR 2018, Eq. 4)::

      F_t->0 = -(1 - t) t F_0->1 + t^2 F_1->0
      F_t->1 = (1 - t)^2 F_0->1 - t (1 - t) F_1->0

  both inputs are backward-warped with ``cv2.remap`` and blended with weights
  ``(1 - t) V_0`` and ``t V_1`` (Super SloMo Eq. 1). The occlusion masks come from the
  forward-backward consistency check of Sundaram et al. (ECCV 2010):
  ``|F01 + F10(x + F01)|^2 > 0.01 (|F01|^2 + |F10(x + F01)|^2) + 0.5`` marks a pixel of
  frame 0 as occluded in frame 1 (O_0, and symmetrically O_1). The occlusion happens at an
  unknown time in the interval; taking it uniform gives the expected visibilities
  ``V_0 = 1 - t O_1(x + F_t->1)`` and ``V_1 = 1 - (1 - t) O_0(x + F_t->0)``, which keep the
  frames continuous at both ends of the interval (hard masks, ``V = 1 - O``, switch an
  occluded pixel to the other input right after t = 0: log steps of up to 2.8 that no
  upsampling removes; benchmarks/bench_interpolate.py).
* ``linear``: plain blending ``(1 - t) I_0 + t I_1`` (baseline / fallback).
* ``cubic``: a Catmull-Rom spline through four frames (``i - 1, i, i + 1, i + 2``; at the
  ends of a sequence the missing one's log intensity is extrapolated linearly) of
  ``log(I + eps)`` per pixel, ``exp(.) - eps``. Piecewise-linear interpolation (``linear``,
  and ``flow``'s blend of its two warps) turns every pixel's trajectory only at the input
  frames; a DVS pixel that turns must first undo its last step (hysteresis), so its next
  event comes late in the interval, and the events of a whole sequence pile up late in every
  frame interval (on the DAVIS346 road frames, 40 ms apart, a cross-fade puts 34 % of the
  simulated events in the last fifth of the interval, against 21 % of the recorded ones;
  ``benchmarks/interpolation_phase.py``). The spline puts a
  pixel's turning points between the frames, where the scene has them, and has continuous
  slope at the frames. It uses no flow (a cross-fade with curvature), and overshoots where
  the log intensity turns, as a sampled smooth signal does.
* ``selected``: ``flow`` where the flow predicts this sequence's frames better than the
  spline of ``cubic``, the spline elsewhere (:func:`flow_weight`): every inner frame (at
  most ``select_frames`` of them, evenly spaced) is
  predicted from its two neighbours by flow and by the spline (knots ``i - 3, i - 1, i + 1,
  i + 3``), each one's squared log-luminance error is summed over the frames and smoothed
  (Gaussian, ``select_sigma_px``), the pixels where flow's is lower get weight 1, the others
  0, and that map, blurred by half the sigma, weights the flow frame against the spline's at
  every pixel (before session 34: the linear cross-fade, in the comparison and the blend). It is meant for scenes
  whose motion and lighting differ in kind: flow warps everything it sees, so it drags a
  still shadow edge along with the textured surface moving under it, while a cross-fade
  keeps such an edge in place but turns motion into a fade (issue 12;
  ``benchmarks/calib_interpolation_error.py``). Fewer than 3 frames give no prediction
  to compare: flow everywhere.
* ``none``: no frames inserted.

All arrays are float32 linear intensity; colour frames (N, H, W, 3) are warped per
channel with the flow of their luminance (ITU-R BT.601), and the log-step bound is
measured on luminance (what a DVS pixel responds to).

Why the bound can fail at the cap: intensity changes linearly in time when an edge moves
across a pixel (the pixel integrates light), and ``d log(Y + eps) / dY = 1 / (Y + eps)``
is up to ``1 / eps`` = 100 at black, so a dark pixel beside a bright edge needs ~1,000
steps per pixel of motion to keep every step under 0.1; the true high-frame-rate frames
show the same steps (benchmarks/bench_interpolate.py). ``fill_log`` is the final
guarantee: between consecutive frames that still exceed the bound it inserts frames
whose log luminance is linear in time, ``log(Y + eps) = (1 - s) L_a + s L_b`` (per
channel for colour, which bounds the luminance step too). That is exactly the trajectory
the event simulator assumes between two frames (:mod:`rdnet.sim.sensor`), so the ideal
sensor's events do not change (up to the microsecond rounding); only effects integrated
per step (low-pass, shot-noise hazard) see the finer steps. It makes the bound hold for
every pixel at the price of more steps. :class:`UpsampleStats` reports what was achieved.
"""
from __future__ import annotations

import contextlib
import dataclasses
import itertools
import logging
import math
import threading
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Iterator, Literal, Optional

import cv2
import numpy as np

from rdnet.config import check_bounds, positive
from rdnet.errors import ConfigError, ValidationError
from rdnet.sim.settings import SENSOR_LOWER_BOUNDS, SENSOR_UPPER_BOUNDS

log = logging.getLogger(__name__)

_LUMA = np.array([0.299, 0.587, 0.114], np.float32)
#: Sundaram et al. 2010 forward-backward consistency constants.
_FB_ALPHA1, _FB_ALPHA2 = 0.01, 0.5


#: ``interpolate.method`` values (:class:`InterpolateConfig`).
METHODS = ("flow", "linear", "cubic", "selected", "none")
#: the methods that compute an optical flow
FLOW_METHODS = ("flow", "selected")
#: the methods that interpolate in place with the log-intensity spline (method 'cubic')
SPLINE_METHODS = ("cubic", "selected")

#: bounds of the ``interpolate`` keys (checked by :func:`rdnet.config.check_bounds`)
UPPER_BOUNDS = {
    # a log step is bounded as a contrast threshold is: beyond e^10 no [0, 1] frame steps
    "max_log_step": SENSOR_UPPER_BOUNDS["threshold_on"],
    # frames inserted per input pair (also at most the microseconds between them), each a whole
    # frame in memory: 1024 frames of 1280x720 float32 are 3.8 GB
    "max_upsample": 1024,
    # the sensor's offset of the log, as ``sensor.log_eps`` (1e300 gave a traceback)
    "log_eps": SENSOR_UPPER_BOUNDS["log_eps"],
    # a Gaussian pooling wider than 256 px averages over most of any frame, so the choice is no
    # longer local, and OpenCV's kernel grows as 6-8 sigma (1e300 gave a traceback)
    "select_sigma_px": 256.0,
    # predicted frames for that choice: any number at least the inner frames' is every frame
    # (as 0 is); a million is over 11 hours of 25 fps frames
    "select_frames": 1_000_000}
#: a bound finer than the smallest contrast threshold only costs frames
LOWER_BOUNDS = {"max_log_step": SENSOR_LOWER_BOUNDS["threshold_on"]}


#: ``interpolate.warp`` -> (the OpenCV resampling of the warped frames, whether the result is
#: clipped to the range of the 2 x 2 source pixels around each sample)
WARPS = {"bilinear": (cv2.INTER_LINEAR, False), "bicubic": (cv2.INTER_CUBIC, False),
         "bicubic_clamped": (cv2.INTER_CUBIC, True)}


@dataclass(frozen=True)
class InterpolateConfig:
    """``interpolate`` section.

    ``method``: 'flow' (optical-flow warping), 'linear' (blending), 'cubic' (a Catmull-Rom
    spline of the log intensity through four frames), 'selected' (flow
    where it predicts the sequence's own frames better than blending, the spline elsewhere:
    module docstring) or 'none'.
    ``flow``: optical-flow algorithm, 'dis' (cv2.DISOpticalFlow) or 'farneback'.
    ``dis_preset``: DIS speed/quality preset ('ultrafast', 'fast', 'medium').
    ``dis_finest_scale``: finest pyramid level DIS computes the flow on (None: the
    preset's; medium uses 1, i.e. half resolution; 2 = quarter resolution, a coarser flow
    grid, ~3x faster: benchmarks/bench_interpolate.py reports its PSNR).
    ``max_log_step``: bound on max per-pixel |delta log(Y + eps)| between consecutive
    output frames (Y = linear luminance).
    ``max_upsample``: most output steps per input interval (inserted frames <= this - 1).
    ``log_eps``: eps of the log; None = the sensor's ``log_eps``.
    ``pixel_quantile``: fraction of pixels that must meet the bound (1.0 = every pixel;
    e.g. 0.999 ignores the few near-black pixels next to bright edges, where
    log(I + eps) is steepest and the strict maximum needs huge upsampling).
    ``occlusion``: use the forward-backward check to weight the two warps.
    ``verify``: measure the bound on the produced frames and refine the count if violated
    (otherwise the first estimate is used).
    ``warp``: how 'flow' and 'selected' resample the two frames they warp, 'bilinear'
    (``cv2.INTER_LINEAR``), 'bicubic' (``cv2.INTER_CUBIC``) or 'bicubic_clamped' (bicubic
    clipped to the range of the 2 x 2 source pixels bilinear would read: the anti-ringing
    clamp of image scalers); the flow fields and occlusion masks are resampled bilinearly
    every time. A bilinear warp by a fractional
    shift is also a low-pass filter whose strength follows the shift, so within every frame
    interval edges soften and sharpen again and the simulated events come late in the
    interval (bicubic: nearly even, as from frames rendered 64x denser;
    ``benchmarks/interpolation_phase.py``). Bicubic overshoots at sharp edges (8.5 % more
    events at a 90:1 edge, ``benchmarks/warp_edge_ringing.py``), which the clamp removes.
    The study's data use 'bilinear' (params.yaml), the calibration 'bicubic'
    (``calibrate.warp``).
    ``select_sigma_px``: 'selected' only: the Gaussian sigma (pixels) over which the two
    methods' prediction errors are pooled before choosing (:func:`flow_weight`).
    ``select_frames``: 'selected' only: at most this many inner frames, evenly spaced, are
    predicted for the choice (0 = every inner frame). Each costs two optical flows; on the
    DAVIS346 road recording 32 of its 57 choose as all 57 do at 99.7 % of the pixels, 16 at
    99.3 % (docs/calibration.md "Fewer frames for the choice").
    ``fill_log``: final guarantee. Where the frames at ``max_upsample`` still exceed the
    bound, insert log-linear frames until every pixel meets it (see the module
    docstring; limited only by integer-microsecond timestamps).
    """

    method: Literal["flow", "linear", "cubic", "selected", "none"] = "flow"
    flow: Literal["dis", "farneback"] = "dis"
    dis_preset: Literal["ultrafast", "fast", "medium"] = "medium"
    dis_finest_scale: Optional[int] = None
    max_log_step: float = 0.1
    max_upsample: int = 64
    log_eps: Optional[float] = None
    pixel_quantile: float = 1.0
    occlusion: bool = True
    verify: bool = True
    fill_log: bool = False
    select_sigma_px: float = 4.0
    select_frames: int = 32
    warp: Literal["bilinear", "bicubic", "bicubic_clamped"] = "bilinear"

    def __post_init__(self):
        if self.method not in METHODS:
            raise ConfigError("interpolate.method", f"must be one of {', '.join(METHODS)}, got {self.method!r}")
        positive("interpolate.select_sigma_px", self.select_sigma_px, allow_zero=False)
        if isinstance(self.select_frames, bool) or not isinstance(self.select_frames, int) or self.select_frames < 0:
            raise ConfigError("interpolate.select_frames",
                              f"must be an integer >= 0 (0 = every inner frame), got {self.select_frames!r}")
        if self.warp not in WARPS:
            raise ConfigError("interpolate.warp", f"must be one of {', '.join(WARPS)}, got {self.warp!r}")
        if self.flow not in ("dis", "farneback"):
            raise ConfigError("interpolate.flow", f"must be dis or farneback, got {self.flow!r}")
        if self.dis_preset not in ("ultrafast", "fast", "medium"):
            raise ConfigError("interpolate.dis_preset", f"must be ultrafast, fast or medium, got {self.dis_preset!r}")
        if self.dis_finest_scale is not None and not 0 <= self.dis_finest_scale <= 4:
            raise ConfigError("interpolate.dis_finest_scale", f"must be 0..4 or null, got {self.dis_finest_scale}")
        positive("interpolate.max_log_step", self.max_log_step, allow_zero=False)
        if self.max_upsample < 1:
            raise ConfigError("interpolate.max_upsample", f"must be >= 1, got {self.max_upsample}")
        if self.log_eps is not None:
            positive("interpolate.log_eps", self.log_eps, allow_zero=False)
        if not 0.5 <= self.pixel_quantile <= 1.0:
            raise ConfigError("interpolate.pixel_quantile", f"must be in [0.5, 1], got {self.pixel_quantile}")
        check_bounds("interpolate", self, UPPER_BOUNDS, LOWER_BOUNDS)


@dataclass
class UpsampleStats:
    """Filled by :func:`upsample` when passed in: what the adaptive choice did and the log
    steps it achieved, measured on the produced frames (luminance, ``|delta log(Y + eps)|``
    between consecutive output frames).

    ``violations``: pairs whose frames still exceed the bound (the ``pixel_quantile``
    criterion; every pixel with ``fill_log``). ``max_log_step``: largest criterion of any
    pair. ``strict_max_log_step``: largest step of any pixel. ``pixel_steps`` /
    ``pixel_steps_over``: pixel-steps in total / above the bound. ``filled``: log-linear
    frames inserted by ``fill_log`` (included in ``inserted``). ``needed_upsample``: for
    the worst pair, a first-order estimate of the steps that would meet the criterion."""

    pairs: int = 0
    inserted: int = 0
    filled: int = 0
    refinements: int = 0
    violations: int = 0
    max_log_step: float = 0.0
    strict_max_log_step: float = 0.0
    pixel_steps: int = 0
    pixel_steps_over: int = 0
    needed_upsample: int = 0
    bound: float = 0.0
    per_pair: list = field(default_factory=list)   # inserted count per pair

    @property
    def over_bound_fraction(self) -> float:
        """Fraction of pixel-steps whose log step exceeds the bound."""
        return self.pixel_steps_over / self.pixel_steps if self.pixel_steps else 0.0

    def as_dict(self) -> dict:
        """JSON-able summary (for recording attrs or a stage summary)."""
        return {"upsample_pairs": self.pairs, "upsample_inserted": self.inserted,
                "upsample_filled": self.filled, "upsample_violations": self.violations,
                "log_step_bound": self.bound, "log_step_criterion_max": round(self.max_log_step, 6),
                "log_step_max": round(self.strict_max_log_step, 6),
                "log_step_over_fraction": float(f"{self.over_bound_fraction:.6g}"),
                "log_step_needed_upsample": self.needed_upsample}

    def merge(self, other: "UpsampleStats") -> None:
        """Add ``other`` (the stats of more pairs) into this one."""
        for k in ("pairs", "inserted", "filled", "refinements", "violations", "pixel_steps", "pixel_steps_over"):
            setattr(self, k, getattr(self, k) + getattr(other, k))
        for k in ("max_log_step", "strict_max_log_step", "needed_upsample", "bound"):
            setattr(self, k, max(getattr(self, k), getattr(other, k)))
        self.per_pair.extend(other.per_pair)

    def _record(self, d: np.ndarray, bound: float, crit: float, inserted: int, filled: int) -> None:
        if d.size:
            self._add(bound, crit, inserted, filled, d.size, float(d.max()), int(np.count_nonzero(d > bound)))
        else:
            self._add(bound, crit, inserted, filled, 0, None, 0)

    def _add(self, bound: float, crit: float, inserted: int, filled: int,
             n_steps: int, strict_max: float | None, n_over: int) -> None:
        """One pair: its criterion, counts and (pixel-steps, their max, how many over the bound)."""
        self.pairs += 1
        self.inserted += inserted
        self.filled += filled
        self.per_pair.append(inserted)
        self.bound = bound
        self.max_log_step = max(self.max_log_step, crit)
        if n_steps:
            self.strict_max_log_step = max(self.strict_max_log_step, strict_max)
            self.pixel_steps += n_steps
            self.pixel_steps_over += n_over
        if crit > bound:
            self.violations += 1
            self.needed_upsample = max(self.needed_upsample,
                                       math.ceil((inserted - filled + 1) * crit / bound))


# --- helpers ---------------------------------------------------------------------------

def luminance(images: np.ndarray) -> np.ndarray:
    """(..., H, W) float32 linear luminance of grey (..., H, W) or colour (..., H, W, 3) frames."""
    if images.ndim >= 3 and images.shape[-1] == 3:
        return (images @ _LUMA).astype(np.float32)
    return images.astype(np.float32, copy=False)


def _log_luminance(frames: np.ndarray, log_eps: float, *, color: bool) -> np.ndarray:
    """float32 ``log(Y + eps)`` of a frame (H, W[, 3]) or a chain (K, H, W[, 3])."""
    y = frames @ _LUMA if color else frames
    return np.log(y.astype(np.float32) + np.float32(log_eps))


def step_sizes(chain: np.ndarray, log_eps: float, *, color: bool) -> np.ndarray:
    """(K - 1, H, W) float32 ``|log(Y_{k+1} + eps) - log(Y_k + eps)|`` along a
    (K, H, W[, 3]) chain of frames (Y = luminance)."""
    return np.abs(np.diff(_log_luminance(chain, log_eps, color=color), axis=0))


def criterion(steps: np.ndarray, quantile: float = 1.0) -> float:
    """Per pixel the largest step over the chain, then the ``quantile`` of that over the
    pixels (1.0: the maximum)."""
    if steps.shape[0] == 0:
        return 0.0
    per_pixel = steps.max(axis=0) if steps.shape[0] > 1 else steps[0]
    if quantile >= 1.0:
        return float(per_pixel.max())
    return float(quantile_exact(per_pixel, quantile))


#: Stride of the pixel sample :func:`quantile_exact` guesses its threshold from.
_Q_SAMPLE_STRIDE = 16


def quantile_exact(values: np.ndarray, q: float) -> np.floating:
    """``np.quantile(values, q)`` (linear method), bit for bit, for a high ``q`` of many
    finite values, without partitioning all of them (np.quantile on 90k values: ~1 ms):
    a threshold guessed from a strided sample keeps the values that can hold the two order
    statistics the quantile interpolates (checked by counting; np.quantile when the guess
    fails, for NaN, or for few values), and those are interpolated by np.quantile itself
    on the pair, with the same fraction, so the rounding is numpy's."""
    v = np.ravel(values)
    n = v.size
    if n < 64 * _Q_SAMPLE_STRIDE or not 0.5 <= q < 1.0:
        return np.quantile(v, q)
    vi = (n - 1) * q
    k = int(math.floor(vi))
    gamma = float(np.asarray(vi) - np.floor(np.asarray(vi)))   # as numpy's _get_gamma (float64)
    sample = v[::_Q_SAMPLE_STRIDE]
    ns = sample.size
    # sample index well below the one of q: the kept set holds the top n - k values w.h.p.
    ks = max(0, int((ns - 1) * q) - 8 - 4 * int(math.sqrt(ns * (1 - q))))
    t = np.partition(sample, ks)[ks]
    if not np.isfinite(t):
        return np.quantile(v, q)
    top = v[v >= t]
    off = n - top.size   # values below t: all smaller than every kept one (unless NaN)
    if off > k or np.count_nonzero(v < t) != off or not np.isfinite(top).all():
        return np.quantile(v, q)
    j = k - off
    hi = min(j + 1, top.size - 1)
    part = np.partition(top, (j, hi))
    return np.quantile(np.array([part[j], part[hi]], v.dtype), gamma)


def log_steps(chain: np.ndarray, log_eps: float, *, color: bool, quantile: float = 1.0) -> float:
    """The log-step criterion along a (K, H, W[, 3]) chain of frames: per pixel the largest
    |log(Y_{k+1} + eps) - log(Y_k + eps)| over k, then the ``quantile`` of that over the
    pixels (1.0: the maximum)."""
    if chain.shape[0] < 2:
        return 0.0
    return criterion(step_sizes(chain, log_eps, color=color), quantile)


def _as_float(images: np.ndarray, name: str = "images") -> np.ndarray:
    im = np.asarray(images)
    if im.dtype == np.uint8:
        return im.astype(np.float32) / np.float32(255.0)
    if not np.issubdtype(im.dtype, np.floating):
        raise ValidationError(name, f"expected float32 linear intensity, got {im.dtype}")
    return im.astype(np.float32, copy=False)


def _flow_u8(y: np.ndarray) -> np.ndarray:
    """Luminance -> 8-bit gamma-encoded image for the flow estimator (gamma 1/2.2 spreads
    the dark tones the way the estimators' photometric constancy expects)."""
    return np.clip(np.power(np.clip(y, 0, 1), 1 / 2.2) * 255.0 + 0.5, 0, 255).astype(np.uint8)


_DIS_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
                "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
                "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


#: Smallest frame side the optical flow is used on: OpenCV's DIS raises an error below
#: 12 px and crashes (segmentation fault) on elongated frames up to 30 px high (e.g.
#: 30 x 346 with the fast preset); every preset ran on all sizes from 32 x 32 to
#: 64 x 2000 tried. Smaller frames are blended linearly (:func:`flow_fits`).
MIN_FLOW_SIDE = 32

_DIS_CACHE = threading.local()


def flow_fits(shape: tuple[int, ...]) -> bool:
    """Whether frames of ``shape`` ((H, W) or (H, W, 3)) are large enough for the flow."""
    return min(shape[0], shape[1]) >= MIN_FLOW_SIDE


#: Every parameter of a cv2.DISOpticalFlow (get/set pairs).
_DIS_PARAMS = ("FinestScale", "CoarsestScale", "PatchSize", "PatchStride", "GradientDescentIterations",
               "VariationalRefinementIterations", "VariationalRefinementAlpha", "VariationalRefinementDelta",
               "VariationalRefinementGamma", "VariationalRefinementEpsilon", "UseMeanNormalization",
               "UseSpatialPropagation")


def _dis(preset: str, finest_scale: int | None = None):
    """This thread's cv2.DISOpticalFlow of ``preset`` (and finest scale), created once and
    reset to its initial parameters before each use: creating one per call costs more than
    the flow itself (15.7 vs 6.6 ms at 346 x 260, medium). The reset matters: on small
    frames DIS rewrites its own patch size and scales inside ``calc``; with it, a reused
    instance gives the flows of a fresh one bit for bit (no initial flow is passed)."""
    cache = getattr(_DIS_CACHE, "by_preset", None)
    if cache is None:
        cache = _DIS_CACHE.by_preset = {}
    key = (preset, finest_scale)
    entry = cache.get(key)
    if entry is None:
        dis = cv2.DISOpticalFlow_create(_DIS_PRESETS[preset])
        if finest_scale is not None:
            dis.setFinestScale(int(finest_scale))
        entry = cache[key] = (dis, {k: getattr(dis, "get" + k)() for k in _DIS_PARAMS})
    else:
        dis, params = entry
        for k, v in params.items():
            getattr(dis, "set" + k)(v)
    return entry[0]


_FLOW_POOL: tuple[int, "object"] | None = None
_FLOW_POOL_LOCK = threading.Lock()


def _flow_pool():
    """Threads for the backward flow of a pair, computed while the calling thread computes
    the forward one (OpenCV's DIS runs on one core and releases the GIL: ~7 ms each at
    346 x 260, medium). Each worker has its own reused DIS instance (:func:`_dis`), so the
    flows are the same bit for bit. Made again in a forked child (the parent's threads do
    not exist there)."""
    global _FLOW_POOL
    import os
    from concurrent.futures import ThreadPoolExecutor
    with _FLOW_POOL_LOCK:
        if _FLOW_POOL is None or _FLOW_POOL[0] != os.getpid():
            workers = max(1, min(4, os.cpu_count() or 1))
            _FLOW_POOL = (os.getpid(), ThreadPoolExecutor(workers, thread_name_prefix="rdnet-flow"))
        return _FLOW_POOL[1]


def _flows_both_ways(u0: np.ndarray, u1: np.ndarray, cfg: InterpolateConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(flow u0 -> u1, flow u1 -> u0)`` of encoded frames, the second in a pool thread."""
    back = _flow_pool().submit(_flow_of_u8, u1, u0, cfg)
    try:
        f01 = _flow_of_u8(u0, u1, cfg)
    finally:
        f10 = back.result()
    return f01, f10


def optical_flow(a: np.ndarray, b: np.ndarray, cfg: InterpolateConfig) -> np.ndarray:
    """(H, W, 2) float32 flow from luminance ``a`` to ``b`` (a(x) ~ b(x + F(x))); the
    frames must have both sides >= :data:`MIN_FLOW_SIDE` (ValidationError otherwise)."""
    _check_flow_size(a.shape)
    return _flow_of_u8(_flow_u8(a), _flow_u8(b), cfg)


def _check_flow_size(shape: tuple[int, ...]) -> None:
    if not flow_fits(shape):
        raise ValidationError("images", f"{shape[1]} x {shape[0]} frames are too small for the optical "
                              f"flow (both sides must be >= {MIN_FLOW_SIDE} px); use method 'linear'")


def _flow_of_u8(ua: np.ndarray, ub: np.ndarray, cfg: InterpolateConfig) -> np.ndarray:
    """:func:`optical_flow` of frames already encoded by :func:`_flow_u8`."""
    if cfg.flow == "dis":
        return _dis(cfg.dis_preset, cfg.dis_finest_scale).calc(ua, ub, None)
    return cv2.calcOpticalFlowFarneback(ua, ub, None, pyr_scale=0.5, levels=4, winsize=15,
                                        iterations=3, poly_n=5, poly_sigma=1.2, flags=0)


def fit_to_size(cfg: InterpolateConfig, shape: tuple[int, ...], *, warn: bool = True) -> InterpolateConfig:
    """``cfg`` for frames of ``shape`` ((H, W[, 3])): method 'flow' or 'selected' becomes
    'linear' (with a warning) when the frames are smaller than the flow accepts (:func:`flow_fits`)."""
    if cfg.method not in FLOW_METHODS or flow_fits(shape):
        return cfg
    if warn:
        log.warning("%d x %d frames are too small for the optical flow (both sides must be >= %d px): "
                    "interpolating by linear blending instead", shape[1], shape[0], MIN_FLOW_SIDE)
    return dataclasses.replace(cfg, method="linear")


def _grid(h: int, w: int) -> np.ndarray:
    """(H, W, 2) float32 pixel coordinates (x, y): the sampling map of a zero flow."""
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return np.stack([gx, gy], axis=-1)


def _warp_map(grid: np.ndarray, flow: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The sampling map ``x + flow(x)`` of :func:`_remap`, (H, W, 2) float32, one
    contiguous add (the same float32 sums as adding each coordinate on its own), into
    ``out`` when given (it may be ``flow``); a frame and its occlusion mask warped by the
    same flow share it."""
    return np.add(flow, grid, out=out)


def _remap(img: np.ndarray, warp_map: np.ndarray, interpolation: int = cv2.INTER_LINEAR,
           clamp: bool = False, bounds: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Backward warp: out(x) = img(x + flow(x)) for ``warp_map`` = :func:`_warp_map` of
    the flow, borders replicated; bilinear unless ``interpolation`` (an OpenCV flag,
    :data:`WARPS`) says otherwise. ``clamp``: each sample clipped to the min / max of the
    2 x 2 source pixels around it (those a bilinear warp reads, borders replicated), so an
    interpolation kernel with negative lobes cannot overshoot an edge; ``bounds``:
    :func:`_block_bounds` of ``img`` when already computed (a pair's frames are warped once
    per inserted frame). OpenCV takes the map as one two-channel array: the same samples as
    separate x and y maps, bit for bit, without splitting the flow's channels."""
    out = cv2.remap(img, warp_map, None, interpolation, borderMode=cv2.BORDER_REPLICATE)
    if not clamp:
        return out
    mx, my = warp_map[..., 0], warp_map[..., 1]
    lo, hi = _block_bounds(img) if bounds is None else bounds
    # block (i, j) of the bounds covers source rows i - 1, i and columns j - 1, j: the
    # 2 x 2 pixels at floor(my), floor(my) + 1 and floor(mx), floor(mx) + 1 are block
    # (floor(my) + 1, floor(mx) + 1); beyond the border all four replicate the edge, as the
    # outermost block does, which the replicated border of the bounds' own lookup gives
    bx, by = np.floor(mx) + 1, np.floor(my) + 1
    lo = cv2.remap(lo, bx, by, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    hi = cv2.remap(hi, bx, by, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    return np.clip(out, lo, hi, out=out)


def _block_bounds(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)``, (H + 1, W + 1[, C]): the min and max of every 2 x 2 block of ``img``
    with its border replicated one pixel out, block (i, j) covering rows i - 1, i and
    columns j - 1, j (the clamp of :func:`_remap`)."""
    p = cv2.copyMakeBorder(img, 1, 1, 1, 1, cv2.BORDER_REPLICATE)
    if p.ndim < img.ndim:                   # OpenCV drops a trailing axis of length 1
        p = p.reshape(p.shape + img.shape[2:])
    a, b, c, d = p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]
    return np.minimum(np.minimum(a, b), np.minimum(c, d)), np.maximum(np.maximum(a, b), np.maximum(c, d))


def _occluded(f01: np.ndarray, f10: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Sundaram et al. 2010 forward-backward check: float32 mask of the pixels of the first
    frame whose forward flow is not undone by the backward flow (occluded / unreliable)."""
    back = _remap(f10, _warp_map(grid, f01))
    d = f01 + back
    lhs = _sq_norm(d)
    rhs = _FB_ALPHA1 * (_sq_norm(f01) + _sq_norm(back)) + _FB_ALPHA2
    return (lhs > rhs).astype(np.float32)


def _sq_norm(v: np.ndarray) -> np.ndarray:
    """``(v * v).sum(-1)`` of (H, W, 2) float32 vectors, written out: the same float32
    ``v0 v0 + v1 v1`` (a numpy reduction over a last axis of length 2 is ~15x slower)."""
    return v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1]


class PairInterpolator:
    """Intermediate frames between ``f0`` and ``f1`` (flows computed once, reused when the
    adaptive loop asks for another count)."""

    def __init__(self, f0: np.ndarray, f1: np.ndarray, cfg: InterpolateConfig,
                 flow_weight: np.ndarray | None = None, flows: "PairFlowCache | None" = None,
                 index: int = 0, *, before: np.ndarray | None = None, after: np.ndarray | None = None,
                 log_eps: float = 0.01):
        """``flow_weight`` (H, W) in [0, 1]: method 'selected' only, the weight of the flow
        frame against the spline's at each pixel (:func:`flow_weight`; None: 1 everywhere).
        ``flows``: the flows of pair ``index`` come from (or go to) this cache, shared with
        other interpolations of the same frames (:class:`PairFlowCache`). ``before``,
        ``after``: methods 'cubic' and 'selected', the frames before ``f0`` and after ``f1`` (None at
        the ends of a sequence: the log intensity extrapolated linearly from the pair);
        ``log_eps``: its log's offset (``cfg.log_eps`` when set)."""
        self.f0 = _as_float(f0, "f0")
        self.f1 = _as_float(f1, "f1")
        if self.f0.shape != self.f1.shape:
            raise ValidationError("f1", f"shape {self.f1.shape} != f0 shape {self.f0.shape}")
        self.cfg = cfg
        self.color = self.f0.ndim == 3
        self._flows = None
        self._bounds = None                     # the clamp's per-pair block bounds (_clamp_bounds)
        w = None
        if cfg.method == "selected" and flow_weight is not None:
            w = np.asarray(flow_weight, np.float32)
            if w.shape != self.f0.shape[:2]:
                raise ValidationError("flow_weight", f"shape {w.shape} != frame shape {self.f0.shape[:2]}")
            w = w[..., None] if self.color else w
        # the arrays ``frame`` blends (swapped for their sampled views by ``on_grid``)
        self._blend = (self.f0, self.f1, w)
        self._logs = None
        if cfg.method in SPLINE_METHODS:
            e = np.float32(cfg.log_eps if cfg.log_eps is not None else log_eps)
            for name, f in (("before", before), ("after", after)):
                if f is not None and np.shape(f) != self.f0.shape:
                    raise ValidationError(name, f"shape {np.shape(f)} != f0 shape {self.f0.shape}")
            self._eps = e
            l1, l2 = np.log(self.f0 + e), np.log(self.f1 + e)
            # a missing end knot is extrapolated linearly (2 l1 - l2), so the spline is exact on
            # a log-linear ramp at the ends of a sequence too
            l0 = 2 * l1 - l2 if before is None else np.log(_as_float(before, "before") + e)
            l3 = 2 * l2 - l1 if after is None else np.log(_as_float(after, "after") + e)
            self._logs = (l0, l1, l2, l3)
        self._grid = 1                          # the stride of ``on_grid`` while inside it
        self._per_grid: dict = {}               # :meth:`_terms`
        self._shared = None
        if flows is not None:
            flows.share(index, self)
            if self.uses_flow:
                self._shared = (flows, int(index), next(_TOKENS))

    @property
    def uses_flow(self) -> bool:
        return self.cfg.method in FLOW_METHODS

    @contextlib.contextmanager
    def on_grid(self, s: int):
        """Inside, :meth:`frame` gives every ``s``-th row and column of the full frame, each
        output pixel computed exactly as at full resolution: the flows, sampling grid and
        blend inputs are swapped for their sampled versions while the warped source images
        and occlusion masks stay whole (``cv2.remap`` evaluates each output pixel from its own
        map entry)."""
        blend, logs = self._blend, self._logs
        full = self._prepare() if self.uses_flow else None
        f0, f1, w = blend
        self._blend = (f0[::s, ::s], f1[::s, ::s], None if w is None else w[::s, ::s])
        if logs is not None:
            self._logs = tuple(lg[::s, ::s] for lg in logs)
        self._grid = int(s)
        if full is not None:
            f01, f10, o0, o1, grid = full
            self._flows = (np.ascontiguousarray(f01[::s, ::s]), np.ascontiguousarray(f10[::s, ::s]), o0, o1,
                           np.ascontiguousarray(grid[::s, ::s]))
        try:
            yield self
        finally:
            self._blend, self._logs = blend, logs
            self._grid = 1
            if full is not None:
                self._flows = full

    def _prepare(self):
        if self._flows is None:
            y0, y1 = luminance(self.f0), luminance(self.f1)
            _check_flow_size(y0.shape)
            u0, u1 = _flow_u8(y0), _flow_u8(y1)   # encoded once for both directions
            f01, f10 = _flows_both_ways(u0, u1, self.cfg)   # in parallel
            grid = _grid(*y0.shape)
            if self.cfg.occlusion:
                o0, o1 = _occluded(f01, f10, grid), _occluded(f10, f01, grid)
            else:
                o0 = o1 = None
            self._flows = (f01, f10, o0, o1, grid)
        return self._flows

    def motion_estimate(self, log_eps: float, quantile: float = 1.0) -> float:
        """First-order estimate of the log-luminance change over the interval, per pixel
        max(|L1 - L0|, |grad L0| |F01|) (flow) or |L1 - L0| (linear); its ``quantile``
        over the pixels."""
        l0 = np.log(luminance(self.f0) + np.float32(log_eps))
        l1 = np.log(luminance(self.f1) + np.float32(log_eps))
        est = np.abs(l1 - l0)
        if self.uses_flow:
            f01 = self._prepare()[0]
            gx = cv2.Sobel(l0, cv2.CV_32F, 1, 0, ksize=3) / 8.0
            gy = cv2.Sobel(l0, cv2.CV_32F, 0, 1, ksize=3) / 8.0
            est = np.maximum(est, np.hypot(gx, gy) * np.hypot(f01[..., 0], f01[..., 1]))
        return float(est.max() if quantile >= 1.0 else quantile_exact(est, quantile))

    def frame(self, t: float) -> np.ndarray:
        """The frame at fraction ``t`` in (0, 1) of the interval."""
        weight = self._blend[2]
        t = np.float32(t)
        if not self.uses_flow:
            if self._logs is not None:
                return self.cubic(t)
            return self.crossfade(t)
        if self._shared is None:
            out = self._warped(t)
        else:
            flows, index, token = self._shared
            out = flows.warped(index, self, t, token)
        if weight is None:
            return out
        still = self.crossfade(t) if self._logs is None else self.cubic(t)
        still *= self._terms("still_weight", lambda: (1 - weight,))[0]
        res = np.multiply(weight, out)              # ``out`` may be shared with another interpolator
        res += still                                # weight out + (1 - weight) still
        return res

    def _terms(self, name: str, make) -> tuple:
        """``make()``'s arrays, computed once per grid of :meth:`on_grid` (the blend inputs
        and log frames it swaps in are the key) for the parts of the per-frame arithmetic
        that do not depend on ``t``."""
        key, src = (name, self._grid), (self._blend, self._logs)
        entry = self._per_grid.get(key)
        if entry is None or entry[0][0] is not src[0] or entry[0][1] is not src[1]:
            entry = self._per_grid[key] = (src, make())
        return entry[1]

    def crossfade(self, t: float) -> np.ndarray:
        """The linear blend ``(1 - t) f0 + t f1`` (method 'linear'), on the grid of
        :meth:`on_grid` when inside it."""
        b0, b1 = self._blend[:2]
        t = np.float32(t)
        return (1 - t) * b0 + t * b1

    def cubic(self, t: float) -> np.ndarray:
        """Method 'cubic': the Catmull-Rom spline of ``log(I + eps)`` through the four
        frames at ``t`` (``f0`` at 0, ``f1`` at 1; uniform knots), back to linear intensity
        (>= 0), on the grid of :meth:`on_grid` when inside it."""
        def coefficients():
            p0, p1, p2, p3 = self._logs
            return (np.ascontiguousarray(p1), p2 - p0, 2 * p0 - 5 * p1 + 4 * p2 - p3, 3 * (p1 - p2) + p3 - p0)
        # v = p1 + 0.5 t ((p2 - p0) + t ((2 p0 - 5 p1 + 4 p2 - p3) + t (3 (p1 - p2) + p3 - p0))),
        # the same float32 operations in place, with the terms free of t computed once per grid
        p1, c1, c2, c3 = self._terms("cubic", coefficients)
        t = np.float32(t)
        v = np.multiply(c3, t)
        v += c2
        v *= t
        v += c1
        v *= np.float32(0.5) * t
        v += p1
        np.exp(v, out=v)
        v -= self._eps
        return np.maximum(v, 0, out=v)

    def _clamp_bounds(self):
        """:func:`_block_bounds` of both frames, computed once per pair (``bicubic_clamped``)."""
        if self._bounds is None:
            self._bounds = (_block_bounds(self.f0), _block_bounds(self.f1))
        return self._bounds

    def _warped(self, t: np.float32) -> np.ndarray:
        """The flow frame at ``t`` (module docstring). The arithmetic runs in place where it
        can, each operation the same float32 one as the plain expressions in the comments."""
        f0, f1 = self.f0, self.f1
        f01, f10, o0, o1, grid = self._prepare()
        # Super SloMo Eq. 4: ft0 = -(1 - t) t F01 + t^2 F10, ft1 = (1 - t)^2 F01 - t (1 - t) F10
        tmp = np.empty_like(f01)
        ft0 = np.multiply(f01, -(1 - t) * t)
        ft0 += np.multiply(f10, t * t, out=tmp)
        ft1 = np.multiply(f01, (1 - t) * (1 - t))
        ft1 -= np.multiply(f10, t * (1 - t), out=tmp)
        m0, m1 = _warp_map(grid, ft0, out=ft0), _warp_map(grid, ft1, out=ft1)
        warp, clamp = WARPS[self.cfg.warp]
        b0, b1 = self._clamp_bounds() if clamp else (None, None)
        g0 = _remap(f0, m0, warp, clamp, b0)
        g1 = _remap(f1, m1, warp, clamp, b1)
        if o0 is not None:
            # content of frame 0 that becomes occluded is invisible in g1 and vice versa;
            # the occlusion happens at an unknown time, uniform in the interval, so the
            # expected visibility of g0 is 1 - t o1 and that of g1 is 1 - (1 - t) o0: the
            # frame stays continuous at both ends (a hard mask would swap sources at t = 0+)
            w1 = _remap(o0, m0)                   # w1 = t (1 - (1 - t) o0(m0)) + 1e-4 t
            w1 *= 1 - t
            np.subtract(1, w1, out=w1)
            w1 *= t
            w1 += 1e-4 * t
            w0 = _remap(o1, m1)                   # w0 = (1 - t) (1 - t o1(m1)) + 1e-4 (1 - t)
            w0 *= t
            np.subtract(1, w0, out=w0)
            w0 *= 1 - t
            w0 += 1e-4 * (1 - t)
        else:
            w0 = np.full(grid.shape[:2], 1 - t, np.float32)
            w1 = np.full(grid.shape[:2], t, np.float32)
        s = w0 + w1
        w0 /= s
        w1 /= s
        if self.color:
            w0, w1 = w0[..., None], w1[..., None]
        out = np.multiply(w0, g0, out=g0)                            # w0 g0 + w1 g1
        out += w1 * g1
        return np.maximum(out, 0, out=out)

    def frames(self, n_inserted: int) -> np.ndarray:
        """(n_inserted, H, W[, 3]) frames at t = k / (n_inserted + 1), k = 1..n_inserted."""
        out = np.empty((n_inserted,) + self.f0.shape, np.float32)
        for k in range(n_inserted):
            out[k] = self.frame((k + 1) / (n_inserted + 1))
        return out


#: distinct ids of the interpolators that take frames from a :class:`PairFlowCache`
_TOKENS = itertools.count()


class PairFlowCache:
    """The flows of each frame pair, computed once for several interpolations of the same
    frames (methods 'flow' and 'selected' warp with the same pair flows), also when they are
    built at the same time in threads (the second waits for the first). Only for one frame
    sequence: a pair is known by its index and the flow settings. ``users``: how many
    interpolations will ask for each pair; a pair's flows are dropped once all have them,
    so the cache holds only the pairs in progress.

    The flow frames are shared the same way (:meth:`warped`): 'selected' blends the very
    frame 'flow' uses (``PairInterpolator._warped``) with the cross-fade, so a frame at a
    time both ask for is warped once. A frame is dropped once ``users`` interpolators have
    taken it; one that only one of them asks for (their adaptive counts differ at that pair)
    stays until the cache goes, at most a few frames per pair."""

    def __init__(self, users: int):
        self._lock = threading.Lock()
        self._pending: dict = {}             # key -> [Future of the flows, users still to come]
        self._frames: dict = {}              # key -> [Future of the frame, tokens that took it]
        self.users = int(users)

    @staticmethod
    def _key(index: int, pi: "PairInterpolator") -> tuple:
        c = pi.cfg
        return (int(index), pi.f0.shape, c.flow, c.dis_preset, c.dis_finest_scale, c.occlusion)

    def share(self, index: int, pi: "PairInterpolator") -> None:
        """Give ``pi`` (pair ``index``) the flows of that pair, computing them on first use."""
        if not pi.uses_flow:
            return
        key = self._key(index, pi)
        with self._lock:
            owner = key not in self._pending
            if owner:
                self._pending[key] = [Future(), self.users]
            entry = self._pending[key]
            fut = entry[0]
            entry[1] -= 1
            if entry[1] <= 0:                   # the last user: nothing keeps it after this
                del self._pending[key]
        if owner:
            try:
                fut.set_result(pi._prepare())
            except BaseException as e:
                fut.set_exception(e)
                raise
        pi._flows = fut.result()

    def warped(self, index: int, pi: "PairInterpolator", t: np.float32, token: int) -> np.ndarray:
        """``pi._warped(t)`` of pair ``index`` on ``pi``'s current grid, computed by the first
        interpolator that asks (the others wait for it); read-only. ``token``: the asking
        interpolator's id (one that asks twice is not counted twice)."""
        key = self._key(index, pi) + (pi.cfg.warp, pi._grid, float(t))
        with self._lock:
            entry = self._frames.get(key)
            owner = entry is None
            if owner:
                entry = self._frames[key] = [Future(), set()]
            entry[1].add(token)
            if len(entry[1]) >= self.users:
                del self._frames[key]
        fut = entry[0]
        if owner:
            try:
                out = pi._warped(t)
                out.flags.writeable = False
                fut.set_result(out)
            except BaseException as e:
                fut.set_exception(e)
                raise
        return fut.result()


def select_centres(n: int, select_frames: int) -> np.ndarray:
    """The inner frames (indices 1..n-2) that :func:`flow_weight` predicts: all of them when
    ``select_frames`` is 0 or at least their number, else ``select_frames`` evenly spaced
    from the first to the last (both included)."""
    if n < 3:
        return np.zeros(0, np.int64)
    if select_frames <= 0 or select_frames >= n - 2:
        return np.arange(1, n - 1, dtype=np.int64)
    return np.unique(np.rint(np.linspace(1, n - 2, select_frames)).astype(np.int64))


def flow_weight(images: np.ndarray, t_us: np.ndarray, cfg: InterpolateConfig, log_eps: float = 0.01
                ) -> np.ndarray:
    """The per-pixel weight of the flow frame of method 'selected' (module docstring), (H, W)
    float32 in [0, 1]: every inner frame ``i`` of ``images`` ((N, H, W[, 3]) linear), or
    ``cfg.select_frames`` of them evenly spaced (:func:`select_centres`), is
    predicted at its own time from frames ``i - 1`` and ``i + 1`` by flow and by the spline
    of method 'cubic' (through frames ``i - 3, i - 1, i + 1, i + 3``); ``E_m`` = the squared
    error of ``log(Y + eps)`` (luminance) summed over the frames; weight 1 where
    ``G * E_flow < G * E_spline`` (``G``: a Gaussian of sigma
    ``cfg.select_sigma_px``), else 0, then blurred by a Gaussian of half that sigma. With
    fewer than 3 frames: 1 everywhere. The predictions span two intervals, so they test
    each method on twice the motion it will interpolate; the choice is made once per
    sequence, from its own frames (``log_eps``: the sensor's unless ``cfg.log_eps``)."""
    images = np.asarray(images)
    n, shape = images.shape[0], images.shape[1:3]
    if n < 3:
        return np.ones(shape, np.float32)
    eps = np.float32(cfg.log_eps if cfg.log_eps is not None else log_eps)
    t = np.asarray(t_us, np.int64)
    flow = dataclasses.replace(cfg, method="flow")
    err_flow = np.zeros(shape, np.float64)
    err_spline = np.zeros(shape, np.float64)
    spline = dataclasses.replace(cfg, method="cubic")
    for i in select_centres(n, cfg.select_frames):
        pi = PairInterpolator(images[i - 1], images[i + 1], flow)
        sp = PairInterpolator(images[i - 1], images[i + 1], spline, before=images[i - 3] if i >= 3 else None,
                              after=images[i + 3] if i + 3 < n else None, log_eps=float(eps))
        s = (t[i] - t[i - 1]) / (t[i + 1] - t[i - 1])
        truth = np.log(luminance(_as_float(images[i])) + eps)
        err_flow += np.square(np.log(luminance(pi.frame(s)) + eps) - truth)
        err_spline += np.square(np.log(luminance(sp.frame(s)) + eps) - truth)
    sigma = float(cfg.select_sigma_px)
    pooled_flow = cv2.GaussianBlur(err_flow.astype(np.float32), (0, 0), sigma)
    pooled_spline = cv2.GaussianBlur(err_spline.astype(np.float32), (0, 0), sigma)
    chosen = (pooled_flow < pooled_spline).astype(np.float32)
    return np.clip(cv2.GaussianBlur(chosen, (0, 0), sigma / 2), 0.0, 1.0)


def pair_interpolator(images: np.ndarray, i: int, f0: np.ndarray, f1: np.ndarray, cfg: InterpolateConfig,
                      weight: np.ndarray | None, flows: "PairFlowCache | None", log_eps: float) -> PairInterpolator:
    """The :class:`PairInterpolator` of frames ``i`` and ``i + 1`` of ``images`` (``f0``,
    ``f1``: those frames as float32), with the neighbouring frames when ``cfg.method`` is
    'cubic' or 'selected' (none at the ends of the sequence: extrapolated)."""
    before = after = None
    if cfg.method in SPLINE_METHODS:
        n = images.shape[0]
        before = images[i - 1] if i > 0 else None
        after = images[i + 2] if i + 2 < n else None
    return PairInterpolator(f0, f1, cfg, weight, flows, i, before=before, after=after, log_eps=log_eps)


def interpolate_pair(f0: np.ndarray, f1: np.ndarray, n_inserted: int,
                     cfg: InterpolateConfig = InterpolateConfig()) -> np.ndarray:
    """``n_inserted`` frames evenly spaced strictly between ``f0`` and ``f1``."""
    if n_inserted < 0:
        raise ValidationError("n_inserted", f"must be >= 0, got {n_inserted}")
    return PairInterpolator(f0, f1, cfg).frames(int(n_inserted))


def _adaptive(pi: PairInterpolator, cap: int, log_eps: float, cfg: InterpolateConfig,
              stats: list[UpsampleStats]) -> tuple[np.ndarray, np.ndarray | None, float | None]:
    """Inserted frames for one pair, count chosen so the measured criterion <= bound (at
    most ``cap``), the step sizes of the final chain and their criterion (None when not
    measured)."""
    bound = cfg.max_log_step
    if cap <= 0:
        return np.empty((0,) + pi.f0.shape, np.float32), None, None
    n = min(cap, max(0, math.ceil(pi.motion_estimate(log_eps, cfg.pixel_quantile) / bound) - 1))
    while True:
        mid = pi.frames(n)
        if not cfg.verify:
            return mid, None, None
        chain = np.concatenate([pi.f0[None], mid, pi.f1[None]])
        steps = step_sizes(chain, log_eps, color=pi.color)
        m = criterion(steps, cfg.pixel_quantile)
        if m <= bound or n >= cap:
            return mid, steps, m
        k = n + 1
        # steps scale ~linearly with the measured step; grow by at least 1.5x
        new_steps = max(math.ceil(k * m / bound * 1.05), math.ceil(k * 1.5), k + 1)
        n = min(cap, new_steps - 1)
        for st in stats:
            st.refinements += 1


#: Fill target relative to the bound (absorbs float32 rounding of the filled frames).
_FILL_MARGIN = 1e-3


def fill_log(chain: np.ndarray, t_us: np.ndarray, log_eps: float, bound: float
             ) -> tuple[np.ndarray, np.ndarray, int]:
    """Final guarantee of the bound: between consecutive frames a, b of ``chain`` (K, H, W[, 3])
    at times ``t_us`` whose largest ``|log(I_b + eps) - log(I_a + eps)|`` (any pixel, any
    channel) exceeds ``bound``, insert k frames at integer times ``t_j`` with
    ``log(I_j + eps) = (1 - s_j) log(I_a + eps) + s_j log(I_b + eps)``,
    ``s_j = (t_j - t_a) / (t_b - t_a)``: log-linear in time, as the event simulator assumes
    between frames. k is the least count whose longest sub-interval keeps the step under
    the bound (at most t_b - t_a - 1). Per channel, the luminance step is a weighted mean
    of the channel steps, so it is bounded too. Returns (chain, t_us, frames inserted)."""
    eps = np.float32(log_eps)
    lg = np.log(chain.astype(np.float32) + eps)
    d = np.abs(np.diff(lg, axis=0))
    worst = d.reshape(d.shape[0], -1).max(axis=1) if d.size else np.zeros(0, np.float32)
    target = bound * (1.0 - _FILL_MARGIN)
    frames, times, added = [chain[:1]], [t_us[:1]], 0
    for j, m in enumerate(worst.astype(np.float64)):
        ta, tb = int(t_us[j]), int(t_us[j + 1])
        span = tb - ta
        k = max(0, math.ceil(m / target) - 1)
        k = min(k, span - 1)
        while k < span - 1 and m * math.ceil(span / (k + 1)) / span > target:
            k += 1
        if k > 0:
            tj = ta + np.rint(np.arange(1, k + 1) * (span / (k + 1))).astype(np.int64)
            sj = ((tj - ta) / span).astype(np.float32).reshape((k,) + (1,) * (chain.ndim - 1))
            mid = np.exp((1 - sj) * lg[j] + sj * lg[j + 1]) - eps
            frames.append(np.maximum(mid, 0).astype(np.float32))
            times.append(tj)
            added += k
        frames.append(chain[j + 1:j + 2])
        times.append(t_us[j + 1:j + 2])
    if not added:
        return chain, t_us, 0
    return np.concatenate(frames), np.concatenate(times), added


def upsample(images: np.ndarray, t_us: np.ndarray, cfg: InterpolateConfig = InterpolateConfig(),
             log_eps: float = 0.01, *, stats: UpsampleStats | None = None, warn: bool = True,
             with_log: bool = False, flows: PairFlowCache | None = None) -> Iterator[tuple]:
    """Stream the adaptively upsampled sequence pair by pair.

    ``images``: (N, H, W) or (N, H, W, 3) float32 linear; ``t_us``: (N,) int64 strictly
    increasing. Yields ``(images_chunk, t_chunk)``: chunk i holds input frame i and the
    frames inserted before frame i + 1; the last chunk also ends with frame N - 1, so the
    concatenation of all chunks is the whole upsampled sequence (memory: one pair at a time).
    Inserted timestamps are ``t_i + round(k (t_{i+1} - t_i) / (n + 1))`` (integer us, kept
    strictly increasing by capping n at t_{i+1} - t_i - 1); ``fill_log`` frames go between
    them. ``cfg.log_eps`` overrides ``log_eps`` (the sensor's) when set. Pass an
    :class:`UpsampleStats` to collect counts and the achieved log steps; a warning is
    logged when the bound is not met (``warn``; :func:`warn_if_over` for callers that
    stream many calls). ``with_log``: yield ``(images_chunk, t_chunk, log_chunk)`` where
    ``log_chunk`` is ``log(images_chunk + eps)`` (float32, what the sensor computes from
    the frames) when it was computed anyway for the statistics (grey frames, nothing
    inserted), else None. ``flows``: pair flows shared with other interpolations of the same
    frames (:class:`PairFlowCache`).
    """
    images = np.asarray(images)
    t_us = np.asarray(t_us)
    if images.ndim not in (3, 4) or (images.ndim == 4 and images.shape[3] != 3):
        raise ValidationError("images", f"expected (N,H,W) or (N,H,W,3), got shape {images.shape}")
    if not np.issubdtype(t_us.dtype, np.integer):
        raise ValidationError("t_us", f"timestamps must be integer microseconds, got {t_us.dtype}")
    t_us = t_us.astype(np.int64)
    n = images.shape[0]
    if t_us.shape != (n,):
        raise ValidationError("t_us", f"expected {n} timestamps, got shape {t_us.shape}")
    if n == 0:
        raise ValidationError("images", "no frames")
    if n > 1 and np.any(np.diff(t_us) <= 0):
        raise ValidationError("t_us", "timestamps must be strictly increasing")
    cfg = fit_to_size(cfg, images.shape[1:], warn=warn)
    eps = float(cfg.log_eps if cfg.log_eps is not None else log_eps)
    bound = cfg.max_log_step
    here = UpsampleStats()
    sts = [here] if stats is None else [here, stats]
    if n == 1:
        one = (_as_float(images[:1]), t_us[:1].copy())
        yield one + (None,) if with_log else one
        return
    color = images.ndim == 4
    quantile = 1.0 if cfg.fill_log else cfg.pixel_quantile
    if not cfg.fill_log and (cfg.method == "none" or cfg.max_upsample <= 1):
        # nothing can be inserted: the frames as given, in one chunk; the steps (for the
        # stats and the warning only) measured on the whole sequence at once
        ims, ts, lg = _unchanged(images, t_us, eps, bound, quantile, color, sts, keep_log=with_log)
        yield (ims, ts, lg) if with_log else (ims, ts)
        if warn:
            warn_if_over(here, cfg)
        return
    weight = flow_weight(images, t_us, cfg, eps) if cfg.method == "selected" else None
    next_f0 = prev_log = None
    for i in range(n - 1):
        f0 = _as_float(images[i]) if next_f0 is None else next_f0
        f1 = next_f0 = _as_float(images[i + 1])
        dt = int(t_us[i + 1] - t_us[i])
        cap = min(cfg.max_upsample - 1, dt - 1)
        if cfg.method == "none" or cap <= 0:
            mid, steps, crit = np.empty((0,) + f0.shape, np.float32), None, None
        else:
            mid, steps, crit = _adaptive(pair_interpolator(images, i, f0, f1, cfg, weight, flows, eps), cap, eps,
                                         cfg, sts)
        k = mid.shape[0]
        t_mid = t_us[i] + np.rint(np.arange(1, k + 1) * (dt / (k + 1))).astype(np.int64)
        chain = np.concatenate([f0[None], mid, f1[None]])
        times = np.concatenate([t_us[i:i + 1], t_mid, t_us[i + 1:i + 2]])
        filled = 0
        if cfg.fill_log:
            chain, times, filled = fill_log(chain, times, eps, bound)
            if filled:
                steps = None
        log1 = None
        if steps is None:
            crit = None
            if chain.shape[0] == 2:   # nothing inserted: the step of the pair, f0's log kept from the last pair
                log1 = _log_luminance(f1, eps, color=color)
                log0 = prev_log if prev_log is not None else _log_luminance(f0, eps, color=color)
                steps = np.abs(log1 - log0)[None]
            else:
                steps = step_sizes(chain, eps, color=color)
        prev_log = log1
        if crit is None or cfg.fill_log:
            crit = criterion(steps, quantile)
        for st in sts:
            st._record(steps, bound, crit, chain.shape[0] - 2, filled)
        last = i == n - 2
        out = (chain if last else chain[:-1]), (times if last else times[:-1])
        yield out + (None,) if with_log else out
    if warn:
        warn_if_over(here, cfg)


def _unchanged(images: np.ndarray, t_us: np.ndarray, eps: float, bound: float, quantile: float,
               color: bool, sts: list[UpsampleStats], block: int = 4, keep_log: bool = False
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`upsample` when nothing can be inserted: ``(frames as float32, t_us, log)``,
    every pair recorded in ``sts`` as the pair-by-pair loop records it (the same steps and
    criterion), the steps computed ``block`` pairs at a time in place (cache-sized: about
    half the time of whole-chunk temporaries). ``log``: with ``keep_log`` and grey frames,
    ``log(frames + eps)`` of every frame (float32, computed once for the steps), else None."""
    ims = _as_float(images)
    e = np.float32(eps)
    kept = np.empty_like(ims) if keep_log and not color else None

    def logs(a: int, b: int) -> np.ndarray:
        if color:
            return np.stack([_log_luminance(f, eps, color=True) for f in ims[a:b]])
        out = np.empty_like(ims[a:b]) if kept is None else kept[a:b]
        np.add(ims[a:b], e, out=out)
        return np.log(out, out=out)

    prev = logs(0, 1)
    for s in range(0, ims.shape[0] - 1, block):
        lg = logs(s + 1, s + 1 + block)
        d = np.empty_like(lg)
        np.subtract(lg[:1], prev, out=d[:1])
        np.subtract(lg[1:], lg[:-1], out=d[1:])
        np.abs(d, out=d)
        prev = lg[-1:]
        flat = d.reshape(d.shape[0], -1)
        strict = flat.max(axis=1)
        crits = strict if quantile >= 1.0 else [quantile_exact(r, quantile) for r in flat]
        over = np.count_nonzero(flat > bound, axis=1)
        for st in sts:
            for c, m, o in zip(crits, strict, over):
                st._add(bound, float(c), 0, 0, flat.shape[1], float(m), int(o))
    return ims, t_us.copy(), kept


def warn_if_over(stats: UpsampleStats, cfg: InterpolateConfig) -> None:
    """Log a warning with the achieved numbers when pairs of ``stats`` exceed the bound."""
    if not stats.violations:
        return
    log.warning("log-step bound %.3g exceeded in %d of %d frame pairs at max_upsample=%d%s: "
                "criterion up to %.3g (pixel_quantile %g), %.3g%% of pixel-steps over the bound, "
                "largest step %.3g; about %d steps per pair would meet it (or set fill_log)",
                cfg.max_log_step, stats.violations, stats.pairs, cfg.max_upsample,
                " with fill_log (timestamps too close)" if cfg.fill_log else "",
                stats.max_log_step, 1.0 if cfg.fill_log else cfg.pixel_quantile,
                100 * stats.over_bound_fraction, stats.strict_max_log_step, stats.needed_upsample)


def upsample_all(images: np.ndarray, t_us: np.ndarray, cfg: InterpolateConfig = InterpolateConfig(),
                 log_eps: float = 0.01, *, stats: UpsampleStats | None = None, warn: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`upsample` concatenated: ``(images (M, ...), t_us (M,))``."""
    ims, ts = zip(*upsample(images, t_us, cfg, log_eps, stats=stats, warn=warn))
    return np.concatenate(ims), np.concatenate(ts)
