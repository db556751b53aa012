"""``rdnet simulate INPUT OUTPUT``: simulate events from frames.

INPUT is any frame source of :mod:`rdnet.sim.sources` (HDF5 recording with frames, a
video, a folder of images); OUTPUT is an HDF5 recording (project layout) holding the
input frames and the simulated events: degraded (``degrade`` section) by default,
undegraded with ``--ideal``; ``--pair`` writes both (degraded in /events, undegraded in
/events_ideal). ``--split train|test`` draws the degradation of this sequence from the
``randomize`` ranges. The values used are stored in the root attribute ``degrade_json``.
Frames and events are streamed chunk by chunk (bounded memory); the output is written
to a temporary file and moved into place only on success. Frames are stored as the
source holds them (uint8 HDF5 frames stay uint8; video and image frames as float32
linear), or not at all with ``--no-frames``. ``--compression auto`` (the default) copies
the frames of an HDF5 INPUT as stored, compressed chunks and all, without decoding and
re-encoding them, and compresses everything else with LZF; ``lzf``, ``gzip`` or ``none``
(re)encode frames and events alike; frames and events are written from a background thread, and the
frames are read (and upsampled) one or two chunks ahead in another, so the sensor
kernels run on one numba thread fewer than the cores.

The params come from ``--params``, else ./params.yaml when present (the study's: every
degradation on), else built-in defaults (every degradation off); the log names the
source and the effective ``sensor``/``degrade``/``interpolate`` values, and the output
stores them in the root attributes ``params_source``, ``sensor_json``, ``degrade_json``
and ``interpolate_json``.
"""
from __future__ import annotations

import contextlib
import json
import logging
from pathlib import Path

