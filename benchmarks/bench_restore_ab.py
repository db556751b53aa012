"""A/B of ``rdnet restore --method rdnet`` between this checkout and another one (a git
worktree of an earlier commit), runs alternated so that both see the same host: on these
shared 2 cores the speed of one code drifts by 20-30 % within minutes, more than most
changes it is meant to show.

Each round restores the DAVIS346 recording written once (x1) and ``K`` times back to back
(xK, as ``bench_restore.py --steady``) with the old and the new code, each in a child
process started in its own checkout (``python -m rdnet.cli`` run in that checkout, with it
first on the path: ``bench_restore.run_one``). Per round and code: the walls, the
steady-state cost per second of recording ``(wall_xK - wall_x1) / ((K - 1) span)`` and its realtime factor (inverse). The
outputs of the two codes are compared event for event on the x1 file.

    git worktree add /tmp/old <rev>
    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_restore_ab.py --old /tmp/old --rounds 4 \\
        --out benchmarks/results/restore_learned_speed_ab.json
    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_restore_ab.py --old /tmp/old --rounds 2 \\
        --recording prophesee_evk4_night --out benchmarks/results/restore_learned_speed_ab_night.json
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_restore import RECORDINGS, ROOT, repeated_h5, run_one  # noqa: E402

log = logging.getLogger("bench_restore_ab")


def _rev(root: Path) -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                          text=True).stdout.strip() or "?"


def _wall(row: dict) -> float:
    """The wall seconds of a :func:`bench_restore.run_one` row (its error raised)."""
    if "error" in row:
        raise RuntimeError(f"rdnet restore failed: {row['error']}")
    return row["wall_s"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", type=Path, required=True, help="checkout of the code to compare against")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--copies", type=int, default=10)
    ap.add_argument("--recording", choices=sorted(RECORDINGS), default="davis346_road",
                    help="davis346_road: x1 / xK steady state; any other: the file itself, end to end")
    ap.add_argument("--no-scores", action="store_true", help="restore.scores=false")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_learned_speed_ab.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.copies < 2:
        ap.error("--copies needs at least 2")
    codes = {"old": args.old.resolve(), "new": ROOT}
    steady = args.recording == "davis346_road"
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in codes:
            (work / name).mkdir()
        if steady:
            files = {k: repeated_h5(RECORDINGS[args.recording], k, work / f"x{k}.h5") for k in (1, args.copies)}
            span_s = files[1]["span_us"] * 1e-6
            inputs = {1: work / "x1.h5", args.copies: work / f"x{args.copies}.h5"}
        else:
            from rdnet.events.io.stream import open_events
            with open_events(RECORDINGS[args.recording]) as src:
                t = np.concatenate([c.t for c in src.chunks(10**7)])
            span_s = (int(t[-1]) - int(t[0])) * 1e-6
            inputs = {1: RECORDINGS[args.recording]}
        rounds = []
        for r in range(args.rounds):
            row = {"load_average_1min_before": os.getloadavg()[0]}
            for name, root in codes.items():
                walls = {k: _wall(run_one(f, "rdnet", work / name, not args.no_scores, root=root))
                         for k, f in inputs.items()}
                if steady:
                    per_s = (walls[args.copies] - walls[1]) / ((args.copies - 1) * span_s)
                else:
                    per_s = walls[1] / span_s
                row[name] = {**{f"wall_x{k}_s": w for k, w in walls.items()},
                             "seconds_per_recording_second": per_s, "realtime_factor": 1.0 / per_s}
                log.info("round %d %s: %s, %s realtime factor %.2fx", r, name,
                         ", ".join(f"x{k} {w:.2f} s" for k, w in walls.items()),
                         "steady" if steady else "end-to-end", 1.0 / per_s)
            rounds.append(row)
        from rdnet.events.io.hdf5 import read_events
        a, b = (read_events(work / n / f"{inputs[1].stem}_rdnet.h5").array for n in codes)
        same = bool(a.shape == b.shape and np.array_equal(a, b))

    def summary(name):
        f = [r[name]["realtime_factor"] for r in rounds]
        return {"realtime_factor_min": min(f), "realtime_factor_median": float(np.median(f)),
                "realtime_factor_max": max(f),
                "seconds_per_recording_second_mean": float(np.mean([r[name]["seconds_per_recording_second"]
                                                                    for r in rounds]))}
    result = {"benchmark": "restore_ab", "recording": args.recording,
              "realtime_factor": "steady state (x1 / xK)" if steady else "end to end (the file once)",
              **({"copies": args.copies} if steady else {}), "span_s": span_s,
              "scores": not args.no_scores, "old": {"path": str(args.old), "commit": _rev(codes["old"])},
              "new": {"commit": _rev(ROOT)}, "machine": {"cpus": os.cpu_count()},
              "same_events": same, "events": {"old": int(a.size), "new": int(b.size)},
              "rounds": rounds, "summary": {n: summary(n) for n in codes}}
    if args.out.exists():               # earlier runs against the same old commit, same setting: kept
        try:
            before = json.loads(args.out.read_text())
        except ValueError:
            before = {}
        if all(before.get(k) == result.get(k) for k in ("recording", "scores", "copies")) and \
                before.get("old", {}).get("commit") == result["old"]["commit"]:
            earlier = before.pop("earlier_runs", [])
            result["earlier_runs"] = earlier + [{"new_commit": before.get("new", {}).get("commit"),
                                                 **{k: before[k] for k in ("rounds", "summary", "same_events")
                                                    if k in before}}]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = args.out.with_suffix(".json.tmp")
    tmp_out.write_text(json.dumps(result, indent=2) + "\n")
    tmp_out.replace(args.out)
    log.info("old %s / new %s: realtime factor %s; same events %s", result["old"]["commit"], result["new"]["commit"],
             {n: round(v["realtime_factor_median"], 2) for n, v in result["summary"].items()}, same)


if __name__ == "__main__":
    main()
