"""What guides a stage-1 restorer besides the events: the image input of :class:`RestoreNet`.

* ``blurry`` (the paper, RDNet's stage 1): the blurry frame of the window (on a recording,
  the frame nearest the window).
* ``frame_pair`` (``rdnet train --task restore_frames``): the two sharp frames that bracket
  the window, given as the first frame and the change of log intensity to the last one in
  units of the contrast threshold, ``(log(I_last + eps) - log(I_first + eps)) / C``. For an
  ideal sensor that change is the net ON-minus-OFF count each pixel fires over the window,
  whatever a degradation removed, so it tells the restorer how many events its window lost,
  which one blurry frame cannot (docs/restoration.md, "The frames bracketing the window").
  ``eps`` and ``C`` are the simulator's ``sensor.log_eps`` and ``sensor.threshold_on`` the
  network was trained with; they travel in the checkpoint (``extra["guide"]``).

Colour frames: the first frame keeps its channels and the change is taken on its luminance
(ITU-R BT.601), so the image has ``channels + 1`` channels.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Mapping

import numpy as np

from rdnet.errors import ValidationError
from rdnet.events.recording import LUMA_BT601

GUIDES = ("blurry", "frame_pair")


@dataclass(frozen=True)
class FramePairGuide:
    """The ``frame_pair`` guide: the log offset and the contrast threshold of the change
    channel (module docstring)."""

    log_eps: float
    threshold: float

    def __post_init__(self):
        for name in ("log_eps", "threshold"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValidationError(f"guide.{name}", f"must be a positive number, got {v!r}")

    def to_dict(self) -> dict:
        return {"kind": "frame_pair", **asdict(self)}

    @classmethod
    def from_dict(cls, d: Mapping | None) -> "FramePairGuide | None":
        """The guide stored in a checkpoint's ``extra["guide"]`` (None: the blurry frame)."""
        if d is None or d.get("kind", "blurry") == "blurry":
            return None
        if d.get("kind") != "frame_pair":
            raise ValidationError("guide.kind", f"must be one of {list(GUIDES)}, got {d.get('kind')!r}")
        extra = set(d) - {"kind", "log_eps", "threshold"}
        if extra:
            raise ValidationError(f"guide.{sorted(extra)[0]}", "unknown key")
        try:
            return cls(float(d["log_eps"]), float(d["threshold"]))
        except KeyError as e:
            raise ValidationError(f"guide.{e.args[0]}", "missing") from None

    def image(self, first: np.ndarray, last: np.ndarray) -> np.ndarray:
        """(C + 1, H, W) float32 network image of two linear frames, each (C, H, W) with C 1
        or 3: the first frame, then the change of log luminance over the threshold."""
        first = np.asarray(first, np.float32)
        last = np.asarray(last, np.float32)
        if first.shape != last.shape or first.ndim != 3 or first.shape[0] not in (1, 3):
            raise ValidationError("frames", f"expected two (C, H, W) frames with C 1 or 3, got {first.shape} "
                                  f"and {last.shape}")
        y0, y1 = ((f[0] if f.shape[0] == 1 else np.tensordot(LUMA_BT601, f, axes=1)) for f in (first, last))
        return np.concatenate([first, self.change(y0, y1)[None]])

    def change(self, first: np.ndarray, last: np.ndarray) -> np.ndarray:
        """float32 ``(log(last + eps) - log(first + eps)) / threshold`` of two linear luminance
        arrays of one shape (any: one frame, or a stack): the net ON-minus-OFF count of an
        ideal pixel between them."""
        eps = np.float32(self.log_eps)
        return ((np.log(np.asarray(last, np.float32) + eps) - np.log(np.asarray(first, np.float32) + eps))
                / np.float32(self.threshold)).astype(np.float32)
