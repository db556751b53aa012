"""Recording formats; ``load``/``save`` dispatch by suffix (see :mod:`rdnet.events.io.dispatch`).

- :mod:`~rdnet.events.io.hdf5`: the project layout (lazy reader, incremental writer),
- :mod:`~rdnet.events.io.aedat4`: AEDAT 4 (read only, via ``aedat``),
- :mod:`~rdnet.events.io.text`: ECD / RPG ``events.txt`` (+ ``images.txt``),
- :mod:`~rdnet.events.io.npz`: NumPy arrays.
"""
from rdnet.events.io.aedat4 import read_aedat4
from rdnet.events.io.dispatch import FORMATS, format_of, load, save
from rdnet.events.io.hdf5 import (H5EventReader, H5RecordingWriter, event_groups, read_events, read_frames,
                                  read_header, read_recording, write_recording)
from rdnet.events.io.npz import read_npz, write_npz
from rdnet.events.io.text import read_text, read_text_events, read_text_frames, write_text

__all__ = ["FORMATS", "H5EventReader", "H5RecordingWriter", "event_groups", "format_of", "load", "read_aedat4",
           "read_events", "read_frames", "read_header", "read_npz", "read_recording", "read_text", "read_text_events",
           "read_text_frames", "save", "write_npz", "write_recording", "write_text"]
