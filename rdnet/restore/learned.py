"""The learned event restorers (RDNet stage 1) behind ``rdnet restore --method rdnet``.

Three networks, all :class:`rdnet.nn.models.RestoreNet` checkpoints (task ``restore`` /
``restore_events`` / ``restore_frames`` of :mod:`rdnet.train.loop`):

* ``rdnet-image`` -- image-guided: needs the frame of each window (``needs_frames``);
* ``rdnet-events`` -- events only (no image branch), for cameras without frames;
* ``rdnet-frames`` -- guided by the two frames that bracket each window (``frame_pairs``;
  the checkpoint's ``extra["guide"]``, :mod:`rdnet.nn.guide`): ``rdnet restore`` then cuts
  its windows at the frames' timestamps and hands each window its two frames; the events
  before the first frame and after the last one, which no pair brackets, pass unchanged
  (:meth:`LearnedRestorer.restore` with ``frame=None``).

:func:`load_restorer` finds the checkpoint, in this order: the ``checkpoint`` argument
(a ``model.pt`` file, or a folder holding ``model.pt`` or ``seed<k>/model.pt``, the
lowest ``k`` first); the study's trained restorers as ``dvc repro`` writes them
(:data:`STUDY_MODELS`, relative to the working directory); the small exported copies
shipped as package data (``rdnet/restore/models/<name>.pt``). Without a checkpoint the kind
follows the recording and ``restore.guide``: on a recording with frames the blurry-frame
restorer (``frame``) or the frame-pair one (``frame_pair``; ``auto``, the default, picks it
when the camera's threshold is known, ``restore.guide_threshold``), falling back to the
events-only one when neither is found; without frames the events-only one. It logs
which one it uses. Every checkpoint is validated (kind, voxel bins, frames): a mismatch is a
ConfigError naming the file and the field.

:meth:`LearnedRestorer.restore` voxelises one window ``[t0, t1)`` (per polarity for the
count output, signed for the paper's output), runs the network, applies the decision
stored in the checkpoint (:mod:`rdnet.nn.decision`: a fitted occupancy threshold, or
rounding for the signed output) and turns the counts back into events. With
``event_times="input"`` (``restore.event_times``, the default) the events a voxel keeps are
the window's own input events of that voxel, with their timestamps, and only the events a
voxel holds beyond its input are spread over its bin (:func:`rdnet.events.select.select_events`);
with ``"bins"`` every event is spread evenly inside its bin
(:func:`rdnet.events.voxel.entry_events`). Both give the same voxel grid; on the DAVIS346
recording the first writes 73,191 of its 76,529 restored events as recorded, the second 26
(where a time spread inside its 4.2 ms bin happens to fall on a recorded one: the study's
restorers take 41.7 ms windows of 10 bins).

Inference speed (issue 11: faster than real time on the DAVIS346 recording): the network
is prepared once by :func:`prepare_for_inference` -- eval mode and, on a CPU with at
least 2 torch threads, the channels_last memory format for the weights and every input
(oneDNN's convolutions run in NHWC without reordering, and
:class:`rdnet.nn.blocks.LayerNorm2d` uses torch's fused layer norm on such inputs: about
25 % less network time at 346 x 260 on 2 cores, 37 -> 28 ms; with 1 thread channels_last
is slower, so contiguous stays). The outputs differ from the contiguous layout's by float
rounding (below 1e-5 on the heads), so a voxel whose occupancy probability lies within
rounding of the threshold may be decided the other way (none on the DAVIS346 recording:
its 70,374 restored events are identical); ``tests/restore/test_learned_speed.py``
checks the two layouts give the same events on synthetic streams. Training is untouched
(it never runs channels_last). The count output is decided on the logits and only the
kept voxels are read back (:func:`rdnet.nn.decision.sparse_decided_entries`,
:func:`rdnet.events.voxel.entry_events`): no dense sigmoid, float64 or int64 grid per
window (about 10 ms a window before). Since then three more inference paths, each equal
to the plain network up to float rounding (tests/nn/test_inference_layout.py): the layer
norms of 8 and 16 channels run in a numba kernel (:mod:`rdnet.nn.cpu_kernels`; torch's
per-row cost dominated them), each NAFBlock folds its channel attention and its
``beta`` / ``gamma`` into the 1x1 convolutions' weights (:meth:`NAFBlock._folded`), and
only the occupancy half of the output convolution runs densely, the count head being
evaluated at the kept voxels alone (:meth:`rdnet.nn.models.RestoreNet.sparse_heads`; the
kept voxels are exactly those of the dense heads). End to end on one host
(``benchmarks/bench_restore.py``, ``benchmarks/results/restore_learned_speed_inference.json``)
the steady state went from 1.70 to 1.46 s per recording second and the night file from
113 to 81 s; the numba kernel costs 0.3-0.5 s once per process, when its compiled code
is loaded, so recordings shorter than about 2 s lose time. A count-output window with at
most :data:`rdnet.nn.sparse.SPARSE_MAX_DENSITY` non-zero voxels (a DAVIS346 window: 0.07 %)
goes in as its entries (:func:`rdnet.events.voxel.voxel_entries`,
:class:`rdnet.nn.sparse.SparseVoxels`): the event branch's first convolution is a scatter of
those entries and the dense grid, its padding and channels_last copy are never made
(``benchmarks/bench_restore_ab.py``: with the vectorised layer norm and the other changes of
that commit, 0.66-0.85x -> 0.81-1.17x real time in steady state, alternated rounds; the
night file 77 -> 57 s; the same events on both). Two more (2026-11-30): with a decision
that applies the support rule (every study restorer's), a window whose supported pixels are
at most :data:`rdnet.nn.decision.GATED_MAX_SUPPORT` of the frame (a DAVIS346 window: 1.6 %
on average, 2.7 % at most) gets its occupancy logits at those pixels alone
(``sparse_heads(pixels=...)``) instead of from the dense conv, the costliest operation of the
window (5.3 of 33 ms in torch's profiler); and on the CPU several windows run at once, one per
torch thread (:meth:`LearnedRestorer.parallel`, ``restore.workers``), since on these shared 2 cores one
window on both threads ran at 30 or at 50 ms depending on the host's other load, one window
per core at 27-30 ms (in-process, alternated). Both give the same events as before on the
DAVIS346, DVXplorer, sparklers and night files (``benchmarks/results/restore_workers.json``
for the settings, ``restore_learned_speed_ab_gated_workers.json`` against the previous code).
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from rdnet.errors import ConfigError, FormatError, ModelNotFoundError, ValidationError
from rdnet.events.core import Events
from rdnet.events.select import capped_entries, floored_entries, select_events, signed_entries, times_used
from rdnet.events.voxel import entry_events, voxel_entries, voxel_events, voxel_grid

log = logging.getLogger(__name__)

#: ``restore.workers: 0`` runs one window per torch thread on sensors of at most this many
#: pixels (640 x 480), one window on every thread on larger ones
#: (:meth:`LearnedRestorer.parallel`)
WINDOW_PER_THREAD_MAX_PIXELS = 640 * 480

#: the kinds of learned restorer: what guides it besides the events (``restore.guide`` picks
#: ``frame`` or ``frame_pair`` for a recording with frames; ``events`` without frames)
KINDS = ("frame", "frame_pair", "events")
#: the study's trained restorers (dvc repro outputs), by kind.
STUDY_MODELS = {"frame": Path("models/restore_image"), "frame_pair": Path("models/restore_frames"),
                "events": Path("models/restore_events")}
#: package-data names (rdnet/restore/models/<name>.pt), by kind.
PACKAGE_MODELS = {"frame": "restore_image", "frame_pair": "restore_frames", "events": "restore_events"}


def _checkpoint_file(path: Path) -> Path | None:
    """``path`` itself, ``path/model.pt`` or the lowest ``path/seed<k>/model.pt``."""
    if path.is_file():
        return path
    if (path / "model.pt").is_file():
        return path / "model.pt"
    seeds = sorted((p for p in path.glob("seed*/model.pt") if p.parent.name[4:].isdigit()),
                   key=lambda p: int(p.parent.name[4:]))
    return seeds[0] if seeds else None


def _package_file(name: str) -> Path | None:
    from importlib import resources
    try:
        f = resources.files("rdnet.restore").joinpath("models", f"{name}.pt")
    except (ModuleNotFoundError, FileNotFoundError):
        return None
    return Path(str(f)) if f.is_file() else None


def prepare_for_inference(net, device, channels_last: bool | None = None) -> bool:
    """Put a restoration network in eval mode in the memory format inference runs fastest
    in (module docstring) and return whether that is channels_last (the inputs must then
    be channels_last too: :meth:`LearnedRestorer.restore` converts them). ``channels_last``:
    None chooses -- True on a CPU device when torch uses at least 2 threads -- or force
    one layout (True / False; the tests compare both). Only the layout of the weights in
    memory changes, never their values; a network trained afterwards is unaffected but
    slower, so this is for inference only."""
    import torch
    if channels_last is None:
        channels_last = torch.device(str(device)).type == "cpu" and torch.get_num_threads() >= 2
    net.eval()
    net.to(memory_format=torch.channels_last if channels_last else torch.contiguous_format)
    return bool(channels_last)


class DecisionMemo:
    """The decided voxel entries of windows restored already, for restoring the same recording
    again with the same network and decision and another post-filter: ``restore_real`` writes
    the learned restorer's output, its deletions only (``restore.add_events: false``) and its
    additions only (``restore.delete_events: false``), whose windows all take the same decision
    before the filter. Give one memo to each of those runs (``restore_recording(memo=...)``):
    the first computes a window's entries, the others read them. An entry is known by the
    restorer's fingerprint (:meth:`LearnedRestorer.decision_fingerprint`: checkpoint source,
    decision, voxel settings, device and memory layout), the window's bounds and a digest of
    its input events and image, so a run with another network, or whose input differs
    (without the hot-pixel pass), computes and adds its own. Thread-safe (windows restored at
    once, :meth:`LearnedRestorer.parallel`)."""

    def __init__(self):
        self._entries: dict = {}
        self._lock = threading.Lock()
        #: windows computed, and windows read from the memo
        self.computed = self.reused = 0

    @staticmethod
    def key(fingerprint: str, t0_us: int, t1_us: int, events: Events, frame: np.ndarray | None) -> tuple:
        h = hashlib.blake2b(np.ascontiguousarray(events.array).tobytes(), digest_size=16)
        if frame is not None:
            h.update(np.ascontiguousarray(frame).tobytes())
        return fingerprint, int(t0_us), int(t1_us), len(events), h.hexdigest()

    def get(self, key: tuple):
        with self._lock:
            hit = self._entries.get(key)
            if hit is not None:
                self.reused += 1
            return hit

    def put(self, key: tuple, entries: tuple) -> None:
        """Keep ``entries`` (the decided ``(index, counts)``), read-only: every run reads them."""
        for a in entries:
            a.flags.writeable = False
        with self._lock:
            self._entries[key] = entries
            self.computed += 1


@dataclass
class LearnedRestorer:
    """A trained RestoreNet and its decision (structurally a
    :class:`rdnet.restore.base.Restorer`)."""

    name: str
    needs_frames: bool
    window_us: int | None
    net: object
    decision: dict
    bins: int
    mode: str
    source: str
    device: str = "cpu"
    #: whether the network and its inputs are channels_last (:func:`prepare_for_inference`)
    channels_last: bool = False
    #: ``input``: kept events are the input's own (:mod:`rdnet.events.select`; hard voxel
    #: bins only, :attr:`times`); ``bins``: every event spread over its bin (``restore.event_times``)
    event_times: str = "input"
    #: False: each voxel capped at its input events, the output a subset of the input
    #: (``restore.add_events``)
    add_events: bool = True
    #: False: each voxel raised to at least its input events, every input event in the
    #: output (``restore.delete_events``)
    delete_events: bool = True
    #: decided entries shared with other runs on the same recording (:class:`DecisionMemo`;
    #: count output only); set by :meth:`share_decisions`
    memo: DecisionMemo | None = None
    #: the frame-pair guide (:class:`rdnet.nn.guide.FramePairGuide`) of a ``restore_frames``
    #: network; None for the blurry-frame and events-only ones
    guide: object = None
    #: the contrast threshold the frame-pair network was trained with when ``guide`` holds
    #: another one (``restore.guide_threshold``); None when it is the checkpoint's own
    trained_threshold: float | None = None

    @property
    def frame_pairs(self) -> bool:
        """Whether each window needs the two frames that bracket it (module docstring)."""
        return self.guide is not None

    def share_decisions(self, memo: DecisionMemo) -> None:
        """Take and give the decided entries of each window through ``memo`` (count output
        only; a signed-output restorer ignores it)."""
        if self.output == "counts":
            self.memo = memo

    def decision_fingerprint(self) -> str:
        """What the decided entries of a window depend on besides its input: the checkpoint,
        the decision, the voxel settings, the device and the memory layout (the key of
        :class:`DecisionMemo`)."""
        d = json.dumps(self.decision or {}, sort_keys=True, default=str)
        g = None if self.guide is None else self.guide.to_dict()
        return f"{self.source}|{d}|{self.bins}|{self.mode}|{self.needs_frames}|{g}|{self.device}|{self.channels_last}"

    @contextlib.contextmanager
    def parallel(self, workers: int = 0, sensor_pixels: int = 0):
        """Inside, :meth:`restore` may be called for several windows at once: yields how many
        (``workers``; 0 = one per torch thread on a sensor of at most
        :data:`WINDOW_PER_THREAD_MAX_PIXELS` pixels, else 1), with torch's intra-op threads
        shared among them, and restores the thread count on exit (numba's layer-norm kernel
        keeps its own: one or two numba threads per window timed the same, 29.1 against
        29.2 ms a DAVIS346 window, ``benchmarks/restore_window_numba_threads.py``).
        1 (one window at a time, every thread on it) on a GPU, with one thread, or when the
        numba kernel of :class:`rdnet.nn.blocks.LayerNorm2d` cannot be called concurrently.
        A window's events do not depend on how many run at once. On 2 cores a window per
        core was faster up to 640 x 480 and slower at 1280 x 720, where one window's
        operations are large enough to share out (``benchmarks/results/restore_workers.json``):
        the finding behind :func:`rdnet.calib.calibrate.numba_threads`, short pieces of work
        run fastest single-threaded on shared cores, at the level of whole windows."""
        import torch
        threads = torch.get_num_threads()
        n = int(workers) if workers else threads if sensor_pixels <= WINDOW_PER_THREAD_MAX_PIXELS else 1
        if n <= 1 or torch.device(self.device).type != "cpu":
            yield 1
            return
        from rdnet.nn.cpu_kernels import concurrent_calls_safe
        if not concurrent_calls_safe():
            log.info("numba's workqueue threading layer cannot run windows concurrently: one at a time")
            yield 1
            return
        torch.set_num_threads(max(1, threads // n))
        try:
            yield n
        finally:
            torch.set_num_threads(threads)

    @property
    def output(self) -> str:
        return self.net.output

    @property
    def times(self) -> str:
        """The timestamp rule applied (:func:`rdnet.events.select.times_used`): ``bins`` for a
        network on bilinear voxels even when ``event_times`` asks for ``input``."""
        return times_used(self.event_times, self.mode)

    @property
    def info(self) -> dict:
        """What ``rdnet restore`` records in OUT.json under ``model``: where the network came
        from, its output and window, and the voxel -> event decision it applies (threshold
        and whether the support rule drops events without a neighbour)."""
        from rdnet.nn.decision import support_applies
        d = self.decision or {}
        sup = d.get("support") or {}
        return {"kind": "learned", "source": self.source, "output": self.output,
                "image_guided": bool(self.needs_frames),
                "guide": None if not self.needs_frames else "frame" if self.guide is None else
                {**self.guide.to_dict(), "threshold_trained": self.guide.threshold if self.trained_threshold is None
                 else self.trained_threshold},
                "window_us": "frame intervals" if self.frame_pairs else self.window_us,
                "event_times": self.times, "add_events": self.add_events,
                "delete_events": self.delete_events,
                "decision": {"rule": d.get("rule"), "threshold": d.get("threshold"),
                             "drops_unsupported": support_applies(d),
                             "support_val_precision": sup.get("val_precision")}}

    def _image(self, frame, height: int, width: int):
        from rdnet.deblur.pipeline import network_images
        from rdnet.events.recording import Frames
        ims = [np.asarray(f) for f in (frame if self.frame_pairs else (frame,))]
        for im in ims:
            if im.shape[:2] != (height, width):
                raise ValidationError("frame", f"frame size {im.shape[:2]} (H, W) != sensor {(height, width)}")
        n = len(ims)
        images = network_images(Frames(np.stack(ims), np.arange(n, dtype=np.int64), np.zeros(n, np.int64)),
                                self.net.image_channels - (1 if self.frame_pairs else 0))
        return self.guide.image(images[0], images[1])[None] if self.frame_pairs else images

    def _tensor(self, a: np.ndarray):
        import torch
        x = torch.from_numpy(a).to(self.device)
        return x.contiguous(memory_format=torch.channels_last) if self.channels_last else x

    def restore(self, events: Events, t0_us: int, t1_us: int, frame) -> Events:
        """Restored events of the window ``t0_us <= t < t1_us`` (``frame``: the window's
        image, (H, W) or (H, W, 3), uint8 or linear float32; required when
        ``needs_frames``, ignored otherwise; with :attr:`frame_pairs` the two frames at
        ``t0_us`` and ``t1_us`` as a pair, or None for a window no pair brackets, whose
        events are returned as they are)."""
        import torch
        from rdnet.nn.decision import sparse_decided_entries
        from rdnet.nn.sparse import SPARSE_MAX_DENSITY, SparseVoxels

        t0_us, t1_us = int(t0_us), int(t1_us)
        if t1_us <= t0_us:
            raise ValidationError("window", f"t1_us {t1_us} must be after t0_us {t0_us}")
        if self.needs_frames and frame is None and not self.frame_pairs:
            raise ValidationError("frame", f"{self.name} needs the frame of each window")
        H, W = events.height, events.width
        ev = events.slice_time(t0_us, t1_us)            # half-open: back-to-back windows share nothing
        if self.frame_pairs and frame is None:          # outside the frames: nothing to guide it
            return ev
        if self.frame_pairs and len(frame) != 2:
            raise ValidationError("frame", f"{self.name} needs the two frames bracketing each window")
        dur = t1_us - t0_us
        split = self.output == "counts"
        guided = bool(self.net.image_channels)
        # the decided entries of this very window, when another run on the recording has them
        key = None if self.memo is None or not split else \
            DecisionMemo.key(self.decision_fingerprint(), t0_us, t1_us, ev,
                             (np.stack(frame) if self.frame_pairs else frame) if guided else None)
        decided = None if key is None else self.memo.get(key)
        if decided is None:
            if split:    # the non-zero voxels; the dense grid only for a dense window (rdnet.nn.sparse)
                index, values, shape = voxel_entries(ev, self.bins, t0_us, dur, mode=self.mode, polarity="split")
                x = SparseVoxels.of(index, values, shape, self.channels_last)
                if x.density > SPARSE_MAX_DENSITY:
                    x = x.dense(self.device)
            else:
                grid = voxel_grid(ev, self.bins, t0_us, dur, mode=self.mode, polarity="signed")
                x = self._tensor(grid.reshape(1, -1, H, W))
            img = self._tensor(self._image(frame, H, W)) if guided else None
        own_times = self.times == "input"
        entries = own_times or not self.add_events or not self.delete_events
        with torch.inference_mode():
            if split:
                if decided is None:
                    decided = sparse_decided_entries(self.net, img, x, self.decision)
                    if key is not None:
                        self.memo.put(key, decided)
                index, counts = decided
                shape = (2, self.bins, H, W)
            else:
                out = self.net(img, x)[0].contiguous().cpu().numpy()
                if entries:
                    index, counts, shape = signed_entries(out)
        if not self.add_events:
            index, counts = capped_entries(ev, index, counts, shape, t0_us, dur)
        if not self.delete_events:
            index, counts = floored_entries(ev, index, counts, shape, t0_us, dur)
        if own_times:
            restored = select_events(ev, index, counts, shape, t0_us, dur)
        elif split or entries:
            restored = entry_events(index, counts, shape, t0_us, dur, mode=self.mode)
        else:
            restored = voxel_events(out, t0_us, dur, mode=self.mode)
        # an event at exactly t1 (last bin closed on the right) belongs to the next window
        return restored.slice_time(t0_us, t1_us) if len(restored) and restored.t[-1] >= t1_us else restored


def _fail(path: Path, field: str, msg: str) -> ConfigError:
    return ConfigError("checkpoint", f"{path}: {field}: {msg}")


def restorer_from_checkpoint(path: str | Path, *, has_frames: bool, params: Mapping | None = None,
                             device: str = "cpu", source: str | None = None,
                             event_times: str = "input", add_events: bool = True,
                             delete_events: bool = True, guide_threshold: float | None = None) -> LearnedRestorer:
    """A :class:`LearnedRestorer` from one checkpoint file, validated (module docstring).
    ``event_times``: ``restore.event_times`` (input or bins); ``add_events``,
    ``delete_events``: ``restore.add_events``, ``restore.delete_events``;
    ``guide_threshold``: ``restore.guide_threshold`` (a frame-pair network's guide divides
    by it instead of the threshold it was trained with; other networks ignore it)."""
    from rdnet.restore.settings import EVENT_TIMES
    if event_times not in EVENT_TIMES:
        raise ConfigError("restore.event_times", f"must be one of {list(EVENT_TIMES)}, got {event_times!r}")
    from rdnet.nn.decision import read_decision
    from rdnet.runtime import keep_freed_memory
    from rdnet.train import checkpoint as ckpt_mod

    keep_freed_memory()      # full-frame activations reused, not mmapped afresh per window

    path = Path(path)
    try:
        ck = ckpt_mod.read_checkpoint(path)
    except FormatError as e:
        raise ConfigError("checkpoint", str(e)) from None
    if ck["model_kind"] != "restore":
        raise _fail(path, "model_kind", f"holds a {ck['model_kind']!r} model ({ck['task']}); "
                    "a restorer is a 'restore' checkpoint (task restore, restore_events or restore_frames)")
    args, extra = ck["model_args"], ck.get("extra", {})
    bins = int(args.get("bins", 0))
    voxel = extra.get("voxel") or {}
    want = (params or {}).get("voxel", {}) if isinstance(params, Mapping) else {}
    if want.get("bins") is not None and int(want["bins"]) != bins:
        raise _fail(path, "model_args.bins", f"the network reads {bins} voxel bins, params voxel.bins is {want['bins']}")
    if voxel.get("normalize"):
        raise _fail(path, "extra.voxel.normalize", f"trained on {voxel['normalize']!r}-normalised voxels; "
                    "restorers read raw counts")
    image_channels = int(args.get("image_channels", 1))
    if image_channels and not has_frames:
        raise _fail(path, "model_args.image_channels", "an image-guided restorer needs frames and the "
                    "recording has none: use an events-only restorer (task restore_events)")
    try:
        net = ckpt_mod.model_from_checkpoint(path, ck, device)
    except FormatError as e:
        raise ConfigError("checkpoint", str(e)) from None
    channels_last = prepare_for_inference(net, device)
    try:
        decision = read_decision(extra.get("decision"), net.output)   # an unknown support rule too
    except ValidationError as e:
        raise _fail(path, "extra.decision", str(e)) from None
    from rdnet.nn.guide import FramePairGuide
    try:
        guide = FramePairGuide.from_dict(extra.get("guide"))
    except ValidationError as e:
        raise _fail(path, "extra.guide", str(e)) from None
    name = "rdnet-events" if not image_channels else "rdnet-image" if guide is None else "rdnet-frames"
    trained_threshold = None
    if guide is not None and guide_threshold is not None and float(guide_threshold) != guide.threshold:
        trained_threshold = guide.threshold
        guide = dataclasses.replace(guide, threshold=float(guide_threshold))
        log.info("%s: the frame-pair guide divides by the camera's threshold %g (restore.guide_threshold), "
                 "not the %g it was trained with", path, guide.threshold, trained_threshold)
    mode = str(voxel.get("mode") or "hard")
    for key, on, what in (("add_events", add_events, "caps each voxel at"),
                          ("delete_events", delete_events, "raises each voxel to at least")):
        if not on and mode != "hard":
            raise _fail(path, "extra.voxel.mode", f"restore.{key}: false {what} its input events, which "
                        f"needs hard voxel bins; the network reads {mode!r} voxels")
    if times_used(event_times, mode) != event_times:
        log.info("%s: restore.event_times=input keeps the recorded timestamps of hard-binned voxels; "
                 "this network reads %r voxels, so its events are spread over the bins", path, mode)
    window = extra.get("window_us")
    return LearnedRestorer(name=name, needs_frames=bool(image_channels),
                           window_us=None if window is None else int(window), net=net, decision=decision,
                           bins=bins, mode=mode, source=source or str(path),
                           device=str(device), channels_last=channels_last, event_times=event_times,
                           add_events=bool(add_events), delete_events=bool(delete_events), guide=guide,
                           trained_threshold=trained_threshold)


def load_restorer(checkpoint: str | Path | None, *, has_frames: bool, params: Mapping,
                  device: str = "cpu", event_times: str = "input", add_events: bool = True,
                  delete_events: bool = True, guide: str = "auto",
                  guide_threshold: float | None = None) -> LearnedRestorer:
    """The learned restorer to use (module docstring for the search order). ``device``: cpu,
    cuda or auto (cuda when available); ``event_times``, ``add_events``, ``delete_events``,
    ``guide``, ``guide_threshold``: ``restore.event_times``, ``restore.add_events``,
    ``restore.delete_events``, ``restore.guide`` (which study or packaged restorer a
    recording with frames gets, ``auto``: the frame-pair one when ``guide_threshold`` is
    given; a ``checkpoint`` brings its own guide), ``restore.guide_threshold``."""
    kw = {"event_times": event_times, "add_events": add_events, "delete_events": delete_events,
          "guide_threshold": guide_threshold}
    from rdnet.train.loop import resolve_device
    device = str(resolve_device(str(device), key="restore.device"))
    if checkpoint is not None:
        path = Path(checkpoint)
        f = _checkpoint_file(path)
        if f is None:
            raise ConfigError("checkpoint", f"{path}: no model.pt (nor seed<k>/model.pt) found")
        r = restorer_from_checkpoint(f, has_frames=has_frames, params=params, device=device, **kw)
        log.info("restorer %s from %s", r.name, f)
        return r
    if guide not in ("auto",) + KINDS[:2]:
        raise ConfigError("restore.guide", f"must be one of {['auto', *KINDS[:2]]}, got {guide!r}")
    if guide == "auto":        # the frame-pair guide needs the camera's threshold to count its events
        guide = "frame_pair" if guide_threshold is not None else "frame"
        if has_frames:
            log.info("restore.guide auto: %s (%s)", guide, "the camera's threshold is known (restore.guide_threshold)"
                     if guide_threshold is not None else "no camera threshold: restore.guide_threshold unset")
    # the guided restorer asked for when the recording has frames; events-only otherwise (or as fallback)
    kinds = (guide, "events") if has_frames else ("events",)
    for kind in kinds:
        f = _checkpoint_file(STUDY_MODELS[kind]) if STUDY_MODELS[kind].exists() else None
        if f is not None:
            r = restorer_from_checkpoint(f, has_frames=has_frames, params=params, device=device,
                                         source=f"study model {f}", **kw)
            log.info("restorer %s: the study's trained model %s", r.name, f)
            return r
    for kind in kinds:
        f = _package_file(PACKAGE_MODELS[kind])
        if f is not None:
            r = restorer_from_checkpoint(f, has_frames=has_frames, params=params, device=device,
                                         source=f"package model {PACKAGE_MODELS[kind]}", **kw)
            log.info("restorer %s: the packaged model %s (no study model under %s)", r.name, f,
                     STUDY_MODELS[kind].parent)
            return r
    raise ModelNotFoundError("checkpoint", "no trained restorer: give --checkpoint, run `dvc repro` "
                      f"(writes {STUDY_MODELS[kinds[0]]}) or install rdnet with its packaged models")


def export_restorer(checkpoint: str | Path, out_dir: str | Path, *, kind: str,
                    metrics: Mapping | None = None) -> Path:
    """Copy a trained restorer of ``kind`` (:data:`KINDS`) to ``out_dir/<name>.pt``
    (``name`` from :data:`PACKAGE_MODELS`, e.g. the package folder ``rdnet/restore/models``)
    with ``<name>.json``: its model arguments, training config, decision and ``metrics``.
    The checkpoint is validated first (:func:`restorer_from_checkpoint`; a checkpoint of
    another kind is a ConfigError); both files are written atomically."""
    import json
    import shutil

    from rdnet.eval.report import write_text_atomic
    from rdnet.events.io._common import atomic_output
    from rdnet.train import checkpoint as ckpt_mod

    src = _checkpoint_file(Path(checkpoint))
    if src is None:
        raise ConfigError("checkpoint", f"{checkpoint}: no model.pt (nor seed<k>/model.pt) found")
    if kind not in KINDS:
        raise ConfigError("kind", f"must be one of {list(KINDS)}, got {kind!r}")
    r = restorer_from_checkpoint(src, has_frames=True)
    have = "events" if not r.needs_frames else "frame_pair" if r.frame_pairs else "frame"
    if have != kind:
        raise _fail(src, "model_args.image_channels" if "events" in (have, kind) else "extra.guide",
                    f"is a {have!r} restorer ({r.name}), exported as the {kind!r} one")
    ck = ckpt_mod.read_checkpoint(src)
    name = PACKAGE_MODELS[kind]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_output(out_dir / f"{name}.pt") as tmp:
        shutil.copyfile(src, tmp)
    card = {"name": r.name, "source": str(src), "task": ck["task"], "step": ck.get("step"),
            "model_args": ck["model_args"], "train": ck["config"], "decision": r.decision,
            "window_us": r.window_us, "voxel": ck.get("extra", {}).get("voxel"),
            "metrics": dict(metrics or {})}
    write_text_atomic(out_dir / f"{name}.json", json.dumps(card, indent=2, sort_keys=True, default=str) + "\n")
    return out_dir / f"{name}.pt"
