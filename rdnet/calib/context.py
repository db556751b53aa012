"""What the calibration knows about a recording before simulating anything: the common
time window of frames and events, its fit/held-out segments, the pixel sample, the
static mask and the log-intensity bins every statistic refers to."""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from rdnet.calib.settings import CalibrateConfig
from rdnet.errors import FormatError
from rdnet.events.core import Events
from rdnet.events.recording import Recording

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CalibContext:
    """Frames, real events and the bookkeeping shared by all statistics.

    Everything is on the *sampled* pixel grid (every ``stride``-th row and column of the
    sensor): ``width``/``height`` are the sampled sizes. ``images`` (N, h, w) float32
    linear, ``log_frames`` = log(images + log_eps), ``frame_t`` (N,) int64 us.
    ``t0``/``t1``: the compared window [t0, t1) (frames and events overlap there).
    ``segments`` (S, 2) int64 [start, end); ``fit`` / ``held`` segment indices.
    ``static`` (h, w) bool; ``intensity_edges`` (B+1,) log-intensity bin edges;
    ``frame_bin`` (N, h, w) int8 log-intensity bin of each pixel in each frame;
    ``sim_images`` (M, h, w) / ``sim_t`` (M,): the frames upsampled between the recorded
    ones (what the simulator is fed); ``occupancy`` (S, B) pixel-seconds spent in each bin during each segment;
    ``time_edges`` (K+1,) rate-over-time bin edges; ``time_seg`` (K,) segment of each bin.
    """

    width: int
    height: int
    stride: int
    images: np.ndarray
    log_frames: np.ndarray
    frame_t: np.ndarray
    sim_images: np.ndarray
    sim_t: np.ndarray
    real: Events
    t0: int
    t1: int
    segments: np.ndarray
    fit: tuple
    held: tuple
    static: np.ndarray
    intensity_edges: np.ndarray
    frame_bin: np.ndarray
    occupancy: np.ndarray
    time_edges: np.ndarray
    time_seg: np.ndarray
    cfg: CalibrateConfig
    log_eps: float
    source: str = "recording"
    _cache: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

    @property
    def frame_bin_flat(self) -> np.ndarray:
        """(N, P) view of ``frame_bin``."""
        return self.frame_bin.reshape(len(self.frame_t), -1)

    @property
    def frame_bin_by_pixel(self) -> np.ndarray:
        """(P, N) C-contiguous copy of ``frame_bin`` (a pixel's bins adjacent in memory),
        made once."""
        fb = self._cache.get("frame_bin_by_pixel")
        if fb is None:
            fb = self._cache["frame_bin_by_pixel"] = np.ascontiguousarray(self.frame_bin_flat.T)
        return fb

    def segment_seconds(self, segs) -> float:
        s = self.segments[list(segs)]
        return float((s[:, 1] - s[:, 0]).sum()) * 1e-6


def subsample_events(ev: Events, stride: int) -> Events:
    """Events of every ``stride``-th row/column, on the sampled grid (x // stride)."""
    if stride == 1:
        return ev
    a = ev.array
    keep = (a["x"] % stride == 0) & (a["y"] % stride == 0)
    out = a[keep].copy()
    out["x"] //= stride
    out["y"] //= stride
    w = (ev.width + stride - 1) // stride
    h = (ev.height + stride - 1) // stride
    return Events(out, w, h, validate=False)


def build_context(rec: Recording, cfg: CalibrateConfig, log_eps: float, *,
                  interpolate=None, stride: int | None = None,
                  source: str = "recording", flows=None) -> CalibContext:
    """Check the recording (frames and events present and overlapping in time), upsample
    its frames (:func:`upsample_sampled`: flow at full resolution, warps only at the
    sampled pixels; ``interpolate``: an ``InterpolateConfig``, None = the default,
    flow-based), sample the pixels and precompute the segment, static-mask and
    intensity-bin bookkeeping.

    The pixel stride is ``stride`` or ``cfg.pixel_stride``, raised until the upsampled
    frames have at most ``cfg.max_sim_steps`` pixel-frames (0 = no limit). ``flows``: a
    :class:`rdnet.sim.interpolate.PairFlowCache` shared by the contexts of one recording."""
    frames = rec.require_frames(source)
    events = rec.require_events(source)
    if len(frames) < 2:
        raise FormatError(source, "frames", f"need at least 2 frames to simulate events, got {len(frames)}")
    ft = frames.t_us.astype(np.int64)
    t0 = max(int(ft[0]), int(events.t[0]))
    t1 = min(int(ft[-1]), int(events.t[-1]) + 1)
    min_span = cfg.segments * 1000
    if t1 - t0 < min_span:
        raise FormatError(source, "events", (
            f"frames ({int(ft[0])}..{int(ft[-1])} us) and events ({int(events.t[0])}..{int(events.t[-1])} us) "
            f"overlap for {max(t1 - t0, 0)} us; need at least {min_span} us ({cfg.segments} segments of 1 ms)"))
    s = int(stride or cfg.pixel_stride)
    grey_full = frames.grey()
    if cfg.max_sim_steps:
        # the upsampled frame count does not depend on the stride much: estimate it at
        # the requested stride, then raise the stride before warping every frame
        n_est = _upsampled_count(grey_full, ft, interpolate, log_eps, cfg.max_upsample)
        k = 1
        while n_est * len(range(0, grey_full.shape[1], s * k)) * len(range(0, grey_full.shape[2], s * k)) \
                > cfg.max_sim_steps and k < 64:
            k += 1
        if k > 1:
            log.info("pixel stride %d -> %d to stay within calibrate.max_sim_steps=%d",
                     s, s * k, cfg.max_sim_steps)
            s *= k
    sim_images, sim_t = upsample_sampled(grey_full, ft, interpolate, log_eps, s, cfg.max_upsample, flows=flows)
    real = subsample_events(events.slice_time(t0, t1), s)
    return _assemble(grey_full[:, ::s, ::s], ft, sim_images, sim_t, real, s, t0, t1, cfg, log_eps, source)


