"""Process-level settings: memory reuse for long CPU inference runs, and short work
forked beside the main process (:class:`ForkedWorker`).

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

import contextlib
import ctypes
import ctypes.util
import logging
import os
import signal
import sys
from typing import Callable, Iterator

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


class ChildFailed(RuntimeError):
    """A :class:`ForkedWorker` exited with an error (its traceback went to stderr)."""


def can_fork() -> bool:
    """Whether :func:`forked_workers` forks here and now: on Linux only (macOS's system
    libraries are not safe to use in a forked child of a threaded process; Windows has no
    fork), and only while this process runs no other Python thread (a lock another thread
    holds at the fork stays locked in the child for ever; a test session or a notebook that
    ran thread pools before gets no fork, and the caller does the work itself)."""
    import threading
    return sys.platform.startswith("linux") and hasattr(os, "fork") and threading.active_count() == 1


def _run_niced(fn: Callable[[], object], nice: int) -> None:
    """``fn()`` in a thread of niceness ``nice`` (Linux keeps a nice value per thread), so
    that only this preparation yields the CPU: the job that follows runs in the calling
    thread at its own priority, also on a machine that other work keeps busy (a process
    cannot lower its niceness again)."""
    if not nice:
        fn()
        return
    import threading
    failed: list[BaseException] = []

    def run() -> None:
        try:
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, 0, min(19, os.getpriority(os.PRIO_PROCESS, 0) + nice))
            fn()
        except BaseException as e:             # raised again in the calling thread
            failed.append(e)

    th = threading.Thread(target=run, name="rdnet-prepare")
    th.start()
    th.join()
    if failed:
        raise failed[0]


class ForkedWorker:
    """A child process forked now that runs ``prepare()`` at once, then waits for one job,
    ``fn(*args)``, sent by :meth:`submit` (pickled through a pipe), and exits.

    For short work that holds the GIL and leaves only files, such as drawing figures with
    matplotlib: forked before a long computation, the child imports what it needs on the
    core the computation leaves idle, where an import thread would take the GIL from the
    computation's own Python code (measured on ``rdnet calibrate``: as slow as importing
    afterwards); several children then draw side by side. ``nice``: the niceness increment
    of ``prepare`` (19: it runs only on CPU time nobody else wants, as a preparation beside
    the parent's computation should); it runs in a thread of its own, so the job, on the
    critical path, runs at the parent's priority. The child is a copy of this
    process at the fork, so fork before other threads start (nothing of numba's or
    OpenCV's pools is usable there). It ignores Ctrl-C (the parent kills it, see
    :func:`forked_workers`) and leaves by ``os._exit``, running no atexit handler and
    flushing none of the parent's buffers."""

    #: the write ends of the pipes of this process's workers still waiting for a job
    _parent_ends: set[int] = set()

    def __init__(self, prepare: Callable[[], object] | None = None, *, nice: int = 0):
        for stream in (sys.stdout, sys.stderr):    # nothing the parent buffered is written twice
            with contextlib.suppress(AttributeError, OSError, ValueError):
                stream.flush()
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:
            # this end, and those of workers forked before: a job's end of file comes when
            # the parent closes it, not when a sibling that holds a copy exits
            for fd in (w, *ForkedWorker._parent_ends):
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._child(r, prepare, nice)        # never returns
        os.close(r)
        ForkedWorker._parent_ends.add(w)
        self.pid: int | None = pid
        self._w: int | None = w

    @staticmethod
    def _child(r: int, prepare, nice: int) -> None:
        code = 1
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            if prepare is not None:
                _run_niced(prepare, nice)
            with os.fdopen(r, "rb") as f:
                data = f.read()                  # until the parent closes its end
            if data:                             # nothing sent: the parent did not need us
                import pickle
                fn, args = pickle.loads(data)
                fn(*args)
            code = 0
        except BaseException:
            import traceback
            traceback.print_exc()
        finally:
            with contextlib.suppress(BaseException):
                sys.stderr.flush()
            os._exit(code)

    def submit(self, fn: Callable, *args) -> None:
        """Send the job (``fn`` and ``args`` must pickle; ``fn`` by reference, so a function
        of a module). At most once; :meth:`wait` for it."""
        import pickle
        if self._w is None:
            raise RuntimeError("this worker has its job already")
        data = pickle.dumps((fn, args), protocol=pickle.HIGHEST_PROTOCOL)
        w = self._take_write_end()
        try:
            with os.fdopen(w, "wb") as f:
                f.write(data)
        except BrokenPipeError:                  # the child died first: wait() says how
            pass

    def _take_write_end(self) -> int | None:
        """This worker's end of the job pipe, no longer this object's nor a later fork's to
        close (None when taken already)."""
        w, self._w = self._w, None
        ForkedWorker._parent_ends.discard(w)
        return w

    def _close_write_end(self) -> None:
        w = self._take_write_end()
        if w is not None:
            with contextlib.suppress(OSError):
                os.close(w)

    def wait(self) -> None:
        """Wait for the child (without a job it exits at once); :class:`ChildFailed` if it
        failed."""
        self._close_write_end()
        if self.pid is None:
            return
        _, status = os.waitpid(self.pid, 0)
        self.pid = None
        code = os.waitstatus_to_exitcode(status)
        if code != 0:
            raise ChildFailed(f"a forked worker failed (exit status {code}; its traceback is above)")

    def kill(self) -> None:
        """Stop the child now and reap it (on the way out of an error)."""
        self._close_write_end()
        if self.pid is not None:
            with contextlib.suppress(OSError):
                os.kill(self.pid, signal.SIGKILL)
                os.waitpid(self.pid, 0)
            self.pid = None


@contextlib.contextmanager
def forked_workers(n: int, prepare: Callable[[], object] | None = None, *,
                   nice: int = 0) -> Iterator[list[ForkedWorker]]:
    """``n`` :class:`ForkedWorker` (none where :func:`can_fork` is false: the caller then
    does the work itself). Leaving the block waits for every
    worker (:class:`ChildFailed` after all are reaped if one failed); leaving it by an
    exception kills them first, so no file is written after the caller's clean-up."""
    workers = [ForkedWorker(prepare, nice=nice) for _ in range(n)] if n > 0 and can_fork() else []
    try:
        yield workers
    except BaseException:
        for w in workers:
            w.kill()
        raise
    failed = None
    for w in workers:
        try:
            w.wait()
        except ChildFailed as e:
            failed = failed or e
    if failed is not None:
        raise failed
