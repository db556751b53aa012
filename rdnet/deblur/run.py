"""``rdnet deblur``: restore and deblur every frame of a real recording, write the
results and the event-frame consistency of raw and restored events.

Outputs (``out``: small, meant for git; ``data_out``: large, defaults to ``out``):

* ``out/consistency.json`` -- ``raw`` and ``restored`` (the headline score of each event
  stream, :mod:`rdnet.deblur.consistency`), ``better`` ("higher"), ``metric`` (what the
  score is), ``details`` (every statistic per stream), ``windows``, ``deblur`` (how much
  the frames changed, events per deblur window) and ``run`` (recording, checkpoint,
  frames, voxel settings, notes);
* ``out/montage.png`` -- a few frames: APS frame | raw events | restored events | deblurred;
* ``data_out/restored.h5`` -- HDF5 recording (project layout): ``/events`` = the restored
  event stream (interval windows), ``/events_deblur`` = the restored events of the deblur
  windows when those differ, ``/frames`` = the deblurred frames (float32 linear,
  ``exposure_us`` 0: a sharp frame stands for its instant);
* ``data_out/deblurred/<k>.png`` -- every deblurred frame as an 8-bit PNG (``deblur.png``).

Everything is written into staging folders that replace their targets only when the
whole run succeeded (:func:`rdnet.events.io._common.atomic_directory`): a failure leaves
no partial output.
"""
from __future__ import annotations

import contextlib
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rdnet.config import section, to_dict
from rdnet.deblur.config import DeblurConfig
from rdnet.deblur.consistency import BETTER, METRIC, LogFrames, compare_consistency
from rdnet.deblur.network import LoadedRDNet, load_rdnet, resolve_checkpoint
from rdnet.deblur.pipeline import FrameWindows, choose_windows, interval_windows, iter_deblur, network_images
from rdnet.errors import FormatError
from rdnet.events.core import Events, concatenate
from rdnet.events.recording import Frames
from rdnet.events.select import times_used
from rdnet.events.voxel_config import VoxelConfig

if TYPE_CHECKING:
    import torch

    from rdnet.sim.settings import SensorConfig

log = logging.getLogger(__name__)


def _finite(v):
    """JSON-safe number (NaN/inf -> None)."""
    return None if isinstance(v, float) and not math.isfinite(v) else v


def _png(path: Path, image_chw: np.ndarray) -> None:
    """8-bit PNG of a (C, H, W) [0, 1] image (the text format's image encoder)."""
    from rdnet.events.io.text import _encode_image
    img = np.rint(np.clip(image_chw, 0.0, 1.0) * 255.0).astype(np.uint8)
    img = img[0] if img.shape[0] == 1 else np.ascontiguousarray(np.moveaxis(img, 0, -1))
    path.write_bytes(_encode_image(img)[1])


@dataclass(frozen=True)
class DeblurInputs:
    """Everything a run needs, checked before anything is written: the settings, the
    network, the frames (``max_frames`` applied) and events, the network's images and
    both window sets."""

    cfg: DeblurConfig
    voxel: VoxelConfig
    sensor: "SensorConfig"
    loaded: LoadedRDNet
    source: str
    sensor_name: str
    frames: Frames
    events: Events
    images: np.ndarray
    deblur_windows: FrameWindows
    event_windows: FrameWindows
    device: "torch.device"
    notes: tuple = ()

    @property
    def event_times(self) -> str:
        """The timestamp rule of the restored events (:func:`rdnet.events.select.times_used`:
        ``deblur.event_times``, but ``bins`` for bilinear voxels)."""
        return times_used(self.cfg.event_times, self.voxel.mode)


