"""Process-level settings for long CPU inference runs.

glibc's malloc serves every allocation above its mmap threshold (at most 32 MB after its
dynamic adjustment) with a fresh ``mmap`` and returns it with ``munmap`` when freed. A
network on a full sensor frame allocates and frees activations of tens of MB per layer
(16 channels x 1280 x 720 x 4 bytes = 59 MB), so every window pays page faults that zero
the pages again: on the Prophesee night recording (1280 x 720) ``rdnet restore`` spent most
of its time in the kernel, 1.03 s per window against 0.34 s once the freed memory is kept
for reuse (2 cores). :func:`keep_freed_memory` raises the mmap and trim thresholds (1 GiB)
with ``mallopt``, so large blocks come from the heap and stay mapped; the price is that
the process keeps its peak heap until it exits. Nothing happens off glibc.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import sys

log = logging.getLogger(__name__)

#: mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: the thresholds set: allocations up to this size come from the heap, and freed heap
#: memory up to this size is not given back to the system.
KEEP_BYTES = 1 << 30

_done = False


def keep_freed_memory() -> bool:
    """Raise glibc malloc's mmap and trim thresholds to :data:`KEEP_BYTES` once per process
    (module docstring). Returns whether the setting is in effect (False off Linux/glibc)."""
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = bool(mallopt(_M_MMAP_THRESHOLD, KEEP_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, KEEP_BYTES))
    _done = ok
    if ok:
        log.debug("malloc keeps freed memory up to %d bytes for reuse", KEEP_BYTES)
    return ok
