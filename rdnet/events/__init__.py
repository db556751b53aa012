"""Event data: the event dtype, containers, voxel grids; formats live in :mod:`rdnet.events.io`."""
from rdnet.events.core import EVENT_DTYPE, Events, concatenate, make_events
from rdnet.events.recording import Frames, Recording
from rdnet.events.voxel import normalization_scale, normalize_voxel, voxel_events, voxel_grid

__all__ = ["EVENT_DTYPE", "Events", "Frames", "Recording", "concatenate", "make_events",
           "normalization_scale", "normalize_voxel", "voxel_events", "voxel_grid"]
