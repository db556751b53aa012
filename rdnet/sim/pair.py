"""Simulate events from frames: one sensor (:func:`simulate`) or the undegraded/degraded
pair from the same frames in one pass (:func:`simulate_pair`), as RDNet trains its
restoration stage on (degraded, ideal) event pairs of the same scene.

Frames are taken as linear intensity; colour frames become luminance (ITU-R BT.601, as
:meth:`Frames.grey`). With ``interpolate`` (an :class:`rdnet.sim.interpolate.InterpolateConfig`)
the frames are first upsampled adaptively (vid2e-style) so the log intensity moves little
between steps. Everything streams chunk by chunk (:func:`frame_chunks`,
:func:`stream_events`), so the whole upsampled video is never in memory.
"""
from __future__ import annotations

import logging
from typing import Iterable, Iterator, Sequence

import numpy as np
from tqdm.auto import tqdm

from rdnet.errors import ValidationError
from rdnet.events.core import Events, concatenate
from rdnet.events.recording import Frames
from rdnet.sim.sensor import Sensor
from rdnet.sim.settings import DegradeConfig, SensorConfig

log = logging.getLogger(__name__)

#: Default number of simulation steps per chunk.
DEFAULT_CHUNK = 64


def as_frames(frames: Frames | np.ndarray, t_us: np.ndarray | None = None) -> Frames:
    """``frames`` as validated :class:`Frames` (arrays: (N, H, W[, 3]) float32 linear or
    uint8 with ``t_us`` (N,) int64 strictly increasing; NaN, negative values, wrong shapes
    and non-increasing times raise :class:`ValidationError`)."""
    if isinstance(frames, Frames):
        if t_us is not None and not np.array_equal(np.asarray(t_us), frames.t_us):
            raise ValidationError("t_us", "differs from the timestamps of the Frames given")
        return frames
    if t_us is None:
        raise ValidationError("t_us", "timestamps are required with an image array")
    images = np.asarray(frames)
    if images.ndim not in (3, 4):
        raise ValidationError("frames/images", f"expected (N,H,W) or (N,H,W,3), got shape {images.shape}")
    return Frames(images, np.asarray(t_us), np.zeros(images.shape[0], np.int64))


def _grey(images: np.ndarray) -> np.ndarray:
    """Float32 linear luminance (K, H, W) of a chunk (uint8 / 255; colour -> BT.601 luma)."""
    return Frames(images, np.arange(images.shape[0], dtype=np.int64), 0).grey()


def upsample_stream(parts: Iterable[Frames], interpolate, log_eps: float, stats=None, *,
                    with_log: bool = False) -> Iterator[tuple]:
    """Upsample a stream of consecutive Frames chunks (linear intensity): yields
    ``(images, t_us)`` pieces, the same frames as :func:`rdnet.sim.interpolate.upsample`
    on the whole sequence, carrying the last frame across chunk borders, so only a chunk
    is ever in memory. One warning at the end if the log-step bound was exceeded;
    ``stats`` (an UpsampleStats) collects what the upsampling achieved; ``with_log``:
    ``(images, t_us, log or None)`` as :func:`rdnet.sim.interpolate.upsample` gives."""
    from rdnet.sim.interpolate import UpsampleStats, fit_to_size, upsample, warn_if_over

    here = UpsampleStats()
    sts = [here] if stats is None else [here, stats]
    prev_im = prev_t = None
    for fr in parts:
        if len(fr) == 0:
            continue
        ims, ts = fr.images, fr.t_us
        if prev_im is None:
            interpolate = fit_to_size(interpolate, ims.shape[1:])   # warns once for small frames
        else:
            ims = np.concatenate([prev_im, ims])
            ts = np.concatenate([prev_t, ts])
        first = True
        part = UpsampleStats()
        for piece in upsample(ims, ts, interpolate, log_eps, stats=part, warn=False, with_log=with_log):
            if first and prev_im is not None:
                piece = tuple(None if a is None else a[1:] for a in piece)
            first = False
            if piece[1].size:
                yield piece
        for st in sts:
            st.merge(part)
        prev_im, prev_t = fr.images[-1:], fr.t_us[-1:]
    warn_if_over(here, interpolate)


