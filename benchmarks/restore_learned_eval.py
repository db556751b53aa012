"""Event-level evaluation of the learned restorers (issue 11, items 1 and 4).

1. Held-out simulated test split (a pairs file with per-polarity voxels): for each
   RestoreNet checkpoint and for the raw degraded events, over every test row at full
   frame: event precision / recall / F1 matched per voxel and polarity against the
   undegraded events (:func:`rdnet.eval.events.match_metrics`), count ratio restored /
   undegraded, signed-voxel L1 over all voxels and over event voxels (where the degraded
   or undegraded voxel is non-zero). Restored events are the checkpoint's stored decision
   applied to its output (counts: fitted occupancy threshold; signed: rounding).
2. A real recording with frames (DAVIS346): each restorer run window by window between
   consecutive frames (:mod:`rdnet.restore.learned`, frame k guiding [t_k, t_k+1)); event
   count restored / raw and the event-frame consistency (r2_fitted,
   :func:`rdnet.deblur.consistency.compare_consistency`, as ``rdnet deblur`` scores it:
   raw and one restored stream at a time).

    PYTHONPATH=$PWD python benchmarks/restore_learned_eval.py --pairs /tmp/learned_pairs/test.h5 \\
        --ckpt counts-image=/tmp/lt/restore_image/model.pt --ckpt ... --out benchmarks/results/restore_learned.json
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from rdnet.config import load_params, section
from rdnet.eval.events import match_metrics
from rdnet.nn.decision import decide_counts, decision_gain, polarity_grid, split_signed, support_applies
from rdnet.train import checkpoint as ckpt_mod
from rdnet.train.data import PairsDataset
from rdnet.train.loop import predict_counts

log = logging.getLogger("restore_learned_eval")


def pair_metrics(restored_counts: np.ndarray, target_counts: np.ndarray, degraded_counts: np.ndarray) -> dict:
    """Metrics of per-polarity (N, 2 * bins, H, W) count grids (module docstring)."""
    b = restored_counts.shape[1] // 2
    signed = lambda c: c[:, :b].astype(np.float64) - c[:, b:]  # noqa: E731
    r, u, d = signed(restored_counts), signed(target_counts), signed(degraded_counts)
    ev = (u != 0) | (d != 0)
    m = match_metrics(polarity_grid(restored_counts), polarity_grid(target_counts))
    out = {k: m[k] for k in ("precision", "recall", "f1", "count_ratio")}
    out["l1_all"] = float(np.abs(r - u).mean())
    out["l1_events"] = float(np.abs(r - u)[ev].mean())
    out["events"] = int(restored_counts.sum())
    return out


def stcf_counts(pairs: Path, events_dir: Path, split: str, filters: dict) -> np.ndarray:
    """Per-polarity (N, 2 * bins, H, W) counts of the degraded events of every pairs row after
    STCF (the study's ``ablation.filters`` settings), run on each whole degraded sequence
    (``events_dir/<split>/seq_*.h5``, row ``sequence`` = file index, as the blur step
    numbers them); checks that the unfiltered stream reproduces the stored counts."""
    import h5py
    from rdnet.baselines.stcf import stcf_filter
    from rdnet.events.io.hdf5 import read_events
    from rdnet.events.voxel import voxel_grid
    from rdnet.study.data import sequences

    files = sequences(events_dir, split)
    with h5py.File(pairs, "r") as f:
        seq, t0, dur = f["sequence"][...], f["t0_us"][...], f["duration_us"][...]
        bins, mode = int(f.attrs["bins"]), str(f.attrs["voxel_mode"])
        on0, off0 = f["voxel_degraded_on"][0], f["voxel_degraded_off"][0]
    out, cache = [], {}
    for i in range(seq.size):
        if int(seq[i]) not in cache:
            ev = read_events(files[int(seq[i])])
            if i == 0:
                g = voxel_grid(ev, bins, int(t0[0]), int(dur[0]), mode=mode, polarity="split")
                if not (np.array_equal(g[0], on0) and np.array_equal(g[1], off0)):
                    raise SystemExit(f"{files[0]} does not reproduce row 0 of {pairs}")
            cache = {int(seq[i]): stcf_filter(ev, filters["stcf_tau_us"], filters["stcf_k"], filters["stcf_radius"])}
        g = voxel_grid(cache[int(seq[i])], bins, int(t0[i]), int(dur[i]), mode=mode, polarity="split")
        out.append(g.reshape(2 * bins, *g.shape[-2:]))
    return np.stack(out)


def stored_decision(decision: dict, out: np.ndarray, prob: np.ndarray, support: np.ndarray) -> np.ndarray:
    """Per-polarity counts of a count network's heads under its checkpoint's ``decision``
    (fitted threshold, the support rule when it applies, the count gain)."""
    return decide_counts(out, prob, float(decision["threshold"]), support if support_applies(decision) else None,
                         decision_gain(decision))


def eval_pairs(pairs: Path, ckpts: dict[str, Path], also_thresholds=(), stcf: np.ndarray | None = None,
               guide=None) -> dict:
    """The metrics of :func:`pair_metrics` for the raw degraded events, ``stcf`` (counts, when
    given) and each checkpoint at its stored decision (and at ``also_thresholds``).
    ``guide``: the frame-pair guide (:class:`rdnet.nn.guide.FramePairGuide`) every checkpoint
    reads, for ``restore_frames`` networks."""
    data = PairsDataset(pairs, crop=None, augment=False, guide=guide)
    rows = [data[i] for i in range(len(data))]
    target = np.stack([r["counts_undegraded"].numpy() for r in rows])
    degraded = np.stack([r["counts_degraded"].numpy() for r in rows])
    res = {"raw": pair_metrics(degraded, target, degraded)}
    res["raw"]["undegraded_events"] = int(target.sum())
    if stcf is not None:
        res["stcf"] = pair_metrics(stcf, target, degraded)
        log.info("stcf: %s", res["stcf"])
    for name, path in ckpts.items():
        ck = ckpt_mod.read_checkpoint(path)
        net = ckpt_mod.model_from_checkpoint(path, ck).eval()
        out, prob, _, support = predict_counts(net, data, torch.device("cpu"), image=net.image_channels > 0,
                                               with_support=True)
        if net.output == "counts":
            decision = ck["extra"]["decision"]
            thr = float(decision["threshold"])
            restored = stored_decision(decision, out, prob, support)
            for t in also_thresholds:      # the same network with another (not fitted) threshold
                res[f"{name}@{t}"] = {**pair_metrics(decide_counts(out, prob, t), target, degraded), "threshold": t}
        else:
            thr = None
            restored = split_signed(np.rint(out), axis=1)
        res[name] = pair_metrics(restored, target, degraded)
        res[name]["threshold"] = thr
        res[name]["val_metrics"] = ck["extra"].get("decision", {}).get("val_metrics")
        res[name]["checkpoint"] = str(path)
        log.info("%s: %s", name, {k: v for k, v in res[name].items() if isinstance(v, float)})
    data.close()
    return res


def eval_real(recording: Path, ckpts: dict[str, Path], params: dict) -> dict:
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    from rdnet.events.core import concatenate
    from rdnet.events.io import load as load_recording
    from rdnet.restore.learned import restorer_from_checkpoint

    rec = load_recording(recording)
    ev, frames = rec.events, rec.frames
    s = section(params, "sensor")
    streams, info = {"raw": ev.slice_time(int(frames.t_us[0]), int(frames.t_us[-1]))}, {}
    for name, path in ckpts.items():
        r = restorer_from_checkpoint(path, has_frames=True, params=params)
        t = frames.t_us.astype(np.int64)
        start = time.perf_counter()
        parts = [r.restore(ev, int(t[k]), int(t[k + 1]), frames.images[k]) for k in range(len(t) - 1)]
        streams[name] = concatenate(parts, sort=True)
        info[name] = {"seconds": time.perf_counter() - start}
    raw_in = streams["raw"]
    lf = LogFrames.of(frames, ev, s.log_eps)
    out = {"raw": {"events": len(raw_in), "count_ratio_vs_raw": 1.0}}
    for name, restored in streams.items():
        if name == "raw":
            continue
        # scored as rdnet deblur scores it: raw and this stream alone (the pixel-intervals
        # scored are the union of the two streams' active ones)
        sc = compare_consistency(lf, {"raw": raw_in, name: restored}, s.threshold_on, s.threshold_off)
        out[name] = {"events": len(restored), "count_ratio_vs_raw": len(restored) / max(len(raw_in), 1),
                     "r2_fitted": sc[name]["r2_fitted"], "r2_nominal": sc[name]["r2_nominal"],
                     "raw_r2_fitted": sc["raw"]["r2_fitted"], "raw_r2_nominal": sc["raw"]["r2_nominal"],
                     **info[name]}
        log.info("%s: %s", name, out[name])
    return out


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pairs", type=Path, required=True)
    p.add_argument("--ckpt", action="append", default=[], help="NAME=PATH (repeatable)")
    p.add_argument("--real", type=Path, default=Path("data/real/davis346_road/davis346.aedat4"))
    p.add_argument("--no-real", dest="real", action="store_const", const=None, help="skip the real recording")
    p.add_argument("--real-ckpt", action="append", default=None, help="names of --ckpt run on --real (default all)")
    p.add_argument("--also-threshold", type=float, action="append", default=[],
                   help="also score count networks at this occupancy threshold (e.g. 0.5)")
    p.add_argument("--events-dir", type=Path, default=None,
                   help="simulated sequences of the pairs file (data/events): adds the STCF baseline")
    p.add_argument("--params", type=Path, default=Path("params.yaml"))
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args()
    torch.set_num_threads(1)
    ckpts = dict(c.split("=", 1) for c in a.ckpt)
    ckpts = {k: Path(v) for k, v in ckpts.items()}
    params = load_params(a.params)
    stcf = None
    if a.events_dir is not None:
        import h5py
        with h5py.File(a.pairs, "r") as f:
            split = str(f.attrs["split"])
        stcf = stcf_counts(a.pairs, a.events_dir, split, params["ablation"]["filters"])
    res = {"pairs": str(a.pairs), "test": eval_pairs(a.pairs, ckpts, a.also_threshold, stcf)}
    real = {k: v for k, v in ckpts.items() if a.real_ckpt is None or k in a.real_ckpt}
    if a.real is not None:
        res["real"] = {"recording": str(a.real), **eval_real(a.real, real, params)}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
