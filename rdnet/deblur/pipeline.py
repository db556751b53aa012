"""RDNet on the frames of a real recording: event windows, voxels, both stages.

For each frame k the events of its *deblur window* become a voxel grid (``voxel``
section: bins, mode, normalisation, as the network was trained); stage 1 restores it,
guided by the frame, and stage 2 deblurs the frame with the restored voxels. The
networks are fully convolutional and pad any frame size internally
(:mod:`rdnet.nn.stage`), so frames of any size go in whole and come out at their size.

Windows (:class:`FrameWindows`):

* ``exposure`` -- [t_k - E_k / 2, t_k + E_k / 2) with E_k the frame's exposure time (the
  blur model of the paper: the frame is the mean of the sharp frames of that window);
* ``interval`` -- from half-way to the previous frame to half-way to the next one
  (consecutive windows tile the recording); also the fallback for frames without an
  exposure time.

With a count-output stage 1 (``train.restore_output: counts``) the windows become
per-polarity count grids (``voxel_grid(polarity="split")``, raw counts), stage 2 reads
stage 1's signed expected counts, and the restored events are the counts the
checkpoint's fitted decision keeps (the rule of :func:`rdnet.nn.decision.decided_events`,
as ``rdnet restore --method rdnet`` applies it), decided on the heads of the stage-1 pass
that gives the voxels (:func:`rdnet.eval.stage1.run_stage1`: stage 1 runs once per window).

The *restored event stream* is stage 1's output over the interval windows, rounded to
whole events; with ``deblur.event_times: input`` the events a voxel keeps are the window's
own recorded events there, with their timestamps (:func:`rdnet.events.select.select_events`),
with ``bins`` every event is spread over its bin (:func:`rdnet.events.voxel.voxel_events`);
it covers the recording from the
first to the last frame, so that the events between consecutive frames can be scored
against the frames (:mod:`rdnet.deblur.consistency`). When the deblur windows are the
interval windows one stage-1 pass serves both; otherwise stage 1 runs a second time on
the interval windows (a frame taken with a short exposure guides the restoration of a
longer window than in training: the restored stream is an extrapolation there).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np
import torch

from rdnet.errors import FormatError, ValidationError
from rdnet.eval.stage1 import signed_counts
from rdnet.events.core import Events, concatenate
from rdnet.events.recording import Frames
from rdnet.events.select import select_events, signed_entries, times_used
from rdnet.events.voxel import normalization_scale, voxel_events, voxel_grid
from rdnet.events.voxel_config import VoxelConfig
from rdnet.nn.decision import polarity_grid, read_decision

WINDOW_NOTES = {
    "exposure": "each frame's exposure window (frames/exposure_us)",
    "interval": "from half-way to the previous frame to half-way to the next one",
}


@dataclass(frozen=True)
class FrameWindows:
    """Per-frame event windows [start_us, start_us + duration_us] (int64, (N,)), their
    ``kind`` (exposure / interval) and a ``note`` on how they were chosen."""

    start_us: np.ndarray
    duration_us: np.ndarray
    kind: str
    note: str = ""

    def __len__(self) -> int:
        return int(self.start_us.shape[0])

    def same_as(self, other: "FrameWindows") -> bool:
        return (np.array_equal(self.start_us, other.start_us)
                and np.array_equal(self.duration_us, other.duration_us))

    def event_counts(self, events: Events) -> np.ndarray:
        """(N,) number of events inside each window (closed on the right, as voxel_grid)."""
        i0 = np.searchsorted(events.t, self.start_us, "left")
        i1 = np.searchsorted(events.t, self.start_us + self.duration_us, "right")
        return (i1 - i0).astype(np.int64)


def exposure_windows(frames: Frames, source: str = "recording") -> FrameWindows:
    """The exposure window of every frame (:meth:`Frames.exposure_window`)."""
    exp = frames.exposure_us
    if len(frames) and int(exp.min()) <= 0:
        k = int(np.argmax(exp <= 0))
        raise FormatError(source, "frames/exposure_us", f"frame {k} has no exposure time "
                          "(0 us); use deblur.window=interval (or auto)")
    return FrameWindows(frames.t_us - exp // 2, exp.copy(), "exposure", WINDOW_NOTES["exposure"])


def interval_windows(frames: Frames, source: str = "recording") -> FrameWindows:
    """Windows between the midpoints of consecutive frames; the first and last frames
    get the same half-width on their open side."""
    t = frames.t_us
    if len(t) < 2:
        raise FormatError(source, "frames", f"need at least 2 frames, got {len(t)}")
    mids = (t[:-1] + t[1:]) // 2
    edges = np.concatenate([[t[0] - (mids[0] - t[0])], mids, [t[-1] + (t[-1] - mids[-1])]])
    return FrameWindows(edges[:-1].astype(np.int64), np.diff(edges).astype(np.int64), "interval",
                        WINDOW_NOTES["interval"])


def choose_windows(frames: Frames, window: str, source: str = "recording") -> FrameWindows:
    """Deblur windows for ``deblur.window`` (auto: exposure when every frame has an
    exposure time, else interval, with a note saying it is the fallback)."""
    if window == "exposure":
        return exposure_windows(frames, source)
    if window == "interval":
        return interval_windows(frames, source)
    if window != "auto":
        raise ValidationError("deblur.window", f"must be auto, exposure or interval, got {window!r}")
    if len(frames) and int(frames.exposure_us.min()) > 0:
        return exposure_windows(frames, source)
    w = interval_windows(frames, source)
    return FrameWindows(w.start_us, w.duration_us, w.kind,
                        w.note + " (fallback: the recording has frames without exposure time)")


def network_images(frames: Frames, image_channels: int, source: str = "recording") -> np.ndarray:
    """(N, C, H, W) float32 linear intensity in [0, 1] for a network taking
    ``image_channels`` channels: colour frames become luminance for a grey network, grey
    frames become R = G = B for a colour one (e.g. DAVIS frames and the paper profile's
    RGB networks)."""
    if image_channels == 1:
        return frames.grey()[:, None]
    if image_channels == 3:
        if frames.is_color:
            return np.ascontiguousarray(np.moveaxis(frames.linear(), -1, 1))
        return np.repeat(frames.grey()[:, None], 3, axis=1)
    raise FormatError(source, "frames/images", f"the network takes {image_channels} image channels; "
                      "frames have 1 (grey) or 3 (colour)")


def window_voxels(events: Events, windows: FrameWindows, index: np.ndarray, voxel: VoxelConfig,
                  height: int, width: int, *, split: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(n, bins, H, W) signed-count voxel grids of the windows ``index`` and (n,) the
    divisor of each grid's normalisation (1 for raw counts): the network input is
    ``grids / scales``. ``split``: (n, 2 * bins, H, W) ON-then-OFF count grids (the
    count-output stage 1's input; raw counts, scales 1)."""
    if (events.width, events.height) != (width, height):
        raise ValidationError("events", f"sensor {events.width}x{events.height} != frames {width}x{height}")
    grids = np.stack([voxel_grid(events, voxel.bins, int(windows.start_us[k]), int(windows.duration_us[k]),
                                 mode=voxel.mode, polarity="split" if split else "signed") for k in index])
    if split:
        return grids.reshape(grids.shape[0], -1, height, width), np.ones(grids.shape[0], np.float32)
    scales = np.array([normalization_scale(g, voxel.normalize) for g in grids], np.float32)
    return grids, scales


