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
with ``"from_an_earlier_run": true``.

    .venv/bin/python benchmarks/bench_restore.py        # writes benchmarks/results/restore.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = {"davis346_road": ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4",
              "prophesee_evk4_night": ROOT.parent / "shared" / "real" / "prophesee_evk4_night" / "night.raw"}


def run_one(path: Path, method: str, work: Path, scores: bool = True) -> dict:
    out = work / f"{path.stem}_{method}.h5"
    cmd = [sys.executable, "-m", "rdnet.cli", "restore", str(path), str(out), "--method", method, "--no-progress",
           "--set", f"restore.scores={'true' if scores else 'false'}"]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    load = os.getloadavg()[0]
    t = time.perf_counter()
    with open(work / "stderr.txt", "w+") as err:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=err, text=True)
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
            "faster_than_realtime": dur_s / wall > 1.0, "load_average_1min_before": load}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="*", default=["raw", "baf", "stcf", "gef"])
    ap.add_argument("--recordings", nargs="*", default=list(RECORDINGS), choices=list(RECORDINGS),
                    help="which recordings (default: all)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore.json")
    ap.add_argument("--big-gb", type=float, default=0.0,
                    help="also restore (baf) a file of about this many GiB: night.raw's data repeated (0: skip)")
    args = ap.parse_args()
    results = {"benchmark": "restore", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                   "platform": platform.platform()},
               "goal": "realtime_factor > 1 on davis346_road", "load_average_1min_before": os.getloadavg()[0],
               "recordings": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name, path in RECORDINGS.items():
            if name not in args.recordings:
                continue
            if not path.is_file():
                results["recordings"][name] = {"skipped": f"{path} not present"}
                continue
            rows = []
            for m in args.methods:
                for scores in (True, False):
                    r = run_one(path, m, work, scores)
                    print(name, json.dumps(r), flush=True)
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
            print("big", json.dumps(r), flush=True)
            results["large_file"] = {"file": f"night.raw's data x {copies} (EVT 3.0)", "bytes": big.stat().st_size,
                                     "run": r}
        elif args.out.is_file():                  # keep the last --big-gb result, marked as such
            earlier = json.loads(args.out.read_text()).get("large_file")
            if earlier:
                results["large_file"] = {**earlier, "from_an_earlier_run": True}
    results["load_average_1min_after"] = os.getloadavg()[0]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(args.out, json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