def _assemble(grey: np.ndarray, ft: np.ndarray, sim_images: np.ndarray, sim_t: np.ndarray, real: Events,
              s: int, t0: int, t1: int, cfg: CalibrateConfig, log_eps: float, source: str,
              intensity_edges: np.ndarray | None = None) -> CalibContext:
    images = np.ascontiguousarray(grey, dtype=np.float32)
    log_frames = np.log(images + np.float32(log_eps)).astype(np.float32)
    h, w = images.shape[1:]

    edges = np.linspace(t0, t1, cfg.segments + 1).round().astype(np.int64)
    segments = np.stack([edges[:-1], edges[1:]], 1)
    fit = tuple(range(0, cfg.segments, 2))
    held = tuple(range(1, cfg.segments, 2))

    rng_l = log_frames.max(0) - log_frames.min(0)
    static = rng_l < cfg.static_contrast

    B = cfg.intensity_bins
    if intensity_edges is None:
        q = np.quantile(log_frames, np.linspace(0, 1, B + 1))
        q = np.maximum.accumulate(q)
    else:
        q = intensity_edges
    inner = q[1:-1]
    frame_bin = np.searchsorted(inner, log_frames, side="right").astype(np.int8)
    # each frame stands for the time between the midpoints to its neighbours
    mids = np.concatenate([[ft[0]], (ft[:-1] + ft[1:]) // 2, [ft[-1]]])
    lo = np.maximum(mids[:-1][None, :], segments[:, :1])
    hi = np.minimum(mids[1:][None, :], segments[:, 1:])
    wseg = np.clip(hi - lo, 0, None).astype(np.float64) * 1e-6            # (S, N) seconds
    per_frame = np.stack([np.bincount(b.ravel(), minlength=B) for b in frame_bin]).astype(np.float64)
    occupancy = wseg @ per_frame                                          # (S, B)

    tb = int(cfg.time_bin_us)
    nb = max(1, (t1 - t0) // tb)                 # the last bin takes the remainder
    time_edges = t0 + tb * np.arange(nb + 1, dtype=np.int64)
    time_edges[-1] = t1
    centers = (time_edges[:-1] + time_edges[1:]) // 2
    time_seg = np.clip(np.searchsorted(edges, centers, side="right") - 1, 0, cfg.segments - 1)
    return CalibContext(width=w, height=h, stride=s, images=images, log_frames=log_frames,
                        frame_t=ft, sim_images=sim_images, sim_t=sim_t, real=real, t0=t0, t1=t1,
                        segments=segments, fit=fit, held=held,
                        static=static, intensity_edges=q, frame_bin=frame_bin, occupancy=occupancy,
                        time_edges=time_edges, time_seg=time_seg, cfg=cfg, log_eps=float(log_eps),
                        source=source)


def subsample_context(ctx: CalibContext, k: int) -> CalibContext:
    """The context on every ``k``-th sampled row/column (stride ``ctx.stride * k``): the
    cheap pixel sample the search runs on. Same window, segments and intensity bins; no
    interpolation is redone (the upsampled frames are sliced)."""
    if k <= 1:
        return ctx
    sim = np.ascontiguousarray(ctx.sim_images[:, ::k, ::k])
    real = subsample_events(ctx.real, k)
    return _assemble(ctx.images[:, ::k, ::k], ctx.frame_t, sim, ctx.sim_t, real, ctx.stride * k,
                     ctx.t0, ctx.t1, ctx.cfg, ctx.log_eps, ctx.source, intensity_edges=ctx.intensity_edges)


def _interp_cfg(interpolate, cap: int):
    from rdnet.sim.interpolate import InterpolateConfig
    cfg = InterpolateConfig() if interpolate is None else interpolate
    if cap and cfg.max_upsample > cap:
        cfg = dataclasses.replace(cfg, max_upsample=int(cap))
    return cfg


def _upsampled_count(grey: np.ndarray, t: np.ndarray, interpolate, log_eps: float, cap: int) -> int:
    """Upper bound of the upsampled frame count (every pair at its cap)."""
    cfg = _interp_cfg(interpolate, cap)
    if cfg.method == "none":
        return len(t)
    dt = np.diff(t)
    return int(1 + np.minimum(cfg.max_upsample, dt).sum())


def upsample_sampled(grey: np.ndarray, t: np.ndarray, interpolate, log_eps: float, stride: int,
                     cap: int = 0, flows=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rdnet.sim.interpolate.upsample` on the pixel grid of every ``stride``-th
    row/column: the optical flow is estimated on the full-resolution pair (flow needs
    neighbours), but the intermediate frames are warped only at the sampled pixels, so
    they equal the full-resolution ones sampled (up to float rounding) at 1/stride^2 of
    the cost. The adaptive count per pair follows ``upsample``: a first-order estimate
    from the full-resolution pair, checked on the sampled frames (the pixels that are
    simulated) and refined up to ``max_upsample`` (capped at ``cap``; a pair whose estimate
    is already at the cap is not checked). ``flows``: pair flows shared with the other
    interpolations of these frames (:class:`rdnet.sim.interpolate.PairFlowCache`)."""
    from rdnet.sim import interpolate as ip
    cfg = _interp_cfg(interpolate, cap)
    if stride == 1 or cfg.method == "none" or getattr(cfg, "fill_log", False):
        # nothing to save, or log-linear filling (decided on every pixel): the full sequence
        ims, ts = [], []
        for im, tt in ip.upsample(grey, t, cfg, log_eps, flows=flows):
            ims.append(np.ascontiguousarray(im[:, ::stride, ::stride]))
            ts.append(tt)
        return np.concatenate(ims).astype(np.float32, copy=False), np.concatenate(ts).astype(np.int64)
    eps = float(cfg.log_eps if cfg.log_eps is not None else log_eps)
    s = stride
    ims, ts = [], []
    at_cap = 0
    n = grey.shape[0]
    weight = ip.flow_weight(grey, t, cfg, eps) if cfg.method == "selected" else None
    for i in range(n - 1):
        f0, f1 = grey[i], grey[i + 1]
        dt = int(t[i + 1] - t[i])
        cap_i = min(cfg.max_upsample - 1, dt - 1)
        pi = ip.pair_interpolator(grey, i, f0, f1, cfg, weight, flows, eps)
        mid = np.empty((0,) + f0[::s, ::s].shape, np.float32)
        if cap_i > 0:
            k = min(cap_i, max(0, math.ceil(pi.motion_estimate(eps, cfg.pixel_quantile) / cfg.max_log_step) - 1))
            while True:
                mid = _sampled_frames(pi, k, s)
                if not cfg.verify or k >= cap_i:       # at the cap there is nothing to refine
                    at_cap += int(k >= cap_i)
                    break
                chain = np.concatenate([f0[None, ::s, ::s], mid, f1[None, ::s, ::s]])
                m = ip.log_steps(chain, eps, color=False, quantile=cfg.pixel_quantile)
                if m <= cfg.max_log_step:
                    break
                steps = k + 1
                new_steps = max(math.ceil(steps * m / cfg.max_log_step * 1.05), math.ceil(steps * 1.5), steps + 1)
                k = min(cap_i, new_steps - 1)
        k = mid.shape[0]
        t_mid = t[i] + np.rint(np.arange(1, k + 1) * (dt / (k + 1))).astype(np.int64)
        ims += [f0[None, ::s, ::s], mid]
        ts += [t[i:i + 1], t_mid]
    ims.append(grey[-1:, ::s, ::s])
    ts.append(t[-1:])
    if at_cap:
        log.info("%d of %d frame pairs upsampled at the cap max_upsample=%d (log-step bound %.3g not checked)",
                 at_cap, n - 1, cfg.max_upsample, cfg.max_log_step)
    return (np.ascontiguousarray(np.concatenate(ims), dtype=np.float32),
            np.concatenate(ts).astype(np.int64))


def _sampled_frames(pi, n_inserted: int, s: int) -> np.ndarray:
    """``pi.frames(n_inserted)`` at every ``s``-th pixel, each pixel computed exactly as at
    full resolution (:meth:`rdnet.sim.interpolate.PairInterpolator.on_grid`)."""
    h, w = pi.f0[::s, ::s].shape[:2]
    out = np.empty((n_inserted, h, w), np.float32)
    if n_inserted == 0:
        return out
    with pi.on_grid(s):
        for j in range(n_inserted):
            out[j] = pi.frame((j + 1) / (n_inserted + 1))
    return out


def frame_index(ctx: CalibContext, t: np.ndarray) -> np.ndarray:
    """Index of the frame nearest in time to each timestamp."""
    ft = ctx.frame_t
    mids = (ft[:-1] + ft[1:]) // 2
    return np.searchsorted(mids, t, side="right")
