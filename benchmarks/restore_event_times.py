"""Timestamps of the learned restorer's events (``restore.event_times``): its own output
spread over the voxel bins (``bins``) against the recording's events kept with their times
(``input``, :mod:`rdnet.events.select`). Both give the same voxel grid, so every voxel-level
score is the same; this measures what differs, on data whose true events are known.

For every row of the test split (the blurry frame and its exposure window), the study's
image-guided restorer (``models/restore_image``, seed 0) restores the row's degraded events
through :meth:`rdnet.restore.learned.LearnedRestorer.restore`, as ``rdnet restore`` does, once
per ``event_times``. Each output event is compared with the undegraded events of the same
pixel and polarity in the window (the truth): the time to the nearest one (its *timing
error*; events with no true event of their pixel and polarity in the window are counted
apart, as unmatched), and whether it is an event of the degraded input, unchanged. The
degraded input itself is scored the same way, as the reference. The restorer with
``restore.add_events: false`` (deletions only) is scored too, and every output by the
study's voxel metrics against the truth (:func:`rdnet.eval.events.match_metrics`: F1,
recall, precision, count ratio), which show what the added events are worth.

Two generators of the test split: rdnet's simulator (``data/events/test``, ``dvc repro``)
and the independent circuit model (one draw of
:func:`rdnet.study.independent.circuit_pairs`, as the ``restoration_circuit`` stage renders
it), whose truth shares no code with rdnet's simulator.

    .venv/bin/python benchmarks/restore_event_times.py     # benchmarks/results/restore_event_times.{json,md}
"""
from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from rdnet.config import load_params
from rdnet.eval.events import match_metrics, polarity_counts
from rdnet.events.core import Events
from rdnet.events.io.hdf5 import read_events
from rdnet.events.select import event_keys, event_voxels
from rdnet.restore.learned import restorer_from_checkpoint
from rdnet.restore.settings import EVENT_TIMES
from rdnet.study.data import sequences

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("restore_event_times")
#: timing-error thresholds reported as "share within"
WITHIN_US = (100, 1000)
#: the row of the learned restorer with ``restore.add_events: false`` (input times)
DELETIONS = "deletions only"


def timing_errors(events: Events, truth: Events) -> np.ndarray:
    """(n,) float64 |t - t_true| of each event to the nearest event of ``truth`` with the
    same pixel and polarity (``inf`` where there is none)."""
    if not len(events) or not len(truth):
        return np.full(len(events), np.inf)

    def keys(a: np.ndarray) -> np.ndarray:
        return (a["y"].astype(np.int64) * truth.width + a["x"].astype(np.int64)) * 2 + a["p"].astype(np.int64)

    a, u = events.array, truth.array
    ku, ka = keys(u), keys(a)
    order = np.lexsort((u["t"], ku))
    ku, tu = ku[order], u["t"][order].astype(np.int64)
    # the position of (key, t) among the truth's (key, t) pairs, then its two neighbours
    pos = np.searchsorted(ku * (1 << 40) + tu, ka * (1 << 40) + a["t"].astype(np.int64))
    err = np.full(a.size, np.inf)
    for p in (pos - 1, pos):
        ok = (p >= 0) & (p < ku.size)
        pc = np.clip(p, 0, ku.size - 1)
        same = ok & (ku[pc] == ka)
        d = np.abs(tu[pc] - a["t"].astype(np.int64)).astype(np.float64)
        err = np.where(same, np.minimum(err, d), err)
    return err


def in_input(events: Events, inputs: Events) -> np.ndarray:
    """(n,) bool: each event is an event of ``inputs`` (time, pixel and polarity)."""
    return np.isin(event_keys(events), event_keys(inputs))


