"""rdnet.runtime: the malloc setting for long CPU inference (checked in child processes,
so the test session's own malloc is left as it is)."""
import subprocess
import sys

import pytest

from rdnet import runtime

# bytes glibc holds in mmapped blocks while a 64 MB array is alive (mallinfo2.hblkhd)
_PROBE = r"""
import ctypes, sys
import numpy as np
class MI(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL("libc.so.6"); libc.mallinfo2.restype = MI
if sys.argv[1] == "keep":
    from rdnet.runtime import keep_freed_memory
    assert keep_freed_memory() and keep_freed_memory()      # idempotent
a = np.ones(64 << 20, np.uint8)
print(libc.mallinfo2().hblkhd)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")
def test_large_blocks_come_from_the_heap_once_set():
    def mmapped(mode):
        out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True)
        return int(out.stdout.split()[-1])
    assert mmapped("default") >= 64 << 20          # glibc's default: the array is its own mmap
    assert mmapped("keep") < 64 << 20               # raised threshold: it comes from the heap


def test_off_glibc_it_does_nothing(monkeypatch):
    monkeypatch.setattr(runtime, "_done", False)
    monkeypatch.setattr(runtime.sys, "platform", "darwin")
    assert runtime.keep_freed_memory() is False
    monkeypatch.setattr(runtime.sys, "platform", "linux")
    monkeypatch.setattr(runtime.ctypes, "CDLL", lambda *a, **k: (_ for _ in ()).throw(OSError("no libc")))
    assert runtime.keep_freed_memory() is False
