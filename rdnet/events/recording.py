"""Frames and :class:`Recording` (frames + events + sensor metadata)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.core import Events

#: ITU-R BT.601 luma weights of linear R, G, B: the luminance of colour frames
LUMA_BT601 = np.array([0.299, 0.587, 0.114], np.float32)


#: frame timestamps must stay below this in magnitude (2^52 us, the year 2112 as Unix time in
#: microseconds). Frames at 2^53 us crashed the simulator (memory corruption in a compiled
#: kernel; where exactly was not located: the interpolated times are int64), frames at 2^52
#: and at today's Unix times simulate the same events as near 0. A guard, not the cure.
MAX_FRAME_TIME_US = 2 ** 52


@dataclass(frozen=True)
class Frames:
    """Intensity frames with their mid-exposure timestamps.

    ``images``: (N, H, W) grey or (N, H, W, 3) colour; uint8 (0..255) or float32 linear
    intensity in [0, 1]. ``t_us``: int64 middle of exposure, strictly increasing.
    ``exposure_us``: int64 exposure duration per frame (>= 0).
    """

    images: np.ndarray
    t_us: np.ndarray
    exposure_us: np.ndarray

    def __post_init__(self):
        im = np.asarray(self.images)
        if im.ndim not in (3, 4) or (im.ndim == 4 and im.shape[3] != 3):
            raise ValidationError("frames/images", f"expected (N,H,W) or (N,H,W,3), got shape {im.shape}")
        if im.dtype not in (np.uint8, np.float32):
            if np.issubdtype(im.dtype, np.floating):
                im = im.astype(np.float32)
            else:
                raise ValidationError("frames/images", f"dtype must be uint8 or float32, got {im.dtype}")
        if im.dtype == np.float32 and im.size and not np.isfinite(im).all():
            raise ValidationError("frames/images", "contains NaN or infinite values")
        if im.dtype == np.float32 and im.size and float(im.min()) < 0:
            raise ValidationError("frames/images", f"negative intensity {float(im.min())}")
        t = np.asarray(self.t_us)
        if not np.issubdtype(t.dtype, np.integer):
            if np.issubdtype(t.dtype, np.floating) and np.all(np.isfinite(t)) and np.all(t == np.round(t)):
                t = t.astype(np.int64)
            else:
                raise ValidationError("frames/t", f"timestamps must be integer microseconds, got {t.dtype}")
        t = t.astype(np.int64)
        exp = np.asarray(self.exposure_us)
        if exp.ndim == 0:
            exp = np.full(t.shape, int(exp), np.int64)
        exp = exp.astype(np.int64)
        n = im.shape[0]
        if t.shape != (n,):
            raise ValidationError("frames/t", f"expected {n} timestamps, got shape {t.shape}")
        if exp.shape != (n,):
            raise ValidationError("frames/exposure_us", f"expected {n} exposures, got shape {exp.shape}")
        if t.size and int(np.abs(t).max()) >= MAX_FRAME_TIME_US:
            raise ValidationError("frames/t", f"timestamp {int(t[np.argmax(np.abs(t))])} us is beyond +-2^52 us "
                                  "(year 2112 as Unix time), which the simulator does not support")
        if n > 1 and np.any(np.diff(t) <= 0):
            i = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise ValidationError("frames/t", f"timestamps not increasing at frame {i + 1} ({int(t[i])} -> {int(t[i + 1])} us)")
        if np.any(exp < 0):
            raise ValidationError("frames/exposure_us", "negative exposure")
        object.__setattr__(self, "images", im)
        object.__setattr__(self, "t_us", t)
        object.__setattr__(self, "exposure_us", exp)

    def __len__(self) -> int:
        return int(self.images.shape[0])

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])

    @property
    def is_color(self) -> bool:
        return self.images.ndim == 4

    def linear(self) -> np.ndarray:
        """Images as float32 linear intensity in [0, 1] (uint8 divided by 255)."""
        if self.images.dtype == np.uint8:
            lin = self.images.astype(np.float32)
            lin /= np.float32(255.0)          # in place: no second full-size array (same values)
            return lin
        return self.images

    def grey(self) -> np.ndarray:
        """(N, H, W) float32 linear luminance (ITU-R BT.601 weights for colour)."""
        lin = self.linear()
        if lin.ndim == 4:
            return (lin @ LUMA_BT601).astype(np.float32)
        return lin

    def exposure_window(self, i: int) -> tuple[int, int]:
        """[start, end) of frame ``i``'s exposure in microseconds."""
        half = int(self.exposure_us[i]) // 2
        return int(self.t_us[i]) - half, int(self.t_us[i]) - half + int(self.exposure_us[i])


