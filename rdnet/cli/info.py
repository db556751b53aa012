"""``rdnet info RECORDING``: print a summary of a recording (any format of
:mod:`rdnet.events.io`), human-readable or ``--json``."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from rdnet.errors import ConfigError


def add_sensor_size_args(p: argparse.ArgumentParser) -> None:
    """``--width``/``--height``: sensor size for formats that do not store it (text)."""
    p.add_argument("--width", type=int, default=None, help="sensor width (text files without a size header)")
    p.add_argument("--height", type=int, default=None, help="sensor height (text files without a size header)")


def sensor_size_of(args) -> tuple[int, int] | None:
    if (args.width is None) != (args.height is None):
        raise ConfigError("--width/--height", "give both or neither")
    if args.width is None:
        return None
    if args.width <= 0 or args.height <= 0:
        raise ConfigError("--width/--height", f"must be positive, got {args.width}x{args.height}")
    return args.width, args.height


def register(subparsers) -> None:
    p = subparsers.add_parser("info", help="summarize a recording (.h5, .aedat4, .txt, .npz)",
                              description="Print sensor size, duration, event count, ON fraction, event rate, "
                                          "frame count, exposure and frame rate of a recording.")
    p.add_argument("recording", type=Path, help="recording file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_sensor_size_args(p)
    p.set_defaults(func=run)


def _extra_groups(path: Path) -> dict[str, int]:
    from rdnet.events.io import H5EventReader, event_groups, format_of
    if format_of(path) != "hdf5":
        return {}
    out = {}
    for g in event_groups(path):
        if g != "events":
            with H5EventReader(path, g) as r:
                out[g] = len(r)
    return out


def _fmt(v, spec: str) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def format_summary(path: Path, s: dict) -> str:
    """Human-readable lines of a ``Recording.summary()`` dict."""
    lines = [f"file         {path}",
             f"sensor       {s['sensor']} ({s['width']} x {s['height']})",
             f"duration     {s['duration_s']:.3f} s"]
    n = s.get("events", 0)
    if n:
        lines += [f"events       {n:,} (ON {s['on_events']:,} / OFF {s['off_events']:,}, "
                  f"ON fraction {_fmt(s['on_fraction'], '.3f')})",
                  f"event rate   {_fmt(s['event_rate_hz'], ',.0f')} ev/s",
                  f"active px    {s['active_pixels']:,} of {s['width'] * s['height']:,}"]
    else:
        lines.append("events       0")
    nf = s.get("frames", 0)
    if nf:
        kind = "colour" if s["frame_channels"] == 3 else "grey"
        lines.append(f"frames       {nf} ({s['frame_dtype']} {kind}), "
                     f"exposure {s['exposure_us_median']:.0f} us (median)")
        if "frame_rate_hz" in s:
            lines.append(f"frame rate   {s['frame_rate_hz']:.3f} Hz (period {1e3 / s['frame_rate_hz']:.1f} ms)")
    else:
        lines.append("frames       0")
    for g, count in s.get("extra_event_groups", {}).items():
        lines.append(f"/{g:<11} {count:,} events")
    return "\n".join(lines)


def run(args) -> int:
    from rdnet.events.io import load
    rec = load(args.recording, sensor_size=sensor_size_of(args))
    s = rec.summary()
    extra = _extra_groups(args.recording)
    if extra:
        s["extra_event_groups"] = extra
    if args.json:
        clean = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in s.items()}
        print(json.dumps({"file": str(args.recording), **clean}, indent=2))
    else:
        print(format_summary(args.recording, s))
    return 0
