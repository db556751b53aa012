"""Speed and memory of ``rdnet restore`` end to end (``python -m rdnet.cli restore ...`` in
a child process: imports, reading, restoring, scoring, writing): events in per second of
wall time, realtime factor (recording duration / wall time; > 1 = faster than real time)
and peak resident memory of the child (``resource.getrusage(RUSAGE_CHILDREN)``: the
maximum over the children so far, so a row's value is an upper bound for that run).
Each method runs twice: with the no-reference scores (the default) and with
``restore.scores=false``. ``restore_loop_s`` is the time inside the restore loop (after
imports and reading, scoring included when on), from OUT.json, with its CPU time
(``restore_loop_cpu_s``; the cores are shared, so wall times include waiting). Goal (issue 11): faster than real time on DAVIS346.

Recordings: the DAVIS346 road file (in the repo) and the 10 s Prophesee EVK4 night file
of ../shared/real when rdnet can read it (skipped with a note otherwise). Methods: every
classical one that fits the recording (gef only with frames); the learned one is added
with ``--methods rdnet`` once installed. The load average is recorded (2 shared cores).

    .venv/bin/python benchmarks/bench_restore.py        # writes benchmarks/results/restore.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
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
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        return {"method": method, "error": proc.stderr.strip().splitlines()[-1] if proc.stderr else "failed",
                "returncode": proc.returncode}
    info = json.loads(out.with_suffix(".json").read_text())
    dur_s = info["duration_us"] * 1e-6
    return {"method": info["method"], "scores": scores, "events_in": info["events_in"], "events_out": info["events_out"],
            "duration_s": dur_s, "wall_s": wall, "cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
            "events_per_s": info["events_in"] / wall, "realtime_factor": dur_s / wall,
            "peak_rss_mb": after.ru_maxrss / 1024.0,
            "restore_loop_s": info["seconds"], "restore_loop_cpu_s": info["cpu_seconds"],
            "restore_loop_events_per_s": info["events_per_s"],
            "restore_loop_realtime_factor_cpu": dur_s / info["cpu_seconds"] if info["cpu_seconds"] > 0 else None,
            "faster_than_realtime": dur_s / wall > 1.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="*", default=["raw", "baf", "stcf", "gef"])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore.json")
    args = ap.parse_args()
    results = {"benchmark": "restore", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                   "platform": platform.platform()},
               "goal": "realtime_factor > 1 on davis346_road", "load_average_1min_before": os.getloadavg()[0],
               "recordings": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name, path in RECORDINGS.items():
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
    results["load_average_1min_after"] = os.getloadavg()[0]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(args.out, json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