from rdnet.config import add_params_args, load_cli_params, params_source, seed_arg

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("simulate", help="simulate (degraded) events from frames",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("input", type=Path, help="frame source: .h5 recording with frames, video file, image folder")
    p.add_argument("output", type=Path, help="output HDF5 recording (.h5)")
    add_params_args(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--ideal", action="store_true", help="write undegraded events only")
    mode.add_argument("--pair", action="store_true",
                      help="write degraded events (/events) and undegraded events (/events_ideal)")
    p.add_argument("--split", choices=["train", "test"], default=None,
                   help="draw this sequence's degradation from the randomize section's range for the split")
    p.add_argument("--seed", type=seed_arg, default=0, help="random seed (default 0)")
    p.add_argument("--no-interpolate", action="store_true",
                   help="use the frames as given (no upsampling, as interpolate.method=none)")
    p.add_argument("--chunk", type=int, default=64, help="simulation steps per chunk (default 64)")
    p.add_argument("--no-frames", dest="store_frames", action="store_false",
                   help="do not copy the input frames into OUTPUT (events only)")
    p.add_argument("--compression", choices=["auto", "lzf", "gzip", "none"], default="auto",
                   help="HDF5 compression of OUTPUT (default auto: frames of an HDF5 input copied as "
                        "stored, the rest LZF; lzf: fast; gzip: ~smaller, slower; none)")
    from rdnet.cli.info import add_progress_arg
    add_progress_arg(p)
    p.set_defaults(func=run)


def _section(params: dict, name: str, target: str):
    """Validated section ``name`` (its class from ``target`` when not registered yet)."""
    import importlib

    from rdnet.config import SECTIONS, from_dict, section
    if name in SECTIONS:
        return section(params, name)
    mod, _, cls = target.partition(":")
    return from_dict(getattr(importlib.import_module(mod), cls), params.get(name), name)


@contextlib.contextmanager
def _leave_a_core():
    """Run the sensor kernels of this thread on one numba thread fewer than numba's
    default (at least one) inside the block, then restore the count: the prefetch thread
    (reading, statistics, flows) and the writer thread need a core, and on 2 shared cores
    a second kernel thread cost ~30 % more CPU per step (0.81 vs 0.58 ms at 346 x 260) for
    ~10 % less wall time alone. The events do not depend on the thread count (fixed
    partitions, see :mod:`rdnet.sim.sensor`)."""
    import numba
    n = numba.get_num_threads()
    numba.set_num_threads(max(1, n - 1))
    try:
        yield
    finally:
        numba.set_num_threads(n)


def run(args) -> int:
    import itertools

    import numpy as np

    from rdnet.config import to_dict
    from rdnet.errors import FormatError, ValidationError
    from rdnet.events.core import Events
    from rdnet.events.io import H5RecordingWriter
    from rdnet.events.io._common import refuse_input_as_output
    from rdnet.events.io.dispatch import FORMATS
    from rdnet.events.io.hdf5 import BackgroundWrites
    from rdnet.sim.pair import frame_chunks, prefetch, stream_events
    from rdnet.sim.randomize import degradation_level, draw_degrade
    from rdnet.sim.sensor import Sensor
    from rdnet.sim.settings import DegradeConfig
    from rdnet.sim.sources import iter_frames, source_kind

    params = load_cli_params(args)
    source_of_params = params_source(args)
    sensor = _section(params, "sensor", "rdnet.sim.settings:SensorConfig")
    base = _section(params, "degrade", "rdnet.sim.settings:DegradeConfig")
    interp_cfg = _section(params, "interpolate", "rdnet.sim.interpolate:InterpolateConfig")
    interp = None if args.no_interpolate else interp_cfg
    if args.chunk < 1:
        raise ValidationError("--chunk", f"must be >= 1, got {args.chunk}")
    if FORMATS.get(args.output.suffix.lower()) != "hdf5":            # the suffixes the readers take
        raise FormatError(args.output, None, "output must be an HDF5 recording (.h5)")
    refuse_input_as_output(args.output, args.input)
    rng = np.random.default_rng(args.seed)
    degrade = base
    if args.split is not None:
        degrade = draw_degrade(base, _section(params, "randomize", "rdnet.sim.settings:RandomizeConfig"),
                               args.split, rng)
    applied = DegradeConfig() if args.ideal else degrade
    interp_json = json.dumps({"method": "none"} if interp is None else to_dict(interp))
    log.info("params: %s", source_of_params)
    log.info("sensor: %s", json.dumps(to_dict(sensor)))
    log.info("degrade%s: %s", " (--ideal: not applied)" if args.ideal else "", json.dumps(to_dict(degrade)))
    log.info("interpolate: %s", interp_json)

    source = iter_frames(args.input, chunk_frames=args.chunk, as_stored=True)
    first = next(source, None)
    if first is None:
        raise FormatError(args.input, "frames", "no frames")
    width, height = first.width, first.height

    # frames of an HDF5 recording are copied chunk for chunk as stored (no decode/encode)
    copy_frames = args.store_frames and args.compression == "auto" and source_kind(args.input) == "hdf5"

    def frames_written(bg):
        for f in itertools.chain([first], source):
            if args.store_frames and not copy_frames:
                bg.append_frames(f.images, f.t_us, f.exposure_us)
            yield f

    if args.ideal:
        sensors, groups = [Sensor(width, height, sensor, None)], ["events"]
    elif args.pair:
        sensors = [Sensor(width, height, sensor, degrade, rng), Sensor(width, height, sensor, None)]
        groups = ["events", "events_ideal"]
    else:
        sensors, groups = [Sensor(width, height, sensor, degrade, rng)], ["events"]

    counts = dict.fromkeys(groups, 0)
    n_frames = 0
    compression = "lzf" if args.compression == "auto" else args.compression
    with H5RecordingWriter(args.output, width, height, "simulated", compression=compression) as w:
        if copy_frames:
            w.copy_frames(args.input)
        w.set_attr("params_source", source_of_params)
        w.set_attr("degrade_json", json.dumps(to_dict(applied)))
        w.set_attr("sensor_json", json.dumps(to_dict(sensor)))
        w.set_attr("interpolate_json", interp_json)
        w.set_attr("simulate_seed", int(args.seed))
        if args.split is not None:
            w.set_attr("split", args.split)
            w.set_attr("degradation_level", degradation_level(applied, base))
        for g in groups:
            w.append_events(Events.empty(width, height), g)   # groups exist even if empty

        def counted(bg):
            nonlocal n_frames
            for f in frames_written(bg):
                n_frames += len(f)
                yield f

        with BackgroundWrites(w) as bg, _leave_a_core():   # compression and writing overlap the simulation
            # reading, log conversion, statistics and flows run one chunk or two ahead in
            # a thread of their own, overlapping the sensor kernel (which drops the GIL);
            # the log frames the statistics computed are handed to the sensors
            with contextlib.closing(prefetch(frame_chunks(counted(bg), interpolate=interp,
                                                          log_eps=sensor.log_eps, chunk=args.chunk,
                                                          with_log=True))) as chunks:
                for evs in stream_events(chunks, sensors, progress=args.progress):
                    for g, ev in zip(groups, evs):
                        bg.append_events(ev, g)
                        counts[g] += len(ev)
    desc = ", ".join(f"{n:,} in /{g}" for g, n in counts.items())
    print(f"wrote {args.output} ({n_frames} frames, {width} x {height}; events: {desc})")
    return 0
