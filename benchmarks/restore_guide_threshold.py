"""Which threshold should the frame-pair guide divide by? (issue 11, the frame-pair restorer)

The frame-pair restorer (``models/restore_frames``, :mod:`rdnet.nn.guide`) reads the log
change between the two frames that bracket its window in units of a contrast threshold:
the net event count an ideal pixel of that threshold fires. The study trains it at the
simulator's ``sensor.threshold_on`` (0.2). A camera whose threshold is larger fires fewer
events for the same change, so at 0.2 the guide asks for events that camera would never
have fired; ``restore.guide_threshold`` (set by ``rdnet restore --calibration``) gives the
guide the camera's threshold instead. Two checks, neither with rdnet's simulator as truth:

1. **Independent generator, known threshold.** The study's test sequences rendered by the
   circuit generator (:mod:`rdnet.circuit`, one draw, as ``restoration_circuit``) with the
   sensor's thresholds set to ``theta`` (0.2, 0.3, 0.4); the truth is that generator's
   undegraded events at ``theta``. Each seed of the study's frame-pair restorer runs with
   the guide at the trained 0.2 and at ``theta``; event precision / recall / F1, count ratio
   and signed-voxel L1 as ``restore_learned_eval.pair_metrics``.
2. **The DAVIS346 recording** (real frames and events, no ground truth): the restorer with
   the guide at the trained 0.2, at the threshold the recording's own events and frames give
   by least squares (``threshold_on_fitted`` of :func:`rdnet.deblur.consistency.compare_consistency`
   on the raw stream), and at the one ``rdnet calibrate`` fitted
   (``results/calibration/davis346/report.json``), in windows between consecutive frames
   and with every other frame hidden (``restore_frame_pair.real_streams`` / ``real_scores``):
   events out / raw, event-frame consistency, and the share of output events that are not
   recorded events (added).
3. **What the added events are** (DAVIS346, windows between consecutive frames, as recorded
   and with the calibrated latency subtracted from the timestamps first): for each seed at
   the trained and at the calibrated threshold, the events it adds, the share of them at a
   pixel whose frames changed by at least the calibrated threshold over the interval, the
   share whose polarity agrees with the sign of that change, and the share at a pixel that
   recorded an event in the interval.
4. **A polarity cap, checked, not built** (``--polarity-cap``): drop every added event whose
   polarity opposes its pixel's guide where the guide asks for at least one event
   (``|change| >= 1``, the guide's change channel). On the simulated test split and the
   circuit generator's rendering at ``theta`` 0.4 (voxel counts: additions beyond the input
   capped in the opposing polarity) and on DAVIS346 at both thresholds (output events not
   recorded, between consecutive frames): the metrics of parts 1 and 2 with and without it.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_guide_threshold.py   # needs dvc repro
        writes benchmarks/results/restore_guide_threshold.{json,md}
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import logging
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
METRICS = ("precision", "recall", "f1", "count_ratio", "l1_all", "l1_events")
log = logging.getLogger("restore_guide_threshold")


def circuit_rows(params: dict, thetas, seeds, work: Path) -> dict:
    """Part 1 (module docstring): ``{theta: {row: metrics}}``."""
    from restore_learned_eval import eval_pairs

    from rdnet.eval.predict import checkpoint_guide
    from rdnet.study.data import sequences
    from rdnet.study.independent import circuit_pairs
    from rdnet.train import checkpoint as ckpt_mod

    files = sequences(ROOT / "data" / "events", "test")
    out = {}
    for theta in thetas:
        p = copy.deepcopy(params)
        p["sensor"] = {**p["sensor"], "threshold_on": theta, "threshold_off": theta}
        pairs, _ = circuit_pairs(p, files, work / f"theta{theta}", 0)
        paths = {str(s): ROOT / "models" / "restore_frames" / f"seed{s}" / "model.pt" for s in seeds}
        trained = {checkpoint_guide(ckpt_mod.read_checkpoint(p)) for p in paths.values()}
        if len(trained) != 1:
            raise SystemExit(f"the seeds were trained with different guides: {trained}")
        trained = trained.pop()
        rows = {}
        for guide in [trained] + ([dataclasses.replace(trained, threshold=theta)]
                                  if theta != trained.threshold else []):
            sc = eval_pairs(pairs, paths, guide=guide)
            rows.setdefault("raw", {"-": sc["raw"]})
            rows[f"guide at {guide.threshold:g}" + (" (trained)" if guide == trained else "")] = {
                s: {k: sc[s][k] for k in METRICS} for s in paths}
        out[str(theta)] = rows
    return out


def real_rows(recording: Path, params: dict, thresholds: dict, seeds) -> dict:
    """Part 2: ``{protocol: {label: {stream: scores}}}``."""
    from restore_frame_pair import real_scores, real_streams
    ck = {f"seed {s}": (ROOT / "models" / "restore_frames" / f"seed{s}" / "model.pt", "library") for s in seeds}
    out = {}
    for step, proto in ((1, "between consecutive frames"), (2, "every other frame hidden")):
        out[proto] = {label: real_scores(recording, real_streams(recording, ck, params, step, guide_threshold=thr),
                                         params)
                      for label, thr in thresholds.items()}
    return out


def added_rows(recording: Path, params: dict, thresholds: dict, seeds, latency_us: float, cut: float,
               work: Path) -> dict:
    """Part 3: ``{"as recorded" | "latency undone": {label: {seed: shares}}}``."""
    import numpy as np
    from restore_frame_pair import real_streams

    from rdnet.events import Events, Recording
    from rdnet.events.io import load as load_recording
    from rdnet.events.io import save
    from rdnet.events.select import event_keys

    rec = load_recording(recording)
    log_grey = np.log(rec.frames.grey().astype(np.float64) + params["sensor"]["log_eps"])
    t = rec.frames.t_us.astype(np.int64)
    a = rec.events.array.copy()
    a["t"] -= int(round(latency_us))
    shifted = work / "latency_undone.h5"
    save(shifted, Recording(rec.width, rec.height, events=Events(a[a["t"] >= 0], rec.width, rec.height),
                            frames=rec.frames, sensor="latency undone"))
    ck = {str(s): (ROOT / "models" / "restore_frames" / f"seed{s}" / "model.pt", "library") for s in seeds}
    out = {}
    for proto, path in (("as recorded", recording), ("latency undone", shifted)):
        out[proto] = {}
        for label, thr in thresholds.items():
            st = real_streams(path, ck, params, 1, guide_threshold=thr)
            raw = st["raw"]
            k_raw = np.searchsorted(t, raw.t, side="right") - 1
            fired = np.zeros((len(t), rec.height, rec.width), bool)
            fired[k_raw, raw.y, raw.x] = True
            out[proto][label] = {}
            for s in ck:
                e = st[s].array[~np.isin(event_keys(st[s]), event_keys(raw))]
                k = np.searchsorted(t, e["t"], side="right") - 1
                dl = log_grey[k + 1, e["y"], e["x"]] - log_grey[k, e["y"], e["x"]]
                share = (lambda m: float(m.mean()) if m.size else None)  # noqa: E731
                out[proto][label][s] = {
                    "added": int(len(e)), "added_share": len(e) / max(len(st[s]), 1),
                    "changed_by_a_threshold": share(np.abs(dl) >= cut),
                    "polarity_agrees": share(np.sign(dl) == np.where(e["p"] > 0, 1, -1)),
                    "pixel_fired": share(fired[k, e["y"], e["x"]]), "on_share": share(e["p"] > 0)}
    return out


def capped_counts(restored, degraded, change, bins: int):
    """``restored`` (N, 2 bins, H, W) with the additions beyond ``degraded`` removed in the
    polarity that opposes ``change`` (N, H, W; the guide's change channel) where
    ``|change| >= 1``: OFF where the guide rises, ON where it falls."""
    import numpy as np
    out = restored.copy()
    on, off = out[:, :bins], out[:, bins:]
    rises, falls = (change >= 1)[:, None], (change <= -1)[:, None]
    np.copyto(off, np.minimum(off, degraded[:, bins:]).astype(out.dtype), where=rises)
    np.copyto(on, np.minimum(on, degraded[:, :bins]).astype(out.dtype), where=falls)
    return out


def cap_rows(params: dict, seeds, work: Path, recording: Path, thresholds: dict) -> dict:
    """Part 4 (module docstring)."""
    import numpy as np
    import torch
    from restore_frame_pair import real_scores, real_streams
    from restore_learned_eval import pair_metrics, stored_decision

    from rdnet.eval.predict import checkpoint_guide
    from rdnet.events import Events
    from rdnet.events.io import load as load_recording
    from rdnet.events.select import event_keys
    from rdnet.study.data import sequences
    from rdnet.study.independent import circuit_pairs
    from rdnet.train import checkpoint as ckpt_mod
    from rdnet.train.data import PairsDataset
    from rdnet.train.loop import predict_counts

    paths = {str(s): ROOT / "models" / "restore_frames" / f"seed{s}" / "model.pt" for s in seeds}
    p = copy.deepcopy(params)
    p["sensor"] = {**p["sensor"], "threshold_on": 0.4, "threshold_off": 0.4}
    circuit, _ = circuit_pairs(p, sequences(ROOT / "data" / "events", "test"), work / "theta0.4", 0)
    out = {}
    for label, pairs, theta in (("simulated test split", ROOT / "data" / "pairs" / "test.h5", None),
                                ("circuit generator, theta 0.4, guide 0.4", circuit, 0.4)):
        out[label] = {}
        for s, path in paths.items():
            ck = ckpt_mod.read_checkpoint(path)
            net = ckpt_mod.model_from_checkpoint(path, ck).eval()
            guide = checkpoint_guide(ck)
            guide = guide if theta is None else dataclasses.replace(guide, threshold=theta)
            data = PairsDataset(pairs, crop=None, augment=False, guide=guide)
            with torch.no_grad():
                mu, prob, target, support = predict_counts(net, data, torch.device("cpu"), with_support=True)
            rows = [data[i] for i in range(len(data))]
            degraded = np.stack([r["counts_degraded"].numpy() for r in rows])
            change = np.stack([r["guide"][-1].numpy() for r in rows])
            restored = stored_decision(ck["extra"]["decision"], mu, prob, support)
            bins = restored.shape[1] // 2
            out[label][s] = {"as decided": pair_metrics(restored, target, degraded),
                             "polarity cap": pair_metrics(capped_counts(restored, degraded, change, bins), target,
                                                          degraded)}
            data.close()
    rec = load_recording(recording)
    log_grey = np.log(rec.frames.grey().astype(np.float64) + params["sensor"]["log_eps"])
    t = rec.frames.t_us.astype(np.int64)
    ck = {s: (path, "library") for s, path in paths.items()}
    trained = checkpoint_guide(ckpt_mod.read_checkpoint(next(iter(paths.values())))).threshold
    for label, thr in thresholds.items():
        st = real_streams(recording, ck, params, 1, guide_threshold=thr)
        cut = thr if thr is not None else trained
        capped = {"raw": st["raw"]}
        for s in ck:
            e = st[s]
            added = ~np.isin(event_keys(e), event_keys(st["raw"]))
            k = np.searchsorted(t, e.t, side="right") - 1
            change = (log_grey[k + 1, e.y, e.x] - log_grey[k, e.y, e.x]) / cut
            opposes = np.where(e.p > 0, change <= -1, change >= 1)
            capped[s] = Events(e.array[~(added & opposes)], e.width, e.height, validate=False)
        out[f"DAVIS346, guide {label}"] = {"as decided": real_scores(recording, st, params),
                                           "polarity cap": real_scores(recording, capped, params)}
    return out


def table(res: dict) -> str:
    lines = ["Part 1: the circuit generator's rendering of the test split at threshold theta; truth = its "
             "undegraded events at theta.", ""] if res.get("circuit") else []
    for theta, rows in res.get("circuit", {}).items():
        lines += [f"theta = {theta}:", "", "| guide | seed | " + " | ".join(METRICS) + " |",
                  "|---|---|" + "---:|" * len(METRICS)]
        lines += [f"| {name} | {seed} | " + " | ".join(f"{m[k]:.3f}" for k in METRICS) + " |"
                  for name, runs in rows.items() for seed, m in runs.items()]
        lines.append("")
    if res.get("real"):
        lines += ["Part 2: DAVIS346 (" + ", ".join(f"{k}: {v:.3f}" if v else f"{k}: trained"
                                                   for k, v in res["real_thresholds"].items()) + ")", ""]
    for proto, by in res.get("real", {}).items():
        lines += [f"Windows {proto}:", "",
                  "| guide threshold | stream | events | x raw | consistency (r2_fitted) | raw's | not recorded |",
                  "|---|---|---:|---:|---:|---:|---:|"]
        for label, streams in by.items():
            lines += [f"| {label} | {n} | {m['events']} | {m['count_ratio_vs_raw']:.3f} | {m['r2_fitted']:.3f} | "
                      f"{m['raw_r2_fitted']:.3f} | {100 * m['not_recorded']:.1f} % |"
                      for n, m in streams.items() if n != "raw" or label == next(iter(by))]
        lines.append("")
    fmt = (lambda v: "-" if v is None else f"{100 * v:.1f} %")  # noqa: E731
    if res.get("added"):
        lines += [f"Part 3: the events added on DAVIS346 between consecutive frames (changed: the frames' log "
                  f"change at the pixel over the interval at least {res['added_cut']:.3f}, the calibrated "
                  "threshold).", ""]
    for proto, by in res.get("added", {}).items():
        lines += [f"{proto}:", "", "| guide threshold | seed | added | of the output | at a changed pixel | "
                  "polarity agrees with the change | pixel fired in the interval | ON |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
        lines += [f"| {label} | {s} | {m['added']} | {fmt(m['added_share'])} | {fmt(m['changed_by_a_threshold'])} | "
                  f"{fmt(m['polarity_agrees'])} | {fmt(m['pixel_fired'])} | {fmt(m['on_share'])} |"
                  for label, seeds in by.items() for s, m in seeds.items()]
        lines.append("")
    if res.get("cap"):
        lines += ["Part 4: the polarity cap (checked, not built).", ""]
        for label, by in res["cap"].items():
            if label.startswith("DAVIS346"):
                lines += [f"{label}:", "", "| stream | as decided: x raw, consistency, not recorded | "
                          "polarity cap: x raw, consistency, not recorded |", "|---|---|---|"]
                lines += [f"| {n} | " + " | ".join(
                    f"{by[v][n]['count_ratio_vs_raw']:.3f}, {by[v][n]['r2_fitted']:.3f}, "
                    f"{100 * by[v][n]['not_recorded']:.1f} %" for v in ("as decided", "polarity cap")) + " |"
                    for n in by["as decided"]]
            else:
                lines += [f"{label}:", "", "| seed | rule | " + " | ".join(METRICS) + " |",
                          "|---|---|" + "---:|" * len(METRICS)]
                lines += [f"| {s} | {v} | " + " | ".join(f"{m[v][k]:.3f}" for k in METRICS) + " |"
                          for s, m in by.items() for v in ("as decided", "polarity cap")]
            lines.append("")
    return "\n".join(lines)


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--thetas", type=float, nargs="+", default=[0.2, 0.3, 0.4])
    ap.add_argument("--real", type=Path, default=ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4")
    ap.add_argument("--report", type=Path, default=ROOT / "results" / "calibration" / "davis346" / "report.json")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_guide_threshold.json")
    ap.add_argument("--polarity-cap", action="store_true", help="part 4 only, into --out (another file)")
    args = ap.parse_args()
    from restore_train_range import write_results

    from rdnet.config import load_params
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    from rdnet.events.io import load as load_recording
    from rdnet.restore.settings import calibrated_restore
    from rdnet.study.config import calibrated_configs

    params = load_params(ROOT / "params.yaml")
    s = params["sensor"]
    rec = load_recording(args.real)
    own = compare_consistency(LogFrames.of(rec.frames, rec.events, s["log_eps"]), {"raw": rec.events},
                              s["threshold_on"], s["threshold_off"])["raw"]
    thresholds = {"trained (0.2)": None,
                  "the recording's least squares": float(own["threshold_on_fitted"]),
                  "rdnet calibrate's fit": calibrated_restore(*calibrated_configs(args.report))["guide_threshold"]}
    res = {"seeds": args.seeds, "thetas": args.thetas, "load_average_1min_before": os.getloadavg()[0],
           "real_thresholds": thresholds}
    if args.polarity_cap:
        with tempfile.TemporaryDirectory() as tmp:
            res["cap"] = cap_rows(params, args.seeds, Path(tmp), args.real,
                                  {k: v for k, v in thresholds.items() if "least" not in k})
        write_results(args.out, res, table)
        print(json.dumps({"out": str(args.out)}))
        return
    with tempfile.TemporaryDirectory() as tmp:
        res["circuit"] = circuit_rows(params, args.thetas, args.seeds, Path(tmp))
    res["real"] = real_rows(args.real, params, thresholds, args.seeds)
    fitted = calibrated_restore(*calibrated_configs(args.report))
    res["added_cut"] = fitted["guide_threshold"]
    with tempfile.TemporaryDirectory() as tmp:
        res["added"] = added_rows(args.real, params, {k: v for k, v in thresholds.items() if "least" not in k},
                                  args.seeds, fitted["latency_us"], fitted["guide_threshold"], Path(tmp))
    write_results(args.out, res, table)
    print(json.dumps({"out": str(args.out)}))


if __name__ == "__main__":
    main()
