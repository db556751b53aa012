"""``rdnet restore``: restore a recording's events, streamed in time windows.

Writes OUT.h5 (the restored events in the project's HDF5 layout, the frames copied when
the recording has them) and OUT.json beside it (OUT with suffix ``.json``):

* ``input``, ``format``, ``width``, ``height``, ``has_frames``, ``duration_us``,
* ``method`` (the restorer's name, e.g. ``baf`` or ``rdnet-events``) and ``model``
  (what the restorer reports about itself: filter parameters, or the checkpoint path,
  kind, training config and metrics of a learned one),
* ``events_in``, ``events_out``, ``kept_fraction``, ``events_not_recorded`` (output events
  that are not events of the recording, as the restorer got them: time, pixel and polarity
  compared, :func:`rdnet.events.select.shared_count`; a filter's are 0, a learned
  restorer's are the events it adds or moves), ``windows``, ``window_us`` (``"frame
  intervals"`` for a frame-pair restorer, whose windows run from frame to frame),
  ``events_outside_frame_pairs`` (a frame-pair restorer: events before the first frame or
  after the last, passed on unrestored, hot pixels still dropped; else null), ``workers``
  (windows restored at once: ``restore.workers``),
  ``seconds`` (wall time of the restore loop, after reading), ``cpu_seconds`` (its CPU
  time), ``events_per_s`` (input events per second of wall time),
  ``realtime_factor`` (recording duration / wall time),
* ``scores``: no-reference scores of the raw and the restored stream: ``esr``
  (:func:`rdnet.eval.noref.esr_score`, higher = more structured) and, with frames,
  ``consistency`` (:mod:`rdnet.deblur.consistency`: event-frame consistency, higher is
  better; null with a note when the raw stream has more than ``score_max_events``), both
  computed window by window in the restore loop (the consistency holds count images only
  for the frame intervals in progress:
  :class:`~rdnet.deblur.consistency.ConsistencyAccumulator`),
* ``hot_pixels``: the pixels the hot-pixel pass flagged (:mod:`rdnet.restore.hotpixels`;
  every method but raw): ``factor``, ``min_rate_hz``, ``count``, ``pixels`` ([x, y], the
  first 1,000), ``events_dropped`` and ``polarity`` (their ON share and the simulator's
  ``degrade.hot_pixel_on_fraction`` / ``hot_pixel_polarity_concentration`` fitted to them:
  :func:`rdnet.restore.hotpixels.polarity_model`),
* ``latency_dropped``: events before the first one ``restore.latency_us`` keeps (counted in
  ``events_in``, not scored),
* ``settings``: the ``restore`` section used (``latency_us``: subtracted from every event
  timestamp before anything else; the output's timestamps are the corrected ones, the raw
  scores are those of the stream as recorded).

Both files are written atomically: on any error neither exists afterwards (an older
OUT.h5/OUT.json is left untouched).
"""
from __future__ import annotations

import contextlib
import json
import logging
import time
from pathlib import Path
from typing import Mapping

import numpy as np

from rdnet.config import section, to_dict
from rdnet.errors import ConfigError, FormatError
from rdnet.events.core import Events, concatenate
from rdnet.events.select import shared_count
from rdnet.restore.base import get_restorer
from rdnet.restore.stream import ordered_map, windows

log = logging.getLogger(__name__)


def json_path_for(out: str | Path) -> Path:
    return Path(out).with_suffix(".json")


def nearest_frame(frames, t_mid_us: int, grey: np.ndarray | None = None) -> np.ndarray | None:
    """The grey linear frame whose mid-exposure time is nearest ``t_mid_us``."""
    if frames is None:
        return None
    i = int(np.argmin(np.abs(frames.t_us - int(t_mid_us))))
    return (grey if grey is not None else frames.grey())[i]


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def shifted(chunks, latency_us: float, dropped: list | None = None):
    """Event chunks with ``round(latency_us)`` subtracted from every timestamp (a constant
    sensor latency undone; the order does not change), dropping those that would fall
    before 0 (their number is appended to ``dropped`` per chunk); the chunks unchanged
    when it is 0."""
    shift = int(round(latency_us))
    for ev in chunks:
        if shift == 0 or len(ev) == 0:
            yield ev
            continue
        arr = ev.array[ev.t >= shift]          # a copy: the caller's events are not changed
        arr["t"] -= shift
        if dropped is not None:
            dropped.append(len(ev) - len(arr))
        yield Events(arr, ev.width, ev.height, validate=False)


def _windows_after_shift(chunks, latency_us: float, early: list, window_us: int, recording: Path, cuts=None):
    """:func:`rdnet.restore.stream.windows` of the shifted chunks (``cuts``: window ends,
    as there); a ConfigError naming ``restore.latency_us`` when the shift leaves no event
    of a recording that has some."""
    try:
        yield from windows(shifted(chunks, latency_us, early), window_us, path=recording, cuts=cuts)
    except FormatError as e:
        if sum(early) and e.field == "events":
            raise ConfigError("restore.latency_us", f"{int(round(latency_us))} us is longer than the "
                              f"{sum(early)} events of {recording} span: none is left") from None
        raise e