def prepare(recording: str | Path, params: dict, checkpoint: str | Path | None = None) -> DeblurInputs:
    """Load and check the checkpoint (against the ``model``/``voxel`` params), the
    recording (frames and events) and the windows; RdnetError on any bad input."""
    import torch

    from rdnet.events.io import load
    from rdnet.train.loop import resolve_device

    cfg = section(params, "deblur")
    voxel, model_cfg, sensor = section(params, "voxel"), section(params, "model"), section(params, "sensor")
    device = resolve_device(cfg.device, key="deblur.device")
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    loaded = load_rdnet(resolve_checkpoint(checkpoint), model_cfg, voxel, device)
    rec = load(recording)
    src = str(recording)
    frames, events = rec.require_frames(src), rec.require_events(src)
    if cfg.max_frames is not None and len(frames) > cfg.max_frames:
        k = cfg.max_frames
        frames = Frames(frames.images[:k], frames.t_us[:k], frames.exposure_us[:k])
    if len(frames) < 2:
        raise FormatError(src, "frames", f"need at least 2 frames (consecutive frames are compared), "
                          f"got {len(frames)}")
    images = network_images(frames, loaded.image_channels, src)
    deblur_w = choose_windows(frames, cfg.window, src)
    event_w = interval_windows(frames, src)
    if len(events) == 0 or not np.any(event_w.event_counts(events)):
        span = f"events at {int(events.t[0])}..{int(events.t[-1])} us" if len(events) else "no events"
        raise FormatError(src, "events", f"no event falls in any frame's window (frames at {int(frames.t_us[0])}.."
                          f"{int(frames.t_us[-1])} us, {span}): the frames and events do not overlap in time")
    notes = [deblur_w.note if "fallback" in deblur_w.note else "", loaded.note,
             "grey frames given to a colour network as R = G = B"
             if images.shape[1] == 3 and not frames.is_color else "",
             f"deblur.event_times=input keeps recorded timestamps only with hard voxel bins; voxel.mode is "
             f"{voxel.mode!r}, so the restored events are spread over the bins"
             if times_used(cfg.event_times, voxel.mode) != cfg.event_times else ""]
    return DeblurInputs(cfg=cfg, voxel=voxel, sensor=sensor, loaded=loaded, source=src, sensor_name=rec.sensor,
                        frames=frames, events=events, images=images, deblur_windows=deblur_w,
                        event_windows=event_w, device=device,
                        notes=tuple(x for x in notes if x))


