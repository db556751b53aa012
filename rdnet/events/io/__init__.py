"""Recording formats; ``load``/``save`` dispatch by suffix (see :mod:`rdnet.events.io.dispatch`).

- :mod:`~rdnet.events.io.hdf5`: the project layout (lazy reader, incremental writer),
- :mod:`~rdnet.events.io.aedat4`: AEDAT 4 (read only, via ``aedat``),
- :mod:`~rdnet.events.io.text`: ECD / RPG ``events.txt`` (+ ``images.txt``),
- :mod:`~rdnet.events.io.npz`: NumPy arrays,
- :mod:`~rdnet.events.io.prophesee`: Prophesee RAW (EVT 2.0, EVT 3.0) and DAT (read only, streamed),
- :mod:`~rdnet.events.io.npy`: plain x, y, t, p structured arrays (tonic's layout).

:func:`open_events` (:mod:`~rdnet.events.io.stream`) streams any of them chunk by chunk.
"""
from rdnet.events.io.aedat4 import read_aedat4
from rdnet.events.io.dispatch import FORMATS, format_of, load, save
from rdnet.events.io.hdf5 import (H5EventReader, H5RecordingWriter, event_groups, read_events, read_frames,
                                  read_header, read_recording, write_recording)
from rdnet.events.io.npy import NPY_DTYPE, read_npy, write_npy, write_npy_chunks
from rdnet.events.io.npz import read_npz, write_npz
from rdnet.events.io.prophesee import ProphReader, read_prophesee
from rdnet.events.io.stream import EventStream, open_events
from rdnet.events.io.text import read_text, read_text_events, read_text_frames, write_text

__all__ = ["FORMATS", "NPY_DTYPE", "EventStream", "H5EventReader", "H5RecordingWriter", "ProphReader",
           "event_groups", "format_of", "load", "open_events", "read_aedat4", "read_events", "read_frames",
           "read_header", "read_npy", "read_npz", "read_prophesee", "read_recording", "read_text",
           "read_text_events", "read_text_frames", "save", "write_npy", "write_npy_chunks", "write_npz",
           "write_recording", "write_text"]
