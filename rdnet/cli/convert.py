"""``rdnet convert IN OUT``: convert a recording between formats (chosen by suffix:
.h5/.hdf5, .aedat4 (input only), .txt, .npz). The output is written atomically; extra
event groups (e.g. /events_ideal) are kept from HDF5 to HDF5."""
from __future__ import annotations

from pathlib import Path

from rdnet.cli.info import add_sensor_size_args, sensor_size_of


def register(subparsers) -> None:
    p = subparsers.add_parser("convert", help="convert a recording between .h5, .aedat4 (read), .txt and .npz",
                              description="Read IN and write OUT, formats chosen by file suffix.")
    p.add_argument("input", type=Path, help="input recording (.h5, .hdf5, .aedat4, .txt, .npz)")
    p.add_argument("output", type=Path, help="output recording (.h5, .hdf5, .txt, .npz)")
    add_sensor_size_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from rdnet.errors import FormatError
    from rdnet.events.io import event_groups, format_of, load, read_events, save
    out_fmt = format_of(args.output)
    if args.output.resolve() == args.input.resolve():
        raise FormatError(args.output, None, "output is the input file")
    rec = load(args.input, sensor_size=sensor_size_of(args))
    kw = {}
    if out_fmt == "hdf5" and format_of(args.input) == "hdf5":
        extra = {g: read_events(args.input, g) for g in event_groups(args.input) if g != "events"}
        if extra:
            kw["extra_events"] = extra
    save(args.output, rec, **kw)
    n_ev = 0 if rec.events is None else len(rec.events)
    n_fr = 0 if rec.frames is None else len(rec.frames)
    print(f"wrote {args.output} ({n_ev:,} events, {n_fr} frames, {rec.width} x {rec.height})")
    return 0
