"""``restore.workers``: how many windows the learned restorer runs at once on the CPU, torch's
threads shared among them (:meth:`rdnet.restore.learned.LearnedRestorer.parallel`), measured
as a user runs it: ``rdnet restore`` in a child process (``bench_restore.run_one``), the
settings alternated run by run so that each sees the same host (these 2 shared cores drift
by 20-30 % within minutes).

Recordings, each with the restorer ``rdnet restore`` picks for it (image-guided with frames,
events-only without), scores on:

* ``davis346_x10``: the DAVIS346 road recording (346 x 260, frames) written 10 times back to
  back (``bench_restore.repeated_h5``): the steady state of issue 11's real-time goal;
* ``dvxplorer_x10``: the DVXplorer take of ``../shared/real`` (320 x 240, events only), 10 times;
* ``sparklers_x5``: the Prophesee Gen3 sparklers clip of ``../shared/real`` (640 x 480), 5 times;
* ``night``: the 10 s Prophesee EVK4 night file of ``../shared/real`` (1280 x 720) as it is.

Per run: ``restore_loop_s`` (OUT.json ``seconds``: the restore loop, scores included, after
imports and reading) and its realtime factor, the process wall time and CPU time; per
recording and setting the median over the rounds. The outputs of every setting are the same
events (checked on the first round).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_restore_workers.py --rounds 3   # writes
        benchmarks/results/restore_workers.json
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_restore import ROOT, repeated_h5, run_one  # noqa: E402

from rdnet.events.io import read_recording  # noqa: E402

log = logging.getLogger("bench_restore_workers")
SHARED = ROOT.parent / "shared" / "real"
SOURCES = {"davis346_x10": (ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4", 10),
           "dvxplorer_x10": (SHARED / "dvxplorer_person" / "dvxplorer.aedat4", 10),
           "sparklers_x5": (SHARED / "prophesee_gen3_sparklers" / "sparklers.raw", 5),
           "night": (SHARED / "prophesee_evk4_night" / "night.raw", 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="restore.workers values compared")
    ap.add_argument("--recordings", nargs="+", default=list(SOURCES), choices=list(SOURCES))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_workers.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    result = {"benchmark": "restore_workers", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                           "platform": platform.platform()},
              "command": "PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_restore_workers.py --rounds "
                         f"{args.rounds} --workers {' '.join(map(str, args.workers))}",
              "recordings": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        inputs = {}
        for name in args.recordings:
            src, copies = SOURCES[name]
            if not src.is_file():
                log.info("%s: %s not found, skipped", name, src)
                continue
            if copies > 1:
                inputs[name] = work / f"{name}.h5"
                info = repeated_h5(src, copies, inputs[name])
            else:
                inputs[name], info = src, {"copies": 1}
            result["recordings"][name] = {"source": str(src.relative_to(ROOT.parent)), **info, "runs": []}
        for rnd in range(args.rounds):
            order = args.workers if rnd % 2 == 0 else args.workers[::-1]
            for name, path in inputs.items():
                first = {}
                for w in order:
                    row = run_one(path, "rdnet", work, True, sets=(f"restore.workers={w}",))
                    if "error" in row:
                        raise RuntimeError(f"{name} workers={w}: {row['error']}")
                    row.update({"round": rnd, "workers_setting": w,
                                "restore_loop_realtime_factor": row["duration_s"] / row["restore_loop_s"]})
                    if rnd == 0:
                        first[w] = read_recording(work / f"{path.stem}_rdnet.h5").events.array
                    result["recordings"][name]["runs"].append(row)
                    log.info("%s round %d workers=%d: loop %.2f s (%.2fx real time), wall %.2f s", name, rnd, w,
                             row["restore_loop_s"], row["restore_loop_realtime_factor"], row["wall_s"])
                if first:
                    a = first[order[0]]
                    result["recordings"][name]["same_events"] = all(np.array_equal(a, b) for b in first.values())
    for name, rec in result["recordings"].items():
        summary = {}
        for w in args.workers:
            rows = [r for r in rec["runs"] if r["workers_setting"] == w]
            summary[str(w)] = {"restore_loop_s_median": float(np.median([r["restore_loop_s"] for r in rows])),
                               "restore_loop_realtime_factor_median":
                                   float(np.median([r["restore_loop_realtime_factor"] for r in rows])),
                               "wall_s_median": float(np.median([r["wall_s"] for r in rows])),
                               "restore_loop_s": [round(r["restore_loop_s"], 3) for r in rows]}
        rec["summary"] = summary
        log.info("%s: %s", name, json.dumps(summary))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