def deblur_recording(recording: str | Path, out: str | Path, params: dict, *,
                     checkpoint: str | Path | None = None, data_out: str | Path | None = None,
                     progress: bool = False) -> dict:
    """Run ``rdnet deblur`` (module docstring) and return the consistency.json content.

    ``params``: a loaded params dict (sections ``deblur``, ``voxel``, ``model``,
    ``sensor``); ``checkpoint``: an RDNet checkpoint file or folder (default: the study's,
    :data:`rdnet.deblur.network.DEFAULT_CHECKPOINT`). Every check (checkpoint against the
    params, frames, events) happens before anything is written (:func:`prepare`)."""
    from rdnet.events.io import H5RecordingWriter
    from rdnet.events.io._common import atomic_directory, check_output_folder
    from rdnet.eval.report import sample_grid, write_text_atomic

    out = Path(out)
    data_out = out if data_out is None else Path(data_out)
    check_output_folder(out, ("consistency.json", "montage.png"), inputs=(recording,))  # before the work
    check_output_folder(data_out, ("restored.h5",), inputs=(recording,))
    x = prepare(recording, params, checkpoint)
    cfg, frames, images = x.cfg, x.frames, x.images
    n, C, H, W = images.shape
    show = (np.unique(np.linspace(0, n - 1, min(cfg.montage_frames, n)).round().astype(int))
            if cfg.montage_frames else np.zeros(0, int))
    log.info("%s: %d frames %dx%d, %d events; deblur windows: %s; checkpoint %s on %s",
             x.source, n, W, H, len(x.events), x.deblur_windows.kind, x.loaded.path, x.device)

    restored_parts, deblur_parts, window_events, change = [], [], [], []
    fig: dict[str, list] = {"raw": [], "restored": [], "deblurred": []}
    same_dir = out.resolve() == data_out.resolve()
    with atomic_directory(data_out) as stage_data, \
            (contextlib.nullcontext(stage_data) if same_dir else atomic_directory(out)) as stage_out:
        if cfg.png:
            (stage_data / "deblurred").mkdir()
        with H5RecordingWriter(stage_data / "restored.h5", W, H, x.sensor_name) as w:
            for b in iter_deblur(x.loaded.net, images, x.events, x.deblur_windows, x.event_windows, x.voxel,
                                 batch_size=cfg.batch_size, device=x.device, progress=progress,
                                 decision=x.loaded.decision, event_times=x.event_times):
                restored_parts.append(b.events)
                if b.deblur_events is not None:
                    deblur_parts.append(b.deblur_events)
                window_events.append(b.deblur_window_events)
                change.append(np.abs(b.deblurred - images[b.index]).mean(axis=(1, 2, 3)))
                out_frames = b.deblurred[:, 0] if C == 1 else np.moveaxis(b.deblurred, 1, -1)
                w.append_frames(out_frames.astype(np.float32), frames.t_us[b.index],
                                np.zeros(b.index.size, np.int64))
                for i, k in enumerate(b.index):
                    if cfg.png:
                        _png(stage_data / "deblurred" / f"{k:05d}.png", b.deblurred[i])
                    if k in show:
                        fig["raw"].append(b.raw_voxel[i])
                        fig["restored"].append(b.restored_voxel[i])
                        fig["deblurred"].append(b.deblurred[i])
            restored = concatenate(restored_parts, sort=True)
            w.append_events(restored, "events")
            if deblur_parts:
                w.append_events(concatenate(deblur_parts, sort=True), "events_deblur")
            w.set_attr("source", x.source)
            w.set_attr("checkpoint", str(x.loaded.path))
            w.set_attr("deblur_json", json.dumps({"deblur_windows": x.deblur_windows.kind,
                                                  "event_windows": x.event_windows.kind,
                                                  "voxel": to_dict(x.voxel),
                                                  "event_times": x.event_times}))
        result = _summary(x, restored, np.concatenate(change), np.concatenate(window_events))
        if show.size:
            ek, dk = x.event_windows.kind, x.deblur_windows.kind
            sample_grid(stage_out / "montage.png", images[show], np.stack(fig["raw"]), np.stack(fig["restored"]),
                        np.stack(fig["deblurred"]), None,
                        titles=["frame", f"raw events ({ek})", f"restored events ({ek})", f"deblurred ({dk})"],
                        row_labels=[f"frame {k}" for k in show])
        write_text_atomic(stage_out / "consistency.json", json.dumps(result, indent=2) + "\n")
    return result


def _summary(x: DeblurInputs, restored: Events, change: np.ndarray, window_events: np.ndarray) -> dict:
    """The consistency.json content (module docstring)."""
    s = x.sensor
    lf = LogFrames.of(x.frames, x.events, s.log_eps)
    scores = compare_consistency(lf, {"raw": x.events, "restored": restored}, s.threshold_on, s.threshold_off)
    return {
        "raw": _finite(scores["raw"]["r2_fitted"]),
        "restored": _finite(scores["restored"]["r2_fitted"]),
        "better": BETTER,
        "metric": METRIC,
        "details": {k: {m: _finite(v) for m, v in d.items()} for k, d in scores.items()},
        "frame_pairs": lf.scored_intervals,
        "windows": {"deblur": x.deblur_windows.kind, "deblur_note": x.deblur_windows.note,
                    "restored_events": x.event_windows.kind, "restored_events_note": x.event_windows.note},
        "deblur": {"mean_abs_change": float(np.mean(change)),
                   "events_per_window_median": float(np.median(window_events)),
                   "events_per_window_max": int(window_events.max())},
        "run": {"recording": x.source, "checkpoint": str(x.loaded.path), "frames": len(x.frames),
                "width": x.frames.width, "height": x.frames.height, "events": len(x.events),
                "voxel": to_dict(x.voxel), "event_times": x.event_times,
                "thresholds_nominal": [s.threshold_on, s.threshold_off],
                "log_eps": s.log_eps, "notes": list(x.notes)},
    }
