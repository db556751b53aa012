"""The event dtype and the :class:`Events` container (tonic style: a thin frozen
dataclass over a structured numpy array; all work is vectorized numpy)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from rdnet.errors import ValidationError

#: The one event dtype used everywhere: t in microseconds, x/y pixel, p 1=ON 0=OFF.
EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])


def make_events(t, x, y, p) -> np.ndarray:
    """Build a structured event array (copies and casts the four columns)."""
    t = np.asarray(t)
    n = t.shape[0]
    arr = np.empty(n, dtype=EVENT_DTYPE)
    for name, col in (("t", t), ("x", x), ("y", y), ("p", p)):
        col = np.asarray(col)
        if col.shape != (n,):
            raise ValidationError(name, f"expected shape ({n},), got {col.shape}")
        arr[name] = col
    return arr


def _check_columns(t, x, y, p, width: int, height: int) -> None:
    n = t.shape[0]
    if n == 0:
        return
    if n > 1:
        bad = np.flatnonzero(np.diff(t) < 0)
        if bad.size:
            i = int(bad[0])
            raise ValidationError(
                "t", f"timestamps decrease at index {i + 1} ({int(t[i])} -> {int(t[i + 1])} us)")
    if int(x.max()) >= width:
        i = int(np.argmax(x >= width))
        raise ValidationError("x", f"x={int(x[i])} at index {i} outside sensor width {width}")
    if int(y.max()) >= height:
        i = int(np.argmax(y >= height))
        raise ValidationError("y", f"y={int(y[i])} at index {i} outside sensor height {height}")
    if int(p.max()) > 1:
        i = int(np.argmax(p > 1))
        raise ValidationError("p", f"polarity {int(p[i])} at index {i}; must be 0 (OFF) or 1 (ON)")


#: the largest sensor side taken, from a file or ``--width``/``--height`` (event sensors are
#: at most 1280 x 960 today; a 100000 x 100000 header once ran the per-pixel maps out of memory)
MAX_SENSOR_SIDE = 8192


@dataclass(frozen=True)
class Events:
    """Time-sorted events of one sensor.

    ``array`` has :data:`EVENT_DTYPE`; ``width``/``height`` are the sensor size (never
    inferred from the data). Invariants are checked on creation: non-decreasing ``t``,
    ``0 <= x < width``, ``0 <= y < height``, ``p`` in {0, 1}.
    """

    array: np.ndarray
    width: int
    height: int
    validate: bool = field(default=True, repr=False, compare=False)

    def __post_init__(self):
        arr = self.array
        if not isinstance(arr, np.ndarray) or arr.dtype != EVENT_DTYPE:
            try:
                arr = np.asarray(arr)
                if arr.dtype.names is None or not set("txyp") <= set(arr.dtype.names):
                    raise TypeError
                conv = np.empty(arr.shape[0], dtype=EVENT_DTYPE)
                for k in "txyp":
                    conv[k] = arr[k]
                arr = conv
            except (TypeError, ValueError):
                raise ValidationError("array", f"expected a structured array with fields t,x,y,p; got {getattr(arr, 'dtype', type(arr))}")
            object.__setattr__(self, "array", arr)
        if arr.ndim != 1:
            raise ValidationError("array", f"expected 1-D array, got shape {arr.shape}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValidationError("width/height", f"sensor size must be positive, got {self.width}x{self.height}")
        if max(int(self.width), int(self.height)) > MAX_SENSOR_SIDE:
            raise ValidationError("width/height", f"at most {MAX_SENSOR_SIDE} pixels a side (larger than any event "
                                  f"sensor; per-pixel maps of that size do not fit), got {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if self.validate:
            _check_columns(arr["t"], arr["x"], arr["y"], arr["p"], self.width, self.height)

    # --- construction -----------------------------------------------------------------
    @classmethod
    def from_columns(cls, t, x, y, p, width: int, height: int, *, sort: bool = False) -> "Events":
        """Build from four columns; ``sort=True`` sorts stably by time first."""
        arr = make_events(t, x, y, p)
        if sort and arr.shape[0] > 1:
            arr = arr[np.argsort(arr["t"], kind="stable")]
        return cls(arr, width, height)

    @classmethod
    def empty(cls, width: int, height: int) -> "Events":
        return cls(np.empty(0, dtype=EVENT_DTYPE), width, height)

    # --- columns ----------------------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        return self.array["t"]

    @property
    def x(self) -> np.ndarray:
        return self.array["x"]

    @property
    def y(self) -> np.ndarray:
        return self.array["y"]

    @property
    def p(self) -> np.ndarray:
        return self.array["p"]

    def __len__(self) -> int:
        return int(self.array.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """Sensor shape as (height, width)."""
        return (self.height, self.width)

    @property
    def duration_us(self) -> int:
        return 0 if len(self) == 0 else int(self.t[-1] - self.t[0])

    # --- slicing ----------------------------------------------------------------------
    def index_range(self, t_start_us: int, t_end_us: int) -> tuple[int, int]:
        """Indices [i0, i1) of the events with t_start_us <= t < t_end_us (binary search)."""
        t = self.t
        return int(np.searchsorted(t, t_start_us, "left")), int(np.searchsorted(t, t_end_us, "left"))

    def slice_time(self, t_start_us: int, t_end_us: int) -> "Events":
        """Events with t_start_us <= t < t_end_us; a view, O(log n)."""
        i0, i1 = self.index_range(t_start_us, t_end_us)
        return Events(self.array[i0:i1], self.width, self.height, validate=False)

    def __getitem__(self, item) -> "Events":
        if isinstance(item, slice):
            return Events(self.array[item], self.width, self.height, validate=False)
        raise TypeError("Events supports slices only; use .array for fancy indexing")

    def select(self, mask: np.ndarray) -> "Events":
        """Events where the boolean ``mask`` is true (order kept)."""
        return Events(self.array[np.asarray(mask, bool)], self.width, self.height, validate=False)

    # --- statistics -------------------------------------------------------------------
    def count_per_pixel(self, polarity: int | None = None) -> np.ndarray:
        """(height, width) int64 event counts; ``polarity`` 1/0 restricts to ON/OFF."""
        x, y = self.x, self.y
        if polarity is not None:
            keep = self.p == polarity
            x, y = x[keep], y[keep]
        flat = y.astype(np.int64) * self.width + x
        return np.bincount(flat, minlength=self.width * self.height).reshape(self.height, self.width)

    def signed_count_per_pixel(self) -> np.ndarray:
        """(height, width) sum of +1 per ON and -1 per OFF event."""
        flat = self.y.astype(np.int64) * self.width + self.x
        w = self.p.astype(np.int64) * 2 - 1
        return np.bincount(flat, weights=w, minlength=self.width * self.height).reshape(
            self.height, self.width).astype(np.int64)

    @property
    def on_fraction(self) -> float:
        return float(self.p.mean()) if len(self) else float("nan")

    @property
    def rate_hz(self) -> float:
        """Mean event rate over the span of the events."""
        d = self.duration_us
        return float(len(self) / (d * 1e-6)) if d > 0 else float("nan")


def concatenate(parts: Sequence[Events] | Iterable[Events], *, sort: bool = False) -> Events:
    """Join events of one sensor. Parts must be in time order unless ``sort=True``
    (then a stable merge sort by time is applied, keeping the order of equal times)."""
    parts = list(parts)
    if not parts:
        raise ValidationError("parts", "nothing to concatenate")
    w, h = parts[0].width, parts[0].height
    for q in parts[1:]:
        if (q.width, q.height) != (w, h):
            raise ValidationError("width/height", f"sensor sizes differ: {w}x{h} vs {q.width}x{q.height}")
    arr = np.concatenate([q.array for q in parts])
    if sort:
        arr = arr[np.argsort(arr["t"], kind="stable")]
    return Events(arr, w, h)
