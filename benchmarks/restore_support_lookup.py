"""The support rule's cost on the user's path: ``rdnet restore --method rdnet`` (the library
function the CLI runs, :func:`rdnet.restore.run.restore_recording`, with params.yaml's
``restore`` settings) on a real recording, with the kept voxels' neighbours read from the
input's occupancy (:func:`rdnet.nn.decision.entry_support`, the code) against the
whole-frame neighbour map read at the same voxels (:func:`rdnet.nn.decision.input_support`,
the code before session 23), alternated run by run in one process (the host's speed drifts
by 20-30 % within minutes). Both give the same events (checked).

    .venv/bin/python benchmarks/restore_support_lookup.py [--recording ../shared/real/prophesee_evk4_night/night.raw]
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

import rdnet.nn.decision as decision
from rdnet.config import load_params
from rdnet.events.io import load
from rdnet.restore.run import restore_recording

ROOT = Path(__file__).resolve().parents[1]
ENTRIES = decision.entry_support


def map_support(index: np.ndarray, shape: tuple, inputs) -> np.ndarray:
    """The whole-frame map (:func:`rdnet.nn.decision.input_support`) read at ``index``."""
    n, C, H, W = shape
    sup = decision.input_support(inputs).reshape(-1)
    index = np.asarray(index, np.int64)
    return sup[(index // (C * H * W)) * (H * W) + index % (H * W)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recording", type=Path,
                    default=ROOT.parent / "shared" / "real" / "prophesee_evk4_night" / "night.raw")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_support_lookup.json")
    args = ap.parse_args()
    params = load_params(ROOT / "params.yaml")
    runs, events = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, fn in (("entries", ENTRIES), ("whole-frame map", map_support)):
                decision.entry_support = fn
                load1 = os.getloadavg()[0]
                t = time.perf_counter()
                res = restore_recording(args.recording, Path(tmp) / f"{r}_{name[0]}.h5", params, method="rdnet",
                                        progress=False)
                wall = time.perf_counter() - t
                runs.append({"round": r, "support": name, "wall_s": wall, "restore_loop_s": res["seconds"],
                             "windows": res["windows"], "events_out": res["events_out"],
                             "load_average_1min_before": load1})
                print(json.dumps(runs[-1]), flush=True)
                if r == 0:
                    events[name] = load(Path(tmp) / f"{r}_{name[0]}.h5").events.array
        decision.entry_support = ENTRIES
    same = bool(np.array_equal(events["entries"], events["whole-frame map"]))
    mean = {n: float(np.mean([x["restore_loop_s"] for x in runs if x["support"] == n])) for n in events}
    out = {"benchmark": "restore_support_lookup", "recording": str(args.recording.resolve().relative_to(ROOT.parent)),
           "same_events": same, "runs": runs, "restore_loop_mean_s": mean}
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({"same_events": same, "restore_loop_mean_s": mean}))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