#: ``rdnet restore`` notes (OUT.json ``notes``, a logged warning) an output of more than this
#: many times the recorded events: the learned restorers trained without identity pairs
#: doubled clean and dense streams (docs/restoration.md, "A stream that needs no restoring").
MANY_ADDED = 1.5


def restore_recording(recording: str | Path, out: str | Path, params: Mapping, *, method: str | None = None,
                      checkpoint: str | Path | None = None, progress: bool = True,
                      sensor_size: tuple[int, int] | None = None, memo=None) -> dict:
    """Run ``rdnet restore`` (module docstring); returns the OUT.json content.
    ``sensor_size`` (width, height): for formats that do not store it (text). ``memo``: a
    :class:`rdnet.restore.learned.DecisionMemo` shared by runs of the same learned restorer
    on this recording that differ only after its decision (``restore.add_events``,
    ``restore.delete_events``); other restorers ignore it."""
    from tqdm import tqdm

    from rdnet.events.io._common import atomic_output
    from rdnet.events.io.hdf5 import H5RecordingWriter
    from rdnet.eval.noref import EsrAccumulator

    cfg = section(params, "restore")
    method = method or cfg.method
    recording, out = Path(recording), Path(out)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise FormatError(out, None, "output must be an HDF5 file (.h5)")
    if out.resolve() == recording.resolve():
        raise FormatError(out, None, "output would overwrite the input recording")
    from rdnet.events.io.stream import open_events
    with open_events(recording, sensor_size=sensor_size) as src:
        frames = src.frames()
        has_frames = frames is not None and len(frames) > 0
        restorer = get_restorer(method, params, checkpoint, has_frames=has_frames)
        share = getattr(restorer, "share_decisions", None)      # optional (rdnet.restore.base.Restorer)
        if memo is not None and share is not None:
            share(memo)
        if restorer.needs_frames and not has_frames:
            raise FormatError(recording, "frames", f"method {restorer.name} needs frames; the recording has none")
        window_us = int(restorer.window_us or cfg.window_us)
        hot = None
        if method != "raw" and cfg.hot_pixel_factor > 0:
            from rdnet.restore.hotpixels import drop_pixels, hot_pixels, polarity_counts, polarity_model
            counts, on_counts, dur = polarity_counts(shifted(src.chunks(cfg.chunk_events), cfg.latency_us),
                                                     src.width, src.height)
            hot = hot_pixels(counts, dur, cfg.hot_pixel_factor, cfg.hot_pixel_min_hz)
            hot_polarity = polarity_model(counts, on_counts, hot)
            log.info("hot-pixel pass: %d pixels flagged (factor %g, min %g Hz)", int(hot.sum()),
                     cfg.hot_pixel_factor, cfg.hot_pixel_min_hz)
        n_hot = 0
        shift = int(round(cfg.latency_us))
        grey = frames.grey() if has_frames else None
        esr_raw = EsrAccumulator(src.width, src.height, cfg.esr_interval_us)
        esr_out = EsrAccumulator(src.width, src.height, cfg.esr_interval_us)
        consistency = None                          # the event-frame consistency, streamed
        if has_frames and cfg.scores:
            from rdnet.deblur.consistency import ConsistencyAccumulator
            sensor = section(params, "sensor")
            consistency = ConsistencyAccumulator(frames, ("raw", "restored"), sensor.threshold_on,
                                                 sensor.threshold_off, sensor.log_eps, grey=grey)
        # a frame-pair restorer: windows from frame to frame, each with its two frames
        pairs = has_frames and getattr(restorer, "frame_pairs", False)
        cuts = frames.t_us.astype(np.int64) if pairs else None
        frame_at = {int(t): k for k, t in enumerate(frames.t_us)} if pairs else {}
        n_in = n_out = n_win = n_pending = n_shared = n_unpaired = 0
        pending: list[Events] = []
        t_first = t_last = None
        total = getattr(src, "n_events", None)
        start, cpu_start = time.perf_counter(), time.process_time()
        with atomic_output(json_path_for(out)) as json_tmp, \
                H5RecordingWriter(out, src.width, src.height, getattr(src, "sensor", "") or "",
                                  frame_compression=cfg.frame_compression) as writer, \
                tqdm(total=total, desc=f"restore {restorer.name}", unit="ev", unit_scale=True,
                     disable=(not progress) or None) as bar:
            early: list[int] = []                   # events before the first one the shift keeps

            def windows_to_restore():
                # (t0, t1, events as read, events handed to the restorer, frame), in order
                for t0, t1, ev in _windows_after_shift(src.chunks(cfg.chunk_events), cfg.latency_us, early,
                                                       window_us, recording, cuts):
                    if pairs:      # None outside the frames: the events pass as they are
                        k = frame_at.get(t0)
                        frame = (grey[k], grey[k + 1]) if k is not None and frame_at.get(t1) == k + 1 else None
                    else:
                        frame = nearest_frame(frames, (t0 + t1) // 2, grey) if has_frames else None
                    yield t0, t1, ev, ev if hot is None else drop_pixels(ev, hot), frame

            # a learned restorer on the CPU takes several windows at once (restore.workers);
            # everything else here runs in this thread, window by window in order
            parallel = getattr(restorer, "parallel", None)      # optional (rdnet.restore.base.Restorer)
            at_once = contextlib.nullcontext(1) if parallel is None else parallel(cfg.workers, src.width * src.height)
            with at_once as workers:
                restored = ordered_map(lambda w: restorer.restore(w[3], w[0], w[1], w[4]),
                                       windows_to_restore(), workers)
                for (t0, t1, ev, kept, frame), res in restored:
                    n_hot += len(ev) - len(kept)
                    n_unpaired += len(ev) if pairs and frame is None else 0
                    n_shared += shared_count(res, kept)
                    pending.append(res)
                    n_pending += len(res)
                    if n_pending >= cfg.chunk_events:          # few large HDF5 appends, memory bounded
                        writer.append_events(concatenate(pending))
                        pending, n_pending = [], 0
                    recorded = ev
                    if shift:                                   # the raw scores: the stream as recorded
                        arr = ev.array.copy()
                        arr["t"] += shift
                        recorded = Events(arr, ev.width, ev.height, validate=False)
                    if cfg.scores:
                        esr_raw.add(recorded)
                        esr_out.add(res)
                    if consistency is not None:
                        if n_in + len(ev) > cfg.score_max_events:
                            consistency = None
                        else:                                   # every event before the window's end given
                            consistency.add("raw", recorded, t1 + shift)
                            consistency.add("restored", res, t1)
                    if len(ev):
                        t_first = int(ev.t[0]) if t_first is None else t_first
                        t_last = int(ev.t[-1])
                    n_in += len(ev)
                    n_out += len(res)
                    n_win += 1
                    bar.update(len(ev))
            n_in += sum(early)
            if pending:
                writer.append_events(concatenate(pending))
            if has_frames:
                writer.write_frames(frames)
            seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
            writer.set_attr("restore_method", restorer.name)
            duration = (t_last - t_first) if t_first is not None else 0
            scores = {"esr": {"raw": esr_raw.score(), "restored": esr_out.score(),
                              "interval_us": cfg.esr_interval_us} if cfg.scores else None,
                      "consistency": None}
            notes = [] if cfg.scores else ["no-reference scores off (restore.scores=false)"]
            if n_in and n_out > MANY_ADDED * n_in:
                note = (f"the restored stream holds {n_out / n_in:.2f}x the recorded events: {restorer.name} "
                        f"added events where it judged them lost; on a stream that lost few (a clean sensor, "
                        f"dense activity) that is invention: compare with --method baf")
                notes.append(note)
                log.warning("%s", note)
            if pairs and n_unpaired:
                notes.append(f"{n_unpaired} events before the first frame or after the last one passed "
                             f"unrestored (hot pixels still dropped): {restorer.name} restores the intervals "
                             f"between frames")
            if consistency is not None:
                scores["consistency"] = consistency.scores()
            elif has_frames and cfg.scores:
                notes.append(f"event-frame consistency not scored: more than {cfg.score_max_events} raw events")
            result = {
                "input": str(recording), "output": str(out), "format": src.format,
                "width": src.width, "height": src.height, "has_frames": has_frames,
                "method": restorer.name, "model": getattr(restorer, "info", {}),
                "checkpoint": None if checkpoint is None else str(checkpoint),
                "events_in": n_in, "events_out": n_out,
                "kept_fraction": n_out / n_in if n_in else None,
                "events_not_recorded": n_out - n_shared,
                "latency_dropped": sum(early),
                "windows": n_win, "window_us": "frame intervals" if pairs else window_us, "workers": workers,
                "events_outside_frame_pairs": n_unpaired if pairs else None, "duration_us": duration,
                "seconds": seconds, "cpu_seconds": cpu_seconds, "events_per_s": n_in / seconds if seconds > 0 else None,
                "realtime_factor": (duration * 1e-6) / seconds if seconds > 0 else None,
                "scores": scores, "notes": notes,
                "hot_pixels": None if hot is None else {
                    "factor": cfg.hot_pixel_factor, "min_rate_hz": cfg.hot_pixel_min_hz, "count": int(hot.sum()),
                    "pixels": [[int(x), int(y)] for y, x in zip(*np.nonzero(hot))][:1000],
                    "events_dropped": n_hot, "polarity": hot_polarity},
                "settings": {**to_dict(cfg), "method": method}}
            result = _jsonable(result)
            json_tmp.write_text(json.dumps(result, indent=2) + "\n")
    log.info("restored %d -> %d events with %s", n_in, n_out, restorer.name)
    return result