def score_split(pairs: Path, events_dir: Path, checkpoint: Path, params: dict) -> dict:
    restorers = {m: restorer_from_checkpoint(checkpoint, has_frames=True, params=params, event_times=m)
                 for m in EVENT_TIMES}
    restorers[DELETIONS] = restorer_from_checkpoint(checkpoint, has_frames=True, params=params, add_events=False)
    bins = restorers["input"].bins
    files = sequences(events_dir, "test")
    acc = {k: {"err": [], "input": [], "voxels": []} for k in ("raw degraded input", *restorers)}
    with h5py.File(pairs, "r") as f:
        seq, t0s, durs = f["sequence"][:], f["t0_us"][:], f["duration_us"][:]
        blurry = f["blurry"][:]
    cache: dict[int, tuple[Events, Events]] = {}
    for r in range(seq.size):
        s = int(seq[r])
        if s not in cache:
            cache[s] = (read_events(files[s], "events"), read_events(files[s], "events_ideal"))
        deg, ideal = cache[s]
        t0, t1 = int(t0s[r]), int(t0s[r]) + int(durs[r])
        inputs, truth = deg.slice_time(t0, t1), ideal.slice_time(t0, t1)
        frame = blurry[r, 0] if blurry.shape[1] == 1 else np.moveaxis(blurry[r], 0, -1)
        outs = {"raw degraded input": inputs}
        for m, rest in restorers.items():
            outs[m] = rest.restore(deg, t0, t1, frame.astype(np.float32))
        grids = {m: np.sort(event_voxels(o, bins, t0, t1 - t0)) for m, o in outs.items() if m in EVENT_TIMES}
        if not np.array_equal(grids["input"], grids["bins"]):
            raise AssertionError(f"row {r}: the two event_times give different voxels")
        reference = polarity_counts(truth, bins, t0, t1 - t0)
        for m, o in outs.items():
            acc[m]["err"].append(timing_errors(o, truth))
            acc[m]["input"].append(in_input(o, inputs))
            acc[m]["voxels"].append((polarity_counts(o, bins, t0, t1 - t0), reference))
    out = {}
    for m, a in acc.items():
        err, inp = np.concatenate(a["err"]), np.concatenate(a["input"])
        fin = err[np.isfinite(err)]
        vox = match_metrics(np.stack([g for g, _ in a["voxels"]]), np.stack([u for _, u in a["voxels"]]))
        out[m] = {"events": int(err.size), "input_events_unchanged": float(inp.mean()) if inp.size else 0.0,
                  **{k: vox[k] for k in ("precision", "recall", "f1", "count_ratio")},
                  "with_true_event": float(fin.size / max(err.size, 1)),
                  "timing_error_median_us": float(np.median(fin)) if fin.size else None,
                  "timing_error_mean_us": float(fin.mean()) if fin.size else None,
                  **{f"within_{w}_us": float((fin <= w).mean()) if fin.size else None for w in WITHIN_US}}
        log.info("%-20s %7d events, %.1f %% unchanged input, timing error median %s us", m, err.size,
                 100 * out[m]["input_events_unchanged"], out[m]["timing_error_median_us"])
    out["rows"] = int(seq.size)
    return out


def markdown(res: dict) -> str:
    lines = ["# Timestamps of the learned restorer's events (`restore.event_times`)", "",
             "`benchmarks/restore_event_times.py`: the study's image-guided restorer (seed 0) on every row of "
             "the test split, through `LearnedRestorer.restore` as `rdnet restore` runs it; each output event "
             "against the nearest undegraded event of its pixel and polarity in the window. Both settings give "
             "the same voxels (checked per row). Last row: the same restorer with `restore.add_events: false`. "
             "Voxel F1, recall, precision and count ratio: the study's event metrics against the undegraded "
             "events (10-bin voxels of each row's window).", ""]
    for split, r in res["splits"].items():
        lines += [f"## {split} ({r['rows']} rows)", "",
                  "| events | count | input events unchanged | with a true event | timing error median (us) "
                  "| mean (us) | within 100 us | within 1 ms | voxel F1 | recall | precision | count ratio |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for m in ("raw degraded input", *EVENT_TIMES, DELETIONS):
            x = r[m]
            name = {"raw degraded input": m, DELETIONS: "restored, deletions only (`add_events: false`)"}.get(
                m, f"restored, `event_times: {m}`")
            lines.append(f"| {name} | {x['events']} | {100 * x['input_events_unchanged']:.1f} % | "
                         f"{100 * x['with_true_event']:.1f} % | {x['timing_error_median_us']:.0f} | "
                         f"{x['timing_error_mean_us']:.0f} | {100 * x['within_100_us']:.1f} % | "
                         f"{100 * x['within_1000_us']:.1f} % | {x['f1']:.3f} | {x['recall']:.3f} | "
                         f"{x['precision']:.3f} | {x['count_ratio']:.2f} |")
        lines.append("")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", type=Path, default=ROOT / "models" / "restore_image" / "seed0" / "model.pt")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_event_times.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    params = load_params(ROOT / "params.yaml")
    t = time.perf_counter()
    res = {"benchmark": "restore_event_times", "checkpoint": str(args.checkpoint.relative_to(ROOT)), "splits": {}}
    res["splits"]["simulated test split (rdnet.sim)"] = score_split(
        ROOT / "data" / "pairs" / "test.h5", ROOT / "data" / "events", args.checkpoint, params)
    with tempfile.TemporaryDirectory() as tmp:
        from rdnet.study.independent import circuit_pairs
        pairs = circuit_pairs(params, sequences(ROOT / "data" / "events", "test"), Path(tmp), 0)[0]
        res["splits"]["test split by the independent circuit generator (one draw)"] = score_split(
            pairs, Path(tmp) / "events", args.checkpoint, params)
    res["wall_s"] = time.perf_counter() - t
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    args.out.with_suffix(".md").write_text(markdown(res) + "\n")
    log.info("wrote %s and .md (%.0f s)", args.out, res["wall_s"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
