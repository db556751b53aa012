"""``voxel`` section of params.yaml."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional

from rdnet.config import check_bounds
from rdnet.errors import ConfigError

#: bounds of the ``voxel`` keys (checked by :func:`rdnet.config.check_bounds`): time bins are
#: input channels of the networks and planes of every voxel grid in memory (the paper: 10)
UPPER_BOUNDS = {"bins": 100}


@dataclass(frozen=True)
class VoxelConfig:
    """How events become network input: ``bins`` (N_e, paper: 10), ``mode`` ('hard' =
    paper Eq. 7, 'bilinear' = split in time), ``normalize`` (None/'maxabs'/'std')."""

    bins: int = 10
    mode: Literal["hard", "bilinear"] = "hard"
    normalize: Optional[str] = None

    def __post_init__(self):
        if self.bins < 1:
            raise ConfigError("voxel.bins", f"must be >= 1, got {self.bins}")
        check_bounds("voxel", self, UPPER_BOUNDS)
        if self.normalize not in (None, "none", "maxabs", "std"):
            raise ConfigError("voxel.normalize", f"must be none, maxabs or std, got {self.normalize!r}")
