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


# ForkedWorker / forked_workers, in a child Python (the test session runs threads, and
# forked_workers does not fork a process that does)
_FORKS = r"""
import os, signal, sys, threading, time
from pathlib import Path
from rdnet.runtime import ChildFailed, ForkedWorker, can_fork, forked_workers
out = Path(sys.argv[1])
case = sys.argv[2]
signal.alarm(60)                          # a deadlock fails the test instead of hanging it

def prepare():
    (out / f"prepared.{os.getpid()}").write_text("")

def job(name, text):
    (out / name).write_text(f"{text} {os.getpid()}")

def fail():
    raise ValueError("a job that fails")

def slow(name):
    time.sleep(30)
    (out / name).write_text("late")

if case == "jobs":
    with forked_workers(3, prepare) as ws:
        assert len(ws) == 3
        ws[0].submit(job, "a.txt", "A")
        ws[1].submit(job, "b.txt", "B")   # the third gets no job: it exits at once
    print(os.getpid())
elif case == "order":
    # the first worker's job ends while the second still waits for one: its end of file
    # must not wait for the second (which holds no copy of the first's pipe)
    with forked_workers(2) as ws:
        ws[0].submit(job, "a.txt", "A")
        ws[0].wait()
        assert (out / "a.txt").exists()
        ws[1].submit(job, "b.txt", "B")
elif case == "fails":
    try:
        with forked_workers(2) as ws:
            ws[0].submit(fail)
            ws[1].submit(job, "b.txt", "B")
    except ChildFailed as e:
        print("ChildFailed", e)
elif case == "raises":
    t = time.perf_counter()
    try:
        with forked_workers(1) as ws:
            ws[0].submit(slow, "late.txt")
            raise KeyError("the caller fails")
    except KeyError:
        print(f"killed after {time.perf_counter() - t:.1f} s")
elif case == "nice":
    def prio(name):
        (out / name).write_text(str(os.getpriority(os.PRIO_PROCESS, 0)))
    base = os.getpriority(os.PRIO_PROCESS, 0)
    with forked_workers(1, lambda: prio("prepare.txt"), nice=19) as ws:
        ws[0].submit(prio, "job.txt")
    print(base)
elif case == "threads":
    ev = threading.Event()
    th = threading.Thread(target=ev.wait)
    th.start()
    with forked_workers(2, prepare) as ws:
        print("workers", len(ws), can_fork())
    ev.set()
    th.join()
"""


def _forks(tmp_path, case):
    return subprocess.run([sys.executable, "-c", _FORKS, str(tmp_path), case], capture_output=True, text=True,
                          timeout=120)


linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork")


@linux
def test_forked_workers_run_their_jobs_in_other_processes(tmp_path):
    r = _forks(tmp_path, "jobs")
    assert r.returncode == 0, r.stderr
    parent = r.stdout.split()[-1]
    a, b = ((tmp_path / n).read_text().split() for n in ("a.txt", "b.txt"))
    assert a[0] == "A" and b[0] == "B" and len({a[1], b[1], parent}) == 3
    assert len(list(tmp_path.glob("prepared.*"))) == 3        # every worker prepared, also the idle one


@linux
def test_a_worker_ends_without_waiting_for_its_siblings(tmp_path):
    r = _forks(tmp_path, "order")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "b.txt").exists()


@linux
def test_a_failed_job_is_reported_after_every_worker_is_reaped(tmp_path):
    r = _forks(tmp_path, "fails")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ChildFailed") and "exit status 1" in r.stdout
    assert "ValueError: a job that fails" in r.stderr           # the child's traceback
    assert (tmp_path / "b.txt").exists()


@linux
def test_an_error_in_the_caller_kills_the_workers(tmp_path):
    r = _forks(tmp_path, "raises")
    assert r.returncode == 0, r.stderr
    assert float(r.stdout.split()[2]) < 10                       # not the job's 30 s
    assert not (tmp_path / "late.txt").exists()


@linux
def test_only_the_preparation_runs_niced(tmp_path):
    """The preparation yields the CPU (nice 19, capped); the job, on the caller's critical
    path, runs at the caller's own priority (Linux keeps a nice value per thread)."""
    r = _forks(tmp_path, "nice")
    assert r.returncode == 0, r.stderr
    base = int(r.stdout.split()[-1])
    assert int((tmp_path / "prepare.txt").read_text()) == min(19, base + 19)
    assert int((tmp_path / "job.txt").read_text()) == base


@linux
def test_no_fork_while_another_thread_runs(tmp_path):
    r = _forks(tmp_path, "threads")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["workers", "0", "False"]
    assert not list(tmp_path.glob("prepared.*"))
