"""Can the frames tell the restorer how many events its window lost? (issue 11, a check)

docs/restoration.md ends its account of the count-ratio goal with "meeting both would need
the restorer to be told how much its recording lost": a network that sees one blurry image
and the degraded events of a window cannot tell a stream that lost half its events from one
that lost none, so it puts back what its training degradations (0.5-0.9x) taught it, and
the stronger test degradations (1.0-1.5x) come out at 0.6-0.7 of the undegraded count.

The two sharp frames that bracket a window carry exactly that information for an ideal
sensor: a pixel whose log intensity rose by ``dL`` over the window fired at least
``dL / C`` net ON events (``C`` the contrast threshold), whatever the degradation did. A
DAVIS camera records such frames; the study's pairs hold them (the first and the last frame
of each blur window). This script retrains the study's image-guided count stage 1 (its
``params.yaml`` recipe, 800 iterations, one thread per training) with a two-channel image,
and scores it on the study's unchanged test rows (the same two channels):

- ``pair``: the blurry image and ``(log(I_last + eps) - log(I_first + eps)) / C`` (``eps``
  = ``sensor.log_eps``, ``C`` = ``sensor.threshold_on``): the net ON-minus-OFF count an
  ideal pixel fires over the window;
- ``control``: the blurry image and a channel of zeros (the same network shape and
  initialisation draw, no information added).

Metrics as ``benchmarks/restore_train_range.py`` (``restore_learned_eval.eval_pairs``):
event precision / recall / F1 per voxel and polarity, count ratio, signed-voxel L1 over all
voxels and over event voxels; the study's own restorer (``models/restore_image``) beside
them. ``--circuit`` also scores on the test sequences rendered by the independent circuit
generator (one draw), the frames being the same scenes' frames.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_frame_pair.py   # needs dvc repro blur
        writes benchmarks/results/restore_frame_pair.{json,md}
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
METRICS = ("precision", "recall", "f1", "count_ratio", "l1_all", "l1_events")
VARIANTS = ("pair", "control")
log = logging.getLogger("restore_frame_pair")


def window_frames(pairs: Path, events_dir: Path, split: str) -> tuple[np.ndarray, np.ndarray]:
    """(first, last): (N, H, W) float32 linear grey frames at each pairs row's window start
    ``t0_us`` and end ``t0_us + duration_us`` (the blur window's first and last frame),
    read from the sequence files the blur step made the rows from."""
    import h5py
    from rdnet.events.io import read_recording
    from rdnet.study.data import sequences

    files = sequences(events_dir, split)
    with h5py.File(pairs, "r") as f:
        seq, t0, dur = f["sequence"][...], f["t0_us"][...], f["duration_us"][...]
    first, last, cache = [], [], {}
    for s, a, d in zip(seq, t0, dur):
        if int(s) not in cache:
            fr = read_recording(files[int(s)]).require_frames(str(files[int(s)]))
            cache = {int(s): (fr.grey(), fr.t_us)}
        grey, t = cache[int(s)]
        i0, i1 = np.searchsorted(t, [a, a + d])
        if t[i0] != a or t[i1] != a + d:
            raise SystemExit(f"{files[int(s)]}: no frame at {a} or {a + d} us")
        first.append(grey[i0])
        last.append(grey[i1])
    return np.stack(first), np.stack(last)


def copy_pairs(src: Path, dst: Path, replace) -> Path:
    """A copy of the pairs file ``src`` (attributes and datasets) in which ``replace(f, name)``
    gives each dataset's new content, or None to copy it as it is."""
    import h5py

    dst.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(src, "r") as f, h5py.File(dst, "w") as g:
        for k, v in f.attrs.items():
            g.attrs[k] = v
        for name in f:
            new = replace(f, name)
            if new is None:
                f.copy(name, g)
            else:
                g[name] = new
    return dst


def with_channel(src: Path, dst: Path, extra: np.ndarray) -> Path:
    """A copy of the pairs file ``src`` whose ``blurry`` and ``sharp`` images carry ``extra``
    (N, H, W) as a second channel (stage 1 reads ``blurry``; ``sharp`` only has to match)."""
    import h5py
    copy_pairs(src, dst, lambda f, name: np.concatenate([f[name][...], extra[:, None].astype(np.float32)], axis=1)
               if name in ("blurry", "sharp") else None)
    with h5py.File(dst, "a") as g:
        g.attrs["channels"] = 2
    return dst


def as_identity(src: Path, dst: Path) -> Path:
    """A copy of the pairs file ``src`` whose degraded voxels are its undegraded ones: a
    stream that needs no restoring (a restorer should hand it back as it is)."""
    return copy_pairs(src, dst, lambda f, name: f[name.replace("degraded", "undegraded", 1)][...]
                      if name.startswith("voxel_degraded") else None)


def guide_of(params: dict):
    """The frame-pair guide of the study's sensor (:class:`rdnet.nn.guide.FramePairGuide`):
    its ``change`` is the second channel of ``pair``."""
    from rdnet.nn.guide import FramePairGuide
    return FramePairGuide(float(params["sensor"]["log_eps"]), float(params["sensor"]["threshold_on"]))


def frame_change(pairs: Path, events_dir: Path, split: str, params: dict) -> np.ndarray:
    """``(log(I_last + eps) - log(I_first + eps)) / C`` of every row (module docstring)."""
    return guide_of(params).change(*window_frames(pairs, events_dir, split))


def bound_check(pairs: Path, change: np.ndarray) -> dict:
    """How well ``change`` predicts the undegraded (and the degraded) net count per pixel:
    the mean absolute difference, and the share of pixels whose net count it gets within
    one event."""
    import h5py
    out = {}
    with h5py.File(pairs, "r") as f:
        for kind in ("undegraded", "degraded"):
            net = (f[f"voxel_{kind}_on"][...].sum(1) - f[f"voxel_{kind}_off"][...].sum(1)).astype(np.float64)
            err = np.abs(net - change)
            out[kind] = {"mean_abs_diff": float(err.mean()), "within_1": float((err <= 1.0).mean()),
                         "events_per_row": float((f[f"voxel_{kind}_on"][...].sum() + f[f"voxel_{kind}_off"][...].sum())
                                                 / net.shape[0])}
    out["sum_abs_change_per_row"] = float(np.abs(change).sum() / change.shape[0])
    return out


def real_streams(recording: Path, ckpts: dict[str, tuple[Path, str]], params: dict, step: int, *,
                 guide_threshold: float | None = None) -> dict:
    """Every restorer of ``ckpts`` (name: (checkpoint, guide)) on a recording with frames,
    in windows from frame ``k`` to frame ``k + step`` (``step`` 1: consecutive frames; 2:
    every other frame hidden from the restorers). ``guide``: ``frame`` (the window's first
    frame, as the study's restorer reads it), ``pair`` (that frame and the log change to
    the window's last frame over the nominal threshold), ``zeros`` (that frame and a
    channel of zeros) or ``library`` (a ``restore_frames`` checkpoint, handed the window's
    two frames as ``rdnet restore`` hands them; ``guide_threshold``: ``restore.guide_threshold``).
    Returns the streams, ``raw`` included (the events between the first and the last frame used)."""
    from rdnet.events.core import concatenate
    from rdnet.events.io import load as load_recording
    from rdnet.restore.learned import restorer_from_checkpoint

    rec = load_recording(recording)
    ev, frames = rec.events, rec.frames
    grey = frames.grey()
    t = frames.t_us.astype(np.int64)
    ks = list(range(0, len(t) - step, step))
    pair_guide = guide_of(params)
    streams = {"raw": ev.slice_time(int(t[ks[0]]), int(t[ks[-1] + step]))}
    for name, (path, guide) in ckpts.items():
        r = restorer_from_checkpoint(path, has_frames=True, params=params, guide_threshold=guide_threshold)
        if guide not in ("frame", "library"):
            r._image = lambda frame, h, w: frame          # the two channels built below
        parts = []
        for k in ks:
            if guide == "frame":
                image = grey[k]
            elif guide == "library":
                image = (grey[k], grey[k + step])
            else:
                extra = pair_guide.change(grey[k], grey[k + step]) if guide == "pair" else np.zeros_like(grey[k])
                image = np.stack([grey[k], extra])[None].astype(np.float32)
            parts.append(r.restore(ev, int(t[k]), int(t[k + step]), image))
        streams[name] = concatenate(parts, sort=True)
    return streams


def real_scores(recording: Path, streams: dict, params: dict) -> dict:
    """Event count and event-frame consistency (every pair of consecutive frames, as
    ``rdnet restore`` scores it: raw and one stream at a time) of each stream, and the
    share of its events that are not recorded events."""
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    from rdnet.events.io import load as load_recording

    rec = load_recording(recording)
    s = params["sensor"]
    lf = LogFrames.of(rec.frames, rec.events, s["log_eps"])
    raw = streams["raw"]
    key = lambda e: np.stack([e.t, e.x, e.y, e.p]).T  # noqa: E731
    rk = {tuple(r) for r in key(raw).tolist()}
    out = {}
    for name, st in streams.items():
        sc = compare_consistency(lf, {"raw": raw, name: st} if name != "raw" else {"raw": raw},
                                 s["threshold_on"], s["threshold_off"])
        new = sum(tuple(r) not in rk for r in key(st).tolist())
        out[name] = {"events": len(st), "count_ratio_vs_raw": len(st) / max(len(raw), 1),
                     "r2_fitted": sc[name]["r2_fitted"], "raw_r2_fitted": sc["raw"]["r2_fitted"],
                     "not_recorded": new / max(len(st), 1)}
        log.info("%s: %s", name, out[name])
    return out


def real_table(res: dict) -> str:
    lines = []
    for proto, rows in res.get("real", {}).items():
        lines += ["", f"DAVIS346, windows {proto}:", "",
                  "| stream | events | x raw | consistency (r2_fitted) | raw's on the same pixel-intervals | not recorded |",
                  "|---|---:|---:|---:|---:|---:|"]
        lines += [f"| {n} | {m['events']} | {m['count_ratio_vs_raw']:.3f} | {m['r2_fitted']:.3f} | "
                  f"{m['raw_r2_fitted']:.3f} | {100 * m['not_recorded']:.1f} % |" for n, m in rows.items()]
    return "\n".join(lines) + ("\n" if lines else "")


def table(res: dict) -> str:
    lines = ["| restorer | seed | " + " | ".join(METRICS) + " | events |", "|---|---:|" + "---:|" * (len(METRICS) + 1)]
    for name, runs in res["rows"].items():
        for seed, m in runs.items():
            lines.append(f"| {name} | {seed} | " + " | ".join(f"{m[k]:.3f}" for k in METRICS) + f" | {m['events']} |")
    out = "\n".join(lines) + "\n"
    if res.get("rows_circuit"):
        out += "\nOn the circuit generator's rendering of the test sequences (one draw):\n\n" + "\n".join(
            ["| restorer | seed | " + " | ".join(METRICS) + " |", "|---|---:|" + "---:|" * len(METRICS)]
            + [f"| {name} | {seed} | " + " | ".join(f"{m[k]:.3f}" for k in METRICS) + " |"
               for name, runs in res["rows_circuit"].items() for seed, m in runs.items()]) + "\n"
    return out + real_table(res)


def study_real(args) -> None:
    """``--study-real``: the study's restorers (``dvc repro``) on a real recording with frames,
    between consecutive frames and with every other frame hidden."""
    from restore_train_range import write_results

    from rdnet.config import load_params
    params = load_params(ROOT / "params.yaml")
    ck = {f"study blurry-frame/{s}": (ROOT / "models" / "restore_image" / f"seed{s}" / "model.pt", "frame")
          for s in args.seeds}
    ck.update({f"study frame-pair/{s}": (ROOT / "models" / "restore_frames" / f"seed{s}" / "model.pt", "library")
               for s in args.seeds})
    res = {"seeds": args.seeds, "load_average_1min_before": os.getloadavg()[0], "rows": {}, "rows_circuit": {},
           "real": {}}
    for step, proto in ((1, "between consecutive frames (the pair restorer sees both frames a score compares)"),
                        (2, "over two frame intervals (every other frame hidden from the restorers)")):
        res["real"][proto] = real_scores(args.real, real_streams(args.real, ck, params, step), params)
    write_results(args.out, res, table)


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1])
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--parallel", type=int, default=2)
    ap.add_argument("--circuit", action="store_true")
    ap.add_argument("--real", type=Path, default=None, help="also a real recording with frames (DAVIS346)")
    ap.add_argument("--work", type=Path, default=None, help="keep (and reuse) pairs and networks here")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_frame_pair.json")
    ap.add_argument("--study-real", action="store_true",
                    help="only the study's frame-pair restorers (models/restore_frames, --seeds) and its "
                         "blurry-frame ones on --real, both protocols; writes --out")
    args = ap.parse_args()
    if args.study_real:
        study_real(args)
        return
    import torch
    from restore_learned_eval import eval_pairs
    from restore_train_range import train, write_results

    from rdnet.config import load_params

    torch.set_num_threads(1)
    params = load_params(ROOT / "params.yaml")
    iterations = int(params["train"]["iterations"])
    events = ROOT / "data" / "events"
    res = {"iterations": iterations, "seeds": args.seeds, "load_average_1min_before": os.getloadavg()[0],
           "rows": {}, "rows_circuit": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        change = {s: frame_change(ROOT / "data" / "pairs" / f"{s}.h5", events, s, params) for s in ("train", "test")}
        res["frame_change"] = {s: bound_check(ROOT / "data" / "pairs" / f"{s}.h5", c) for s, c in change.items()}
        log.info("frame change against the counts: %s", res["frame_change"])
        files = {}
        for v in args.variants:
            for s in ("train", "test"):
                dst = work / v / f"{s}.h5"
                if not dst.is_file():
                    with_channel(ROOT / "data" / "pairs" / f"{s}.h5", dst,
                                 change[s] if v == "pair" else np.zeros_like(change[s]))
                files[v, s] = dst
        jobs = [(v, seed, work / v / "models" / f"seed{seed}") for v in args.variants for seed in args.seeds]

        def run(job):
            v, seed, out = job
            if (out / "model.pt").is_file():
                return out / "model.pt", None
            return train("restore", files[v, "train"], out, seed, iterations)

        with ThreadPoolExecutor(max_workers=args.parallel) as pool:
            done = list(pool.map(run, jobs))
        res["train_wall_s"] = {f"{v}/{seed}": w for (v, seed, _), (_, w) in zip(jobs, done)}
        study = {f"study/{seed}": ROOT / "models" / "restore_image" / f"seed{seed}" / "model.pt" for seed in args.seeds}
        scored = eval_pairs(ROOT / "data" / "pairs" / "test.h5", study, (0.5,))
        res["rows"]["raw degraded events"] = {"-": scored["raw"]}
        res["rows"]["study (1 channel, committed)"] = {str(s): scored[f"study/{s}"] for s in args.seeds}
        at = {"study (1 channel, committed), occupancy threshold 0.5": {str(s): scored[f"study/{s}@0.5"] for s in args.seeds}}
        for v in args.variants:
            sc = eval_pairs(files[v, "test"], {f"{v}/{seed}": ck for (vv, seed, _), (ck, _) in zip(jobs, done) if vv == v},
                            (0.5,))
            res["rows"][v] = {str(seed): sc[f"{v}/{seed}"] for seed in args.seeds}
            at[f"{v}, occupancy threshold 0.5"] = {str(seed): sc[f"{v}/{seed}@0.5"] for seed in args.seeds}
        res["rows"].update(at)      # not fitted: the L1-optimal median decision, for the trade-off
        ident = eval_pairs(as_identity(ROOT / "data" / "pairs" / "test.h5", Path(tmp) / "identity.h5"), study)
        res["rows"]["study (1 channel, committed), undegraded input"] = {str(s): ident[f"study/{s}"] for s in args.seeds}
        for v in args.variants:
            sc = eval_pairs(as_identity(files[v, "test"], Path(tmp) / f"identity_{v}.h5"),
                            {f"{v}/{seed}": ck for (vv, seed, _), (ck, _) in zip(jobs, done) if vv == v})
            res["rows"][f"{v}, undegraded input"] = {str(seed): sc[f"{v}/{seed}"] for seed in args.seeds}
        if args.circuit:
            from rdnet.study.data import sequences
            from rdnet.study.independent import circuit_pairs
            pc, _ = circuit_pairs(params, sequences(events, "test"), Path(tmp) / "circuit", 0)
            change_c = frame_change(pc, events, "test", params)
            sc = eval_pairs(pc, study)
            res["rows_circuit"]["raw degraded events"] = {"-": sc["raw"]}
            res["rows_circuit"]["study (1 channel, committed)"] = {str(s): sc[f"study/{s}"] for s in args.seeds}
            for v in args.variants:
                dst = with_channel(pc, Path(tmp) / "circuit" / f"{v}.h5",
                                   change_c if v == "pair" else np.zeros_like(change_c))
                sc = eval_pairs(dst, {f"{v}/{seed}": ck for (vv, seed, _), (ck, _) in zip(jobs, done) if vv == v})
                res["rows_circuit"][v] = {str(seed): sc[f"{v}/{seed}"] for seed in args.seeds}
        if args.real is not None:
            ck = {f"study/{s}": (p, "frame") for s, p in ((s, study[f"study/{s}"]) for s in args.seeds)}
            ck.update({f"{v}/{seed}": (c, "pair" if v == "pair" else "zeros")
                       for (v, seed, _), (c, _) in zip(jobs, done)})
            res["real"] = {}
            for step, proto in ((1, "between consecutive frames (the pair restorer sees both frames a score compares)"),
                                (2, "over two frame intervals (every other frame hidden from the restorers)")):
                res["real"][proto] = real_scores(args.real, real_streams(args.real, ck, params, step), params)
    for rows in (res["rows"], res["rows_circuit"]):
        for runs in rows.values():
            for m in runs.values():
                for k in ("checkpoint", "val_metrics"):
                    m.pop(k, None)
    write_results(args.out, res, table)


if __name__ == "__main__":
    main()