def frame_chunks(frames: Frames | np.ndarray | Iterable[Frames], t_us: np.ndarray | None = None, *,
                 interpolate=None, log_eps: float = 0.01, chunk: int = DEFAULT_CHUNK, stats=None,
                 with_log: bool = False) -> Iterator[tuple]:
    """Simulation steps in chunks: ``(grey float32 (K, H, W), t_us (K,))`` with K <= ``chunk``
    (a little more after upsampling), from Frames, an image array with ``t_us``, or an
    iterable of consecutive Frames chunks (e.g. :func:`rdnet.sim.sources.iter_frames`).
    ``interpolate``: InterpolateConfig (None or method 'none': frames used as given);
    ``stats``: an :class:`rdnet.sim.interpolate.UpsampleStats` that collects what the
    upsampling achieved (filled once the iterator is exhausted). ``with_log``: yield
    ``(grey, t_us, log_grey)`` with ``log_grey = log(grey + log_eps)`` (float32, bit for
    bit what :meth:`Sensor.step` computes; pass it as ``log_frames``) when the upsampling
    statistics computed it anyway (grey frames, nothing inserted, the interpolation's
    ``log_eps`` the sensor's), else None."""
    if chunk < 1:
        raise ValidationError("chunk", f"must be >= 1, got {chunk}")
    if isinstance(frames, (Frames, np.ndarray)):
        parts: Iterable[Frames] = [as_frames(frames, t_us)]
    else:
        if t_us is not None:
            raise ValidationError("t_us", "not used with an iterable of Frames")
        parts = frames
    if interpolate is not None and getattr(interpolate, "method", "none") != "none":
        own_eps = getattr(interpolate, "log_eps", None)
        share = with_log and (own_eps is None or float(own_eps) == float(log_eps))
        src: Iterable[tuple] = upsample_stream(parts, interpolate, log_eps, stats, with_log=share)
    else:
        src = ((fr.images[i:i + chunk], fr.t_us[i:i + chunk])
               for fr in parts for i in range(0, len(fr), chunk))
    buf_im: list[np.ndarray] = []
    buf_t: list[np.ndarray] = []
    buf_log: list[np.ndarray | None] = []
    n = 0

    def joined():
        out = np.concatenate(buf_im), np.concatenate(buf_t)
        if not with_log:
            return out
        has = all(lg is not None for lg in buf_log)
        return out + ((np.concatenate(buf_log) if has else None),)

    for piece in src:
        im, t = piece[0], piece[1]
        buf_im.append(_grey(im))
        buf_t.append(np.asarray(t, np.int64))
        # a log is only valid for grey frames (then _grey returns them unchanged)
        buf_log.append(piece[2] if len(piece) > 2 and im.ndim == 3 else None)
        n += len(t)
        if n >= chunk:
            yield joined()
            buf_im, buf_t, buf_log, n = [], [], [], 0
    if n:
        yield joined()


class _Done:
    """End marker of :func:`prefetch` (the producer finished or raised ``error``)."""

    def __init__(self, error: BaseException | None = None):
        self.error = error


