"""Speed and memory of ``rdnet restore`` end to end (``python -m rdnet.cli restore ...`` in
a child process: imports, reading, restoring, scoring, writing): events in per second of
wall time, realtime factor (recording duration / wall time; > 1 = faster than real time)
and peak resident memory of that child process alone (``os.wait4``: its own rusage).
Each method runs twice: with the no-reference scores (the default) and with
``restore.scores=false``. ``restore_loop_s`` is the time inside the restore loop (after
imports and reading, scoring included when on), from OUT.json, with its CPU time
(``restore_loop_cpu_s``). Goal (issue 11): faster than real time on DAVIS346.

Recordings: the DAVIS346 road file (in the repo) and the 10 s Prophesee EVK4 night file
of ../shared/real (skipped with a note when absent). Methods: every classical one (gef
needs frames: on an events-only file its row records the exit-2 error); the learned one
is added with ``--methods rdnet`` once installed. The 1-minute load average is recorded
before each run (the 2 cores are shared with other jobs: wall times include waiting).
``--big-gb 2`` adds one baf run (scores off) on a multi-GB EVT 3.0 file (night.raw's data
repeated, built in a temporary folder by bench_formats.py's helper) to show that memory
does not grow with the file; without it, the out file's earlier ``large_file`` entry is kept
with ``"from_an_earlier_run": true`` (so is a recording left out with ``--recordings``).

``--steady K`` (steady-state throughput, issue 11) also restores, with each method, the
DAVIS346 recording's events and frames written to a temporary HDF5 in the project's layout
(:class:`rdnet.events.io.hdf5.H5RecordingWriter`) once and repeated ``K`` times back to back
(copy ``c`` shifted by ``c`` x the recording span, events and frames), each through the CLI
in a child process like the rows above. From the 1x and Kx walls: the cost per second of
recording (their difference over ``K - 1`` spans), the steady-state realtime factor (its
inverse) and the fixed start-up cost (imports, model loading, ...: the 1x wall minus one
span's cost); with the restore loop's own realtime factor (OUT.json) and peak RSS. The
load average is recorded before and after every run. Written to ``steady_state`` of the
out file (the earlier one kept, marked, when ``--steady`` is not given). ``--settle S``
waits up to S seconds before each run for the 1-minute load average to fall below 1 (a
run's own load takes a minute to decay), recorded as ``settle_wait_s``.

    .venv/bin/python benchmarks/bench_restore.py        # writes benchmarks/results/restore.json
    .venv/bin/python benchmarks/bench_restore.py --methods rdnet --recordings davis346_road --steady 10 \
        --settle 120 --out benchmarks/results/restore_learned_speed.json      # the learned restorer
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import machine          # benchmarks/ is on sys.path (run as a script)

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("bench_restore")
RECORDINGS = {"davis346_road": ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4",
              "prophesee_evk4_night": ROOT.parent / "shared" / "real" / "prophesee_evk4_night" / "night.raw"}


#: ``--settle``: before each run, wait up to this many seconds for the 1-minute load average
#: to fall below SETTLE_LOAD (the previous run's own load decays; 0: do not wait).
SETTLE = {"seconds": 0.0}
SETTLE_LOAD = 1.0


def settle() -> float:
    """Wait (module constants above); returns the seconds waited."""
    t = time.perf_counter()
    while os.getloadavg()[0] >= SETTLE_LOAD and time.perf_counter() - t < SETTLE["seconds"]:
        time.sleep(5.0)
    return time.perf_counter() - t


def run_one(path: Path, method: str, work: Path, scores: bool = True, root: Path = ROOT,
            sets: tuple[str, ...] = ()) -> dict:
    """One ``rdnet restore`` of ``path`` into ``work/<stem>_<method>.h5`` by the code of the
    checkout ``root`` (its working directory and first on the path), in a child process;
    ``sets``: more ``--set key=value`` overrides."""
    waited = settle() if SETTLE["seconds"] > 0 else 0.0
    out = work / f"{path.stem}_{method}.h5"
    cmd = [sys.executable, "-m", "rdnet.cli", "restore", str(path), str(out), "--method", method, "--no-progress",
           "--set", f"restore.scores={'true' if scores else 'false'}"]
    for s in sets:
        cmd += ["--set", s]
    env = {**os.environ, "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    load = os.getloadavg()[0]
    t = time.perf_counter()
    with open(work / "stderr.txt", "w+") as err:
        proc = subprocess.Popen(cmd, cwd=root, env=env, stdout=subprocess.DEVNULL, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)      # this child's own CPU time and peak RSS
        wall = time.perf_counter() - t
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        stderr = err.read()
    if proc.returncode != 0:
        return {"method": method, "error": stderr.strip().splitlines()[-1] if stderr.strip() else "failed",
                "returncode": proc.returncode}
    info = json.loads(out.with_suffix(".json").read_text())
    dur_s = info["duration_us"] * 1e-6
    return {"method": info["method"], "scores": scores, "events_in": info["events_in"], "events_out": info["events_out"],
            "duration_s": dur_s, "wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "events_per_s": info["events_in"] / wall, "realtime_factor": dur_s / wall,
            "peak_rss_mb": usage.ru_maxrss / 1024.0,
            "restore_loop_s": info["seconds"], "restore_loop_cpu_s": info["cpu_seconds"],
            "restore_loop_events_per_s": info["events_per_s"],
            "restore_loop_realtime_factor_cpu": dur_s / info["cpu_seconds"] if info["cpu_seconds"] > 0 else None,
            "faster_than_realtime": dur_s / wall > 1.0, "load_average_1min_before": load,
            **({"workers": info["workers"]} if "workers" in info else {}),
            **({"settle_wait_s": waited} if SETTLE["seconds"] > 0 else {})}


def repeated_h5(path: Path, copies: int, out: Path) -> dict:
    """Write ``path``'s events and frames ``copies`` times back to back to the HDF5 ``out``
    (copy ``c`` shifted by ``c`` x the span: first to last event or frame exposure, + 1 us).
    Returns what was written."""
    import numpy as np

    from rdnet.events.core import Events, concatenate
    from rdnet.events.io.hdf5 import H5RecordingWriter
    from rdnet.events.io.stream import open_events

    with open_events(path) as src:
        ev = concatenate(list(src.chunks(10**7)))
        frames = src.frames()
        width, height, sensor = src.width, src.height, getattr(src, "sensor", "") or ""
    t_lo, t_hi = int(ev.t[0]), int(ev.t[-1])
    if frames is not None and len(frames):
        t_lo = min(t_lo, int((frames.t_us - frames.exposure_us // 2).min()))
        t_hi = max(t_hi, int((frames.t_us - frames.exposure_us // 2 + frames.exposure_us).max()))
    span = t_hi - t_lo + 1
    with H5RecordingWriter(out, width, height, sensor) as w:
        for c in range(copies):
            arr = ev.array.copy()
            arr["t"] += c * span
            w.append_events(Events(arr, width, height, validate=False))
        if frames is not None and len(frames):
            shifts = np.repeat(np.arange(copies, dtype=np.int64) * span, len(frames))
            w.append_frames(np.concatenate([frames.images] * copies), np.tile(frames.t_us, copies) + shifts,
                            np.tile(frames.exposure_us, copies))
    return {"copies": copies, "span_us": span, "events": copies * len(ev),
            "frames": 0 if frames is None else copies * len(frames), "bytes": out.stat().st_size}


def steady_state(path: Path, methods: list[str], copies: int, work: Path) -> dict:
    """The 1x / ``copies``x runs of each method on ``path`` written as HDF5 (module docstring)."""
    files = {k: repeated_h5(path, k, work / f"{path.stem}_x{k}.h5") for k in (1, copies)}
    out = {"source": str(path.relative_to(ROOT.parent) if ROOT.parent in path.parents else path),
           "copies": copies, "span_s": files[1]["span_us"] * 1e-6,
           "inputs": {f"x{k}": v for k, v in files.items()}, "methods": {}}
    for m in methods:
        for scores in (True, False):
            rows = {}
            for k in (1, copies):
                r = run_one(work / f"{path.stem}_x{k}.h5", m, work, scores)
                r["load_average_1min_after"] = os.getloadavg()[0]
                log.info("steady x%d %s", k, json.dumps(r))
                rows[f"x{k}"] = r
            one, many = rows["x1"], rows[f"x{copies}"]
            entry = {"runs": rows}
            if "error" not in one and "error" not in many:
                per_span = (many["wall_s"] - one["wall_s"]) / (copies - 1)          # wall per recording span
                dur = (many["duration_s"] - one["duration_s"]) / (copies - 1)
                entry.update({
                    "wall_per_recording_s": per_span / dur,
                    "steady_realtime_factor": dur / per_span,
                    "fixed_startup_s": one["wall_s"] - per_span,
                    "end_to_end_realtime_factor_x1": one["realtime_factor"],
                    f"end_to_end_realtime_factor_x{copies}": many["realtime_factor"],
                    f"restore_loop_realtime_factor_x{copies}": many["duration_s"] / many["restore_loop_s"],
                    "faster_than_realtime_steady": dur / per_span > 1.0,
                    f"peak_rss_mb_x{copies}": many["peak_rss_mb"]})
            out["methods"][f"{m}{'' if scores else '_noscores'}"] = entry
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="*", default=["raw", "baf", "stcf", "gef"])
    ap.add_argument("--recordings", nargs="*", default=list(RECORDINGS), choices=list(RECORDINGS),
                    help="which recordings (default: all)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore.json")
    ap.add_argument("--big-gb", type=float, default=0.0,
                    help="also restore (baf) a file of about this many GiB: night.raw's data repeated (0: skip)")
    ap.add_argument("--steady", type=int, default=0, metavar="K",
                    help="also measure steady-state throughput on DAVIS346 repeated K times (K >= 2; 0: skip)")
    ap.add_argument("--settle", type=float, default=0.0, metavar="S",
                    help=f"before each run wait up to S seconds for the 1-minute load to fall below {SETTLE_LOAD}")
    args = ap.parse_args()
    SETTLE["seconds"] = args.settle
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.steady == 1 or args.steady < 0:
        ap.error("--steady needs K >= 2 copies (or 0)")
    earlier = json.loads(args.out.read_text()) if args.out.is_file() else {}
    results = {"benchmark": "restore", "machine": machine(),
               "goal": "realtime_factor > 1 on davis346_road", "load_average_1min_before": os.getloadavg()[0],
               "recordings": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name, path in RECORDINGS.items():
            if name not in args.recordings:
                kept = earlier.get("recordings", {}).get(name)
                if kept:                        # keep the last result, marked as such
                    results["recordings"][name] = {**kept, "from_an_earlier_run": True}
                continue
            if not path.is_file():
                results["recordings"][name] = {"skipped": f"{path} not present"}
                continue
            rows = []
            for m in args.methods:
                for scores in (True, False):
                    r = run_one(path, m, work, scores)
                    log.info("%s %s", name, json.dumps(r))
                    rows.append(r)
                    if "error" in r:
                        break
                if "error" in rows[-1] and m == args.methods[0]:
                    break                 # the file cannot be read at all
            results["recordings"][name] = {"path": str(path.relative_to(ROOT.parent) if ROOT.parent in path.parents
                                                       else path), "runs": rows}
        if args.big_gb > 0 and RECORDINGS["prophesee_evk4_night"].is_file():
            from bench_formats import _big_file          # benchmarks/ is on sys.path (run as a script)
            big, copies = _big_file(work, args.big_gb)
            r = run_one(big, "baf", work, scores=False)    # the read/restore/write path alone
            log.info("big %s", json.dumps(r))
            results["large_file"] = {"file": f"night.raw's data x {copies} (EVT 3.0)", "bytes": big.stat().st_size,
                                     "run": r}
        elif earlier.get("large_file"):           # keep the last --big-gb result, marked as such
            results["large_file"] = {**earlier["large_file"], "from_an_earlier_run": True}
        if args.steady:
            results["steady_state"] = steady_state(RECORDINGS["davis346_road"], args.methods, args.steady, work)
        elif earlier.get("steady_state"):
            results["steady_state"] = {**earlier["steady_state"], "from_an_earlier_run": True}
    results["load_average_1min_after"] = os.getloadavg()[0]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(args.out, json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
