"""``rdnet`` command line. Each subcommand is a module with ``register(subparsers)``;
:data:`COMMANDS` lists them in help order (short names live in this package).

User errors (:class:`rdnet.errors.RdnetError`) print one line and exit with code 2.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import logging
import os
import signal
import sys
import threading

from rdnet import __version__
from rdnet.errors import RdnetError, escape_controls

COMMANDS = ["info", "convert", "simulate", "calibrate", "restore", "deblur", "rdnet.train.run"]

log = logging.getLogger("rdnet")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rdnet", description="Simulate, restore and deblur with real-world degraded events.")
    parser.add_argument("--version", action="version", version=f"rdnet {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        mod = name if "." in name else f"rdnet.cli.{name}"
        importlib.import_module(mod).register(sub)
    return parser


class Terminated(BaseException):
    """SIGTERM (``kill``, a job scheduler's time limit) turned into an exception, so the
    temporary outputs are removed on the way out as they are for Ctrl-C."""


def _terminate(signum, frame):
    raise Terminated()


@contextlib.contextmanager
def _sigterm_raises():
    """Within: SIGTERM raises :class:`Terminated` (main thread only; elsewhere unchanged)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        with _sigterm_raises():
            rc = args.func(args)
    except RdnetError as e:
        print(f"rdnet {args.command}: error: {escape_controls(str(e))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("terminated", file=sys.stderr)
        return 143
    except BrokenPipeError:
        # the reader of stdout went away (`rdnet info rec.h5 | head -1`): as a Unix tool does,
        # stop quietly; stdout is pointed at /dev/null so the interpreter's final flush
        # does not raise again
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (AttributeError, OSError, ValueError):   # a stdout that is no file (tests, embedding)
            pass
        return 141
    return int(rc or 0)


def _before_numpy(name: str, value: str) -> bool:
    """Set the environment variable ``name`` to ``value`` for the libraries numpy loads, unless
    the user set it (their choice stands) or numpy is already imported (the variable is read
    at that import); True when ``name`` is ``value`` for this process."""
    if name in os.environ or "numpy" in sys.modules:
        return os.environ.get(name) == value
    os.environ[name] = value
    return True


#: numpy's transparent-huge-page advice for the console script: off unless the user's
#: environment says otherwise (:func:`small_pages`)
HUGEPAGE_ENV = "NUMPY_MADVISE_HUGEPAGE"


def small_pages() -> bool:
    """Ask numpy not to advise transparent huge pages for its large arrays, unless
    ``NUMPY_MADVISE_HUGEPAGE`` is already set (then the user's choice stands) or numpy is
    already imported (it reads the variable once, at import); True when the advice is off
    for this process. Why: where the kernel backs an advised region with a fresh 2 MB page on
    its first touch (``transparent_hugepage/defrag: madvise``, the default of many
    distributions), and most of all in a virtual machine whose memory the host fills in
    lazily, each such page costs far more than the 512 small pages it replaces, which the
    kernel recycles from memory the process freed: a 50 MB numpy array took 176 ms to fill
    the first time with the advice and 28-39 ms without it on the project's 2-core host,
    and ``rdnet calibrate`` spent 2.0-2.6 s of system time against 1.2-1.4 s
    (docs/benchmarks.md, "Huge pages")."""
    return _before_numpy(HUGEPAGE_ENV, "0")


#: OpenBLAS's thread count for the console script: 1 unless the user's environment says
#: otherwise (:func:`single_thread_blas`)
OPENBLAS_ENV = "OPENBLAS_NUM_THREADS"


def single_thread_blas() -> bool:
    """Ask numpy's and scipy's OpenBLAS libraries for one thread, unless
    ``OPENBLAS_NUM_THREADS`` is already set (the user's choice stands) or numpy is already
    imported (OpenBLAS reads the variable when it loads); True when BLAS runs single-threaded
    for this process. Why: each OpenBLAS library starts a thread per further core when it
    loads, and that thread spins for about 0.1 s before it sleeps. rdnet's numpy work has no
    large matrix products (the largest are a colour-to-grey dot product and small (S, K)
    aggregations), so the threads never pay for themselves; ``rdnet calibrate`` loads both
    libraries (scipy's through numba's first compilation, mid-run, while the calibration
    keeps both cores busy) and spent 0.2 s of CPU in their spinning (``perf``, session 55;
    docs/benchmarks.md, "OpenBLAS threads"). Torch uses its own oneMKL, which this leaves
    alone."""
    return _before_numpy(OPENBLAS_ENV, "1")


def entry() -> None:
    """The ``rdnet`` console script (and ``python -m rdnet.cli``): :func:`main`, then exit.
    Numpy's huge-page advice is turned off first (:func:`small_pages`), and OpenBLAS asked
    for one thread (:func:`single_thread_blas`). Before the
    interpreter shuts down, every live object is moved out of the garbage collector's reach
    (``gc.freeze``): the shutdown otherwise spends its time collecting the objects of a
    process that is about to end (0.3-0.5 s after ``rdnet calibrate``, about a tenth of its
    run; ``benchmarks/results/calibrate.json``). Everything the command wrote is closed and
    renamed by then, and atexit handlers still run. In-process callers (tests, notebooks)
    call :func:`main`, which leaves both alone."""
    small_pages()
    single_thread_blas()
    rc = main()
    gc.freeze()
    sys.exit(rc)


if __name__ == "__main__":  # pragma: no cover
    entry()
