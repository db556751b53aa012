"""``rdnet info RECORDING``: print a summary of a recording (any format of
:mod:`rdnet.events.io`), human-readable or ``--json``."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from rdnet.errors import ConfigError


def add_progress_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="no progress bar (shown only on a terminal anyway)")


def progress_chunks(stream, progress: bool = True, max_events: int = 1_000_000):
    """``stream.chunks(max_events)`` with a tqdm bar counting events (on a terminal)."""
    from tqdm import tqdm
    with tqdm(total=stream.n_events, unit="ev", unit_scale=True, desc=stream.path.name,
              disable=None if progress else True, leave=False) as bar:
        for ch in stream.chunks(max_events):
            bar.update(len(ch))
            yield ch


def add_sensor_size_args(p: argparse.ArgumentParser) -> None:
    """``--width``/``--height``: sensor size for formats that do not store it (text)."""
    p.add_argument("--width", type=int, default=None, help="sensor width (text files without a size header)")
    p.add_argument("--height", type=int, default=None, help="sensor height (text files without a size header)")


def sensor_size_of(args) -> tuple[int, int] | None:
    from rdnet.events.core import MAX_SENSOR_SIDE
    if (args.width is None) != (args.height is None):
        raise ConfigError("--width/--height", "give both or neither")
    if args.width is None:
        return None
    if args.width <= 0 or args.height <= 0:
        raise ConfigError("--width/--height", f"must be positive, got {args.width}x{args.height}")
    if max(args.width, args.height) > MAX_SENSOR_SIDE:
        raise ConfigError("--width/--height", f"at most {MAX_SENSOR_SIDE} pixels a side (larger than any event "
                                              f"sensor; per-pixel maps of that size do not fit), got {args.width}x{args.height}")
    return args.width, args.height


def register(subparsers) -> None:
    p = subparsers.add_parser("info", help="summarize a recording (.h5, .aedat4, .txt, .npz, .npy, .raw, .dat)",
                              description="Print sensor size, duration, event count, ON fraction, event rate, "
                                          "frame count, exposure and frame rate of a recording.")
    p.add_argument("recording", type=Path, help="recording file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_sensor_size_args(p)
    add_progress_arg(p)
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


def stream_summary(stream, max_events: int = 1_000_000, progress: bool = False) -> dict:
    """The ``Recording.summary()`` dict of an open :class:`~rdnet.events.io.EventStream`,
    accumulated chunk by chunk (counts, ON/OFF, time and coordinate ranges, an active-pixel
    bitmap), so a multi-GB Prophesee file is never in memory at once."""
    import numpy as np

    from rdnet.events import Events
    from rdnet.events.recording import Recording
    w, h = stream.width, stream.height
    n = n_on = 0
    t_first = t_last = None
    x_lo = y_lo = 1 << 30
    x_hi = y_hi = -1
    active = np.zeros(w * h, bool)
    for ch in progress_chunks(stream, progress, max_events):
        if not len(ch):
            continue
        n += len(ch)
        n_on += int(np.count_nonzero(ch.p))
        t_first = int(ch.t[0]) if t_first is None else t_first
        t_last = int(ch.t[-1])
        x, y = ch.x, ch.y
        x_lo, x_hi = min(x_lo, int(x.min())), max(x_hi, int(x.max()))
        y_lo, y_hi = min(y_lo, int(y.min())), max(y_hi, int(y.max()))
        active[y.astype(np.int64) * w + x] = True
    frames = stream.frames()
    # the frame part (and sensor, duration over events and frames) from Recording.summary
    # on a stand-in of the first and last event, so both summaries stay one definition
    ends = None
    if stream.has_events:
        ends = Events.empty(w, h) if n == 0 else Events.from_columns(
            [t_first, t_last], [0, 0], [0, 0], [0, 0], w, h)
    s = Recording(w, h, events=ends, frames=frames, sensor=stream.sensor).summary()
    if stream.has_events:
        s["events"], s["on_events"], s["off_events"] = n, n_on, n - n_on
        s["on_fraction"] = n_on / n if n else float("nan")
        d = 0 if n == 0 else t_last - t_first
        s["event_rate_hz"] = float(n / (d * 1e-6)) if d > 0 else float("nan")
        if n:
            s["x_range"], s["y_range"] = [x_lo, x_hi], [y_lo, y_hi]
            s["active_pixels"] = int(np.count_nonzero(active))
    return s


def run(args) -> int:
    from rdnet.events.io import open_events
    with open_events(args.recording, sensor_size=sensor_size_of(args)) as stream:
        s = stream_summary(stream, progress=args.progress)
    extra = _extra_groups(args.recording)
    if extra:
        s["extra_event_groups"] = extra
    if args.json:
        clean = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in s.items()}
        print(json.dumps({"file": str(args.recording), **clean}, indent=2))
    else:
        print(format_summary(args.recording, s))
    return 0