@dataclass(frozen=True)
class Recording:
    """What a sensor recorded: optional frames, optional events, sensor size and name."""

    width: int
    height: int
    events: Events | None = None
    frames: Frames | None = None
    sensor: str = ""
    attrs: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        if self.events is None and self.frames is None:
            raise ValidationError("recording", "needs events, frames, or both")
        if self.events is not None and (self.events.width, self.events.height) != (self.width, self.height):
            raise ValidationError("events", f"sensor {self.events.width}x{self.events.height} != recording {self.width}x{self.height}")
        if self.frames is not None and (self.frames.width, self.frames.height) != (self.width, self.height):
            raise ValidationError("frames/images", f"frame size {self.frames.width}x{self.frames.height} != sensor {self.width}x{self.height}")

    @property
    def t_range_us(self) -> tuple[int, int]:
        lo, hi = [], []
        if self.events is not None and len(self.events):
            lo.append(int(self.events.t[0])); hi.append(int(self.events.t[-1]))
        if self.frames is not None and len(self.frames):
            lo.append(int(self.frames.t_us[0] - self.frames.exposure_us[0] // 2))
            hi.append(int(self.frames.t_us[-1] + self.frames.exposure_us[-1] // 2))
        return (min(lo), max(hi)) if lo else (0, 0)

    def require_frames(self, source: str = "recording") -> Frames:
        from rdnet.errors import FormatError
        if self.frames is None or len(self.frames) == 0:
            raise FormatError(source, "frames", "recording has no frames")
        return self.frames

    def require_events(self, source: str = "recording") -> Events:
        from rdnet.errors import FormatError
        if self.events is None or len(self.events) == 0:
            raise FormatError(source, "events", "recording has no events")
        return self.events

    def summary(self) -> dict:
        """Plain-dict summary (what ``rdnet info`` prints)."""
        out: dict = {"sensor": self.sensor or "unknown", "width": self.width, "height": self.height}
        t0, t1 = self.t_range_us
        out["duration_s"] = (t1 - t0) * 1e-6
        ev = self.events
        if ev is not None:
            out["events"] = len(ev)
            out["on_events"] = int(ev.p.sum()) if len(ev) else 0
            out["off_events"] = len(ev) - out["on_events"]
            out["on_fraction"] = ev.on_fraction
            out["event_rate_hz"] = ev.rate_hz
            out["event_t_range_us"] = [int(ev.t[0]), int(ev.t[-1])] if len(ev) else None
            if len(ev):
                x, y = ev.x, ev.y
                out["x_range"] = [int(x.min()), int(x.max())]
                out["y_range"] = [int(y.min()), int(y.max())]
                out["active_pixels"] = int(np.count_nonzero(ev.count_per_pixel()))
        else:
            out["events"] = 0
        fr = self.frames
        if fr is not None and len(fr):
            out["frames"] = len(fr)
            out["frame_dtype"] = str(fr.images.dtype)
            out["frame_channels"] = 3 if fr.is_color else 1
            if len(fr) > 1:
                out["frame_rate_hz"] = float(1e6 / np.median(np.diff(fr.t_us)))
            out["exposure_us_median"] = float(np.median(fr.exposure_us))
        else:
            out["frames"] = 0
        return out