def prefetch(items: Iterable, depth: int = 2) -> Iterator:
    """Iterate ``items`` in a background thread, at most ``depth`` items ahead: the
    producer (frame reading and decompression, log conversion, statistics, optical flow;
    numpy, h5py and OpenCV release the GIL in their large operations) overlaps the
    consumer's work (the sensor kernel, which runs without the GIL). Same items, same
    order; an exception in the producer is raised in the consumer at that item. Closing
    the returned generator early (or an exception in the consumer) stops the producer
    at its next item and joins it, so no thread outlives the loop. The producer must not
    share mutable state with the consumer (e.g. a random generator)."""
    import queue
    import threading

    if depth < 1:
        raise ValidationError("depth", f"must be >= 1, got {depth}")
    q: "queue.Queue" = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    it = iter(items)

    def work() -> None:
        try:
            for item in it:
                if not put(item):
                    return
        except BaseException as e:   # handed to the consumer
            put(_Done(e))
            return
        finally:
            close = getattr(it, "close", None)
            if close is not None:   # a generator's cleanup runs in the thread that ran it
                close()
        put(_Done())

    th = threading.Thread(target=work, name="rdnet-prefetch", daemon=True)
    th.start()
    try:
        while True:
            item = q.get()
            if isinstance(item, _Done):
                if item.error is not None:
                    raise item.error
                return
            yield item
    finally:
        stop.set()
        th.join()


def stream_events(chunks: Iterable[tuple[np.ndarray, np.ndarray]], sensors: Sequence[Sensor], *,
                  progress: bool = False, total: int | None = None) -> Iterator[list[Events]]:
    """Feed every chunk to every sensor; yield, per chunk and at the end (flush), the list
    of each sensor's new events (time-sorted, consecutive across yields). A chunk is
    ``(images, t_us)`` or ``(images, t_us, log_frames or None)`` (:func:`frame_chunks`
    with ``with_log``)."""
    bar = tqdm(total=total, unit="step", desc="simulate", disable=None if progress else True)
    try:
        for images, t, *rest in chunks:
            lg = rest[0] if rest else None
            out = [s.step(images, t, log_frames=lg) for s in sensors]
            bar.update(len(t))
            yield out
        yield [s.flush() for s in sensors]
    finally:
        bar.close()


def _run(frames, t_us, sensors_of, *, interpolate, chunk, progress) -> list[Events]:
    fr = as_frames(frames, t_us)
    sensors = sensors_of(fr.width, fr.height)
    chunks = frame_chunks(fr, interpolate=interpolate, log_eps=sensors[0].sensor.log_eps, chunk=chunk)
    parts: list[list[Events]] = [[] for _ in sensors]
    for evs in stream_events(chunks, sensors, progress=progress):
        for acc, ev in zip(parts, evs):
            acc.append(ev)
    return [concatenate(p) for p in parts]


def simulate(frames: Frames | np.ndarray, t_us: np.ndarray | None = None,
             sensor: SensorConfig = SensorConfig(), degrade: DegradeConfig | None = None,
             rng: np.random.Generator | None = None, *, interpolate=None, chunk: int = DEFAULT_CHUNK,
             progress: bool = False) -> Events:
    """Events of one simulated sensor (ideal when ``degrade`` is None or all effects are
    off). ``frames``: Frames or (N, H, W[, 3]) float32 linear / uint8 with ``t_us``.
    ``rng`` is required for random degradations; same seed -> bit-identical events."""
    return _run(frames, t_us, lambda w, h: [Sensor(w, h, sensor, degrade, rng)],
                interpolate=interpolate, chunk=chunk, progress=progress)[0]


def simulate_pair(frames: Frames | np.ndarray, t_us: np.ndarray | None = None,
                  sensor: SensorConfig = SensorConfig(), degrade: DegradeConfig | None = None,
                  rng: np.random.Generator | None = None, *, interpolate=None,
                  chunk: int = DEFAULT_CHUNK, progress: bool = False) -> tuple[Events, Events]:
    """``(undegraded, degraded)`` events of the same frames, simulated in one pass (the
    frames are read/upsampled once and fed to both sensors chunk by chunk)."""
    ideal, deg = _run(frames, t_us,
                      lambda w, h: [Sensor(w, h, sensor, None), Sensor(w, h, sensor, degrade, rng)],
                      interpolate=interpolate, chunk=chunk, progress=progress)
    return ideal, deg
