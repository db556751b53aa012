"""``deblur`` section of params.yaml: how ``rdnet deblur`` runs RDNet on a real recording."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional

from rdnet.config import MAX_THREADS, check_bounds, positive
from rdnet.errors import ConfigError

#: bounds of the ``deblur`` keys (checked by :func:`rdnet.config.check_bounds`)
UPPER_BOUNDS = {
    # frames per network call, in memory at once (as ``train.batch_size``)
    "batch_size": 4096,
    "threads": MAX_THREADS,
    # more frames than a day at 100 fps (8.6e6)
    "max_frames": 10_000_000,
    # frames in one figure
    "montage_frames": 100}


@dataclass(frozen=True)
class DeblurConfig:
    """``window``: the events a frame's deblurring sees. ``exposure`` = the frame's
    exposure window (what the paper's blur model means); ``interval`` = half-way to the
    neighbouring frames on each side (consecutive windows tile the recording); ``auto`` =
    exposure when every frame has an exposure time, else interval (the fallback for files
    that store none; the choice is written to the output).
    ``batch_size``: frames per network call; ``device``: cpu, cuda or auto (cuda when
    available); ``threads``: torch CPU threads (0 = torch's default).
    ``max_frames``: deblur only the first N frames (None = all).
    ``montage_frames``: frames shown in ``montage.png`` (0 = no figure); ``png``: also
    write every deblurred frame as an 8-bit PNG.
    ``event_times``: the restored event stream's timestamps: ``input`` (the events stage 1
    keeps are the recording's own, with their times; only those a voxel holds beyond its
    input are spread over the bin: :mod:`rdnet.events.select`) or ``bins`` (every event
    spread evenly over its bin). The voxels, and so the deblurred frames, are the same.
    """

    window: Literal["auto", "exposure", "interval"] = "auto"
    batch_size: int = 4
    device: Literal["cpu", "cuda", "auto"] = "auto"
    threads: int = 0
    max_frames: Optional[int] = None
    montage_frames: int = 3
    png: bool = True
    event_times: Literal["input", "bins"] = "input"

    def __post_init__(self):
        positive("deblur.batch_size", self.batch_size, allow_zero=False)
        positive("deblur.threads", self.threads)
        positive("deblur.montage_frames", self.montage_frames)
        if self.max_frames is not None and self.max_frames < 2:
            raise ConfigError("deblur.max_frames", f"must be >= 2 (consecutive frames are compared) "
                              f"or null, got {self.max_frames}")
        if self.event_times not in ("input", "bins"):
            raise ConfigError("deblur.event_times", f"must be input or bins, got {self.event_times!r}")
        if self.device not in ("cpu", "cuda", "auto"):
            raise ConfigError("deblur.device", f"must be cpu, cuda or auto, got {self.device!r}")
        check_bounds("deblur", self, UPPER_BOUNDS)
