"""What the calibration knows about a recording before simulating anything: the common
time window of frames and events, its fit/held-out segments, the pixel sample, the
static mask and the log-intensity bins every statistic refers to."""
from __future__ import annotations

import dataclasses
import logging
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

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

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
                  source: str = "recording") -> CalibContext:
    """Check the recording (frames and events present and overlapping in time), upsample
    its frames with :func:`rdnet.sim.interpolate.upsample` (``interpolate``: an
    ``InterpolateConfig``; None = the default, flow-based), sample the pixels and
    precompute the segment, static-mask and intensity-bin bookkeeping.

    The pixel stride is ``stride`` or ``cfg.pixel_stride``, raised until the upsampled
    frames have at most ``cfg.max_sim_steps`` pixel-frames (0 = no limit)."""
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
    sim_images, sim_t = _upsample(grey_full, ft, interpolate, log_eps, s, cfg.max_upsample)
    k = 1
    while cfg.max_sim_steps and sim_images[:, ::k, ::k].size > cfg.max_sim_steps and k < 64:
        k += 1
    if k > 1:
        log.info("pixel stride %d -> %d to stay within calibrate.max_sim_steps=%d",
                 s, s * k, cfg.max_sim_steps)
        sim_images = np.ascontiguousarray(sim_images[:, ::k, ::k])
        s *= k
    grey = grey_full[:, ::s, ::s]
    images = np.ascontiguousarray(grey, dtype=np.float32)
    log_frames = np.log(images + np.float32(log_eps)).astype(np.float32)
    real = subsample_events(events.slice_time(t0, t1), s)
    h, w = images.shape[1:]

    edges = np.linspace(t0, t1, cfg.segments + 1).round().astype(np.int64)
    segments = np.stack([edges[:-1], edges[1:]], 1)
    fit = tuple(range(0, cfg.segments, 2))
    held = tuple(range(1, cfg.segments, 2))

    rng_l = log_frames.max(0) - log_frames.min(0)
    static = rng_l < cfg.static_contrast

    B = cfg.intensity_bins
    q = np.quantile(log_frames, np.linspace(0, 1, B + 1))
    q = np.maximum.accumulate(q)
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
                        frame_t=ft, sim_images=sim_images, sim_t=sim_t, real=real, t0=t0, t1=t1, segments=segments, fit=fit, held=held,
                        static=static, intensity_edges=q, frame_bin=frame_bin, occupancy=occupancy,
                        time_edges=time_edges, time_seg=time_seg, cfg=cfg, log_eps=float(log_eps),
                        source=source)


def _upsample(grey: np.ndarray, t: np.ndarray, interpolate, log_eps: float, stride: int, cap: int = 0):
    """Upsampled frames at full resolution (optical flow needs neighbours), sampled pair
    by pair to the pixel grid so that the full-resolution sequence is never held."""
    from rdnet.sim.interpolate import InterpolateConfig, upsample
    cfg = InterpolateConfig() if interpolate is None else interpolate
    if cap and cfg.max_upsample > cap:
        cfg = dataclasses.replace(cfg, max_upsample=int(cap))
    ims, ts = [], []
    for im, tt in upsample(grey, t, cfg, log_eps):
        ims.append(np.ascontiguousarray(im[:, ::stride, ::stride]))
        ts.append(tt)
    return np.concatenate(ims).astype(np.float32, copy=False), np.concatenate(ts).astype(np.int64)


def frame_index(ctx: CalibContext, t: np.ndarray) -> np.ndarray:
    """Index of the frame nearest in time to each timestamp."""
    ft = ctx.frame_t
    mids = (ft[:-1] + ft[1:]) // 2
    return np.searchsorted(mids, t, side="right")
