"""``rdnet convert IN OUT``: convert a recording between formats (chosen by suffix:
.h5/.hdf5, .aedat4, .raw and .dat (input only), .txt, .npz, .npy). The output is written
atomically; extra event groups (e.g. /events_ideal) are kept from HDF5 to HDF5.

Prophesee inputs (.raw, .dat), and HDF5 inputs going to .npy, are streamed chunk by chunk
(bounded memory; HDF5 to HDF5 goes through load/save to keep the extra event groups); ``.npy`` is a plain structured array with fields x, y, t, p
(tonic's layout; t in us int64, p 0/1) without the sensor size."""
from __future__ import annotations

from pathlib import Path

from rdnet.cli.info import add_progress_arg, add_sensor_size_args, progress_chunks, sensor_size_of

_STREAMED_IN = ("prophesee_raw", "prophesee_dat", "hdf5")


def register(subparsers) -> None:
    p = subparsers.add_parser("convert", help="convert a recording between .h5, .aedat4/.raw/.dat (read), "
                                              ".txt, .npz and .npy",
                              description="Read IN and write OUT, formats chosen by file suffix. OUT.npy is a plain "
                                          "NumPy structured array (fields x, y, t [us], p [0/1]; no sensor size).")
    p.add_argument("input", type=Path, help="input recording (.h5, .hdf5, .aedat4, .raw, .dat, .txt, .npz, .npy)")
    p.add_argument("output", type=Path, help="output recording (.h5, .hdf5, .txt, .npz, .npy)")
    add_sensor_size_args(p)
    add_progress_arg(p)
    p.set_defaults(func=run)


def _streamed(args, out_fmt: str) -> tuple[int, int, int, int]:
    """Chunked conversion to .h5 or .npy; returns (events, frames, width, height)."""
    import logging

    from rdnet.events.io import H5RecordingWriter, open_events, write_npy_chunks
    with open_events(args.input, sensor_size=sensor_size_of(args)) as s:
        if out_fmt == "npy":
            if not s.has_events:                  # as write_npy says for a whole recording
                from rdnet.errors import FormatError
                raise FormatError(args.input, "events", "recording has no events (.npy holds events only)")
            if s.has_frames:
                logging.getLogger(__name__).warning("%s: frames not written (.npy holds events only)", args.output)
            return write_npy_chunks(args.output, progress_chunks(s, args.progress)), 0, s.width, s.height
        n = n_fr = 0
        with H5RecordingWriter(args.output, s.width, s.height, s.sensor) as w:
            if s.has_events:
                for ch in progress_chunks(s, args.progress):
                    w.append_events(ch)
                    n += len(ch)
            if s.has_frames:
                fr = s.frames()
                w.write_frames(fr)
                n_fr = len(fr)
            if s.format.startswith("prophesee"):
                w.set_attr("source_format", s.encoding)
        return n, n_fr, s.width, s.height


def run(args) -> int:
    from rdnet.errors import FormatError
    from rdnet.events.io import event_groups, format_of, load, read_events, save
    from rdnet.events.io.dispatch import WRITABLE
    from rdnet.events.io._common import refuse_input_as_output
    in_fmt, out_fmt = format_of(args.input), format_of(args.output)
    if out_fmt not in WRITABLE:
        raise FormatError(args.output, None, f"{out_fmt} is read-only; write .h5, .txt, .npz or .npy")
    refuse_input_as_output(args.output, args.input)
    if in_fmt in _STREAMED_IN and (out_fmt == "npy" or (out_fmt == "hdf5" and in_fmt != "hdf5")):
        n_ev, n_fr, w, h = _streamed(args, out_fmt)
    else:
        rec = load(args.input, sensor_size=sensor_size_of(args))
        kw = {}
        if out_fmt == "hdf5" and in_fmt == "hdf5":
            extra = {g: read_events(args.input, g) for g in event_groups(args.input) if g != "events"}
            if extra:
                kw["extra_events"] = extra
        save(args.output, rec, **kw)
        n_ev = 0 if rec.events is None else len(rec.events)
        n_fr = 0 if rec.frames is None else len(rec.frames)
        w, h = rec.width, rec.height
    print(f"wrote {args.output} ({n_ev:,} events, {n_fr} frames, {w} x {h})")
    return 0