def run_rdnet(net, images: np.ndarray, voxels: np.ndarray, device: torch.device, *,
              restore_only: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """(restored voxels, deblurred images) of RDNet for (n, C, H, W) images and
    (n, bins, H, W) voxels of the same frames (numpy float32; (n, 2 * bins, H, W) ON-then-OFF
    counts for a count-output stage 1); ``restore_only`` runs stage 1 alone (deblurred
    None). The restored voxels are signed (n, bins, H, W) (expected ON - OFF counts for the
    count output). ValidationError when the sizes disagree."""
    restored, sharp, _ = _run(net, images, voxels, device, restore_only=restore_only)
    return restored, sharp


def _run(net, images: np.ndarray, voxels: np.ndarray, device: torch.device, *, restore_only: bool = False,
         decision: dict | None = None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`run_rdnet` and, with ``decision``, the (n, 2, bins, H, W) restored events of
    the same stage-1 pass (:func:`rdnet.eval.stage1.run_stage1`; None without)."""
    from rdnet.runtime import keep_freed_memory
    keep_freed_memory()      # full-frame activations reused, not mmapped afresh per batch
    from rdnet.eval.stage1 import run_stage1
    cfg = net.restore.config
    channels = net.restore.in_channels
    if images.ndim != 4 or voxels.ndim != 4:
        raise ValidationError("images/voxels", f"expected 4-D arrays, got {images.shape} and {voxels.shape}")
    if images.shape[0] != voxels.shape[0]:
        raise ValidationError("voxels", f"{voxels.shape[0]} voxel grids for {images.shape[0]} images")
    if images.shape[-2:] != voxels.shape[-2:]:
        raise ValidationError("voxels", f"voxel size {tuple(voxels.shape[-2:])} (H, W) != image size "
                              f"{tuple(images.shape[-2:])}")
    if images.shape[1] != cfg["image_channels"]:
        raise ValidationError("images", f"{images.shape[1]} channels, the network takes {cfg['image_channels']}")
    if voxels.shape[1] != channels:
        raise ValidationError("voxels", f"{voxels.shape[1]} bins, the network takes {channels}")
    with torch.inference_mode():
        img = torch.from_numpy(np.ascontiguousarray(images, np.float32)).to(device)
        vox = torch.from_numpy(np.ascontiguousarray(voxels, np.float32)).to(device)
        restored, events = run_stage1(net.restore, img, vox, decision)
        sharp = None if restore_only else net.stage2(img, restored, vox).float().cpu().numpy()
        return restored.float().cpu().numpy(), sharp, events


@dataclass(frozen=True)
class DeblurBatch:
    """Results of consecutive frames ``index``: ``deblurred`` (n, C, H, W) in [0, 1];
    ``events`` (the restored stream over the interval windows of these frames) and
    ``deblur_events`` (restored events of the deblur windows; None when those are the
    interval windows); ``raw_voxel`` / ``restored_voxel`` (n, bins, H, W) signed counts
    of the interval windows (for figures); ``deblur_window_events`` (n,) raw events in
    each deblur window."""

    index: np.ndarray
    deblurred: np.ndarray
    events: Events
    deblur_events: Events | None
    raw_voxel: np.ndarray
    restored_voxel: np.ndarray
    deblur_window_events: np.ndarray


def _to_events(restored: np.ndarray, scales: np.ndarray, windows: FrameWindows, index: np.ndarray,
               mode: str, inputs: Events | None = None) -> Events:
    """The events of the restored grids (signed or per-polarity, times ``scales``) of the
    windows ``index``: taken from ``inputs`` where they have them (hard binning only;
    :func:`rdnet.events.select.select_events`, each window's inputs as its voxel grid holds
    them, end included), else spread over the bins."""
    parts = []
    for i, k in enumerate(index):
        t0, dur, scale = int(windows.start_us[k]), int(windows.duration_us[k]), float(scales[i])
        if inputs is None or mode != "hard":
            parts.append(voxel_events(restored[i], t0, dur, mode=mode, scale=scale))
            continue
        grid = restored[i] if scale == 1.0 else restored[i].astype(np.float64) * scale
        entries, counts, shape = signed_entries(grid)
        parts.append(select_events(inputs.slice_time(t0, t0 + dur + 1), entries, counts, shape, t0, dur))
    return concatenate(parts, sort=True)


def iter_deblur(net, images: np.ndarray, events: Events, deblur_windows: FrameWindows,
                event_windows: FrameWindows, voxel: VoxelConfig, *, batch_size: int = 4,
                device: torch.device | str = "cpu", progress: bool = False,
                decision: dict | None = None, event_times: str = "input") -> Iterator[DeblurBatch]:
    """Run both stages over ``images`` (N, C, H, W) in batches of ``batch_size`` frames
    (module docstring); yields one :class:`DeblurBatch` per batch. ``decision``: the
    checkpoint's voxel -> event decision (required for a count-output stage 1);
    ``event_times``: ``deblur.event_times`` (input or bins)."""
    if event_times not in ("input", "bins"):
        raise ValidationError("deblur.event_times", f"must be input or bins, got {event_times!r}")
    inputs = events if times_used(event_times, voxel.mode) == "input" else None
    from tqdm.auto import tqdm

    n, _, H, W = images.shape
    if len(deblur_windows) != n or len(event_windows) != n:
        raise ValidationError("windows", f"{len(deblur_windows)} / {len(event_windows)} windows for {n} frames")
    device = torch.device(device)
    net = net.to(device).eval()
    same = deblur_windows.same_as(event_windows)
    counts = deblur_windows.event_counts(events)
    split = net.restore.output == "counts"
    if split and voxel.normalize not in (None, "none"):
        raise ValidationError("voxel.normalize", "a count-output stage 1 reads raw per-polarity counts")

    if split:                            # a count-output stage 1 needs its fitted decision
        read_decision(decision, "counts")
    decide = decision if split else None  # the signed output's events: its voxels rounded

    def stream(restored, decided, scales, windows, idx):
        """Restored events of the windows: rounded signed voxels, or the decided counts
        (of the same stage-1 pass)."""
        return _to_events(decided if split else restored, scales, windows, idx, voxel.mode, inputs)

    def signed(grids):                   # the raw signed voxels of the figures
        if not split:
            return grids
        return signed_counts(polarity_grid(grids))

    with tqdm(total=n, desc="deblur", unit="frame", disable=(not progress) or None) as bar:
        for s in range(0, n, batch_size):
            idx = np.arange(s, min(n, s + batch_size))
            img = images[idx]
            grids, scales = window_voxels(events, deblur_windows, idx, voxel, H, W, split=split)
            restored, sharp, decided = _run(net, img, grids / scales[:, None, None, None], device,
                                            decision=decide)
            if same:
                raw_e, scales_e, restored_e, decided_e, deblur_events = grids, scales, restored, decided, None
            else:
                deblur_events = stream(restored, decided, scales, deblur_windows, idx)
                raw_e, scales_e = window_voxels(events, event_windows, idx, voxel, H, W, split=split)
                restored_e, _, decided_e = _run(net, img, raw_e / scales_e[:, None, None, None], device,
                                                restore_only=True, decision=decide)
            bar.update(idx.size)
            yield DeblurBatch(index=idx, deblurred=np.clip(sharp, 0.0, 1.0),
                              events=stream(restored_e, decided_e, scales_e, event_windows, idx),
                              deblur_events=deblur_events, raw_voxel=signed(raw_e),
                              restored_voxel=restored_e * scales_e[:, None, None, None],
                              deblur_window_events=counts[idx])
