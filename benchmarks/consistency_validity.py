"""Does event-frame consistency measure restoration? Checked where the truth is known (issue 11).

On real recordings rdnet has no ground truth, so issue 11 judges the DAVIS346 restoration by
the event-frame consistency R^2 (:mod:`rdnet.deblur.consistency`, ``r2_fitted``; goal: the
restored stream at least as consistent as the raw one). This benchmark asks whether that score
ranks event streams as their distance to the truth does, on recordings whose undegraded events
are known:

* ``rdnet``: the study's simulated test split (``data/events/test``, each sequence's own
  test-time degradation, drawn from settings disjoint from training);
* ``rdnet stress sX``: the test scenes with every effect of ``degrade`` at exactly X times its
  strength (``data/stress/scale_X``, stage ``stress``): how the score follows degradation;
* ``clean input``: the test split's undegraded events handed to every method as the
  recording: what a restorer does to a stream that needs no restoring (the ideal answer
  is the input, R^2 and F1 unchanged);
* ``circuit``: the test split rendered by the independent circuit generator
  (:func:`rdnet.study.independent.circuit_file`; its own ideal and degraded events), so the
  check does not rest on rdnet's simulator alone.

Each sequence becomes a recording as a DAVIS346 user has one: the degraded events and every
``--frame-step``-th sharp frame (240 Hz / 10 = 24 Hz, the DAVIS346 file's 25 Hz; windows of
10 frames, inside the blur stage's 7-13). Every method runs through ``rdnet restore``'s own
function (:func:`rdnet.restore.run.restore_recording`; the learned ones with the study's
checkpoints, hot-pixel pass and all). Each stream (the undegraded events, the raw degraded
ones, every method's output) is then scored two ways over the windows between those frames:

* consistency ``r2_fitted`` with the raw stream, as ``rdnet restore`` / ``rdnet deblur``
  score it (the union of the two streams' active pixel-intervals);
* against the undegraded events with the study's event metrics
  (:func:`rdnet.eval.events.match_metrics` on 10-bin per-polarity counts per window):
  F1, count ratio, all-voxel L1.

Reads the study's outputs (``dvc repro`` first); writes
``benchmarks/results/consistency_validity.{json,md,png}`` (the figure also draws the committed
run with the restorers before identity pairs, ``consistency_validity_clean_fraction0.json``).

    .venv/bin/python benchmarks/consistency_validity.py [--circuit-draws 1] [--scales 0.5 1 3]
"""
from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

from rdnet.config import load_params, section
from rdnet.deblur.consistency import LogFrames, compare_consistency
from rdnet.eval.events import match_metrics
from rdnet.events.core import Events
from rdnet.events.io.hdf5 import H5RecordingWriter, read_events, read_frames, read_header
from rdnet.events.recording import Frames
from rdnet.events.voxel import voxel_grid

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("consistency_validity")

#: method label -> (restore method, checkpoint relative to ROOT or None for the default)
METHODS = {
    "rdnet-image": ("rdnet", None),
    "rdnet-events": ("rdnet", "models/restore_events/seed0/model.pt"),
    "baf": ("baf", None),
    "stcf": ("stcf", None),
    "gef": ("gef", None),
}


def window_counts(ev: Events, t: np.ndarray, bins: int) -> np.ndarray:
    """(windows, 2, bins, H, W) per-polarity counts of ``ev`` in [t_k, t_k+1)."""
    return np.stack([voxel_grid(ev.slice_time(int(t[k]), int(t[k + 1])), bins, int(t[k]), int(t[k + 1] - t[k]),
                                polarity="split") for k in range(len(t) - 1)]).round().astype(np.int64)


def score_sequence(src: Path, params: dict, frame_step: int, tmp: Path, raw_group: str = "events",
                   methods: dict | None = None) -> dict:
    """Every stream of one sequence file (frames, ``events``, ``events_ideal``): consistency
    with the raw stream and the event metrics against the undegraded one. ``raw_group``:
    the events handed to the methods as the recording (``events_ideal``: a clean input).
    ``methods``: label -> (restore method, checkpoint path or None), default :data:`METHODS`."""
    from rdnet.restore.run import restore_recording

    width, height, _, _ = read_header(src)
    fr = read_frames(src)
    sub = Frames(fr.images[::frame_step], fr.t_us[::frame_step], fr.exposure_us[::frame_step])
    t = sub.t_us
    raw = read_events(src, raw_group).slice_time(int(t[0]), int(t[-1]))
    ideal = read_events(src, "events_ideal").slice_time(int(t[0]), int(t[-1]))
    rec = tmp / "in.h5"
    with H5RecordingWriter(rec, width, height, sensor="consistency-validity") as w:
        w.write_frames(sub)
        w.append_events(raw)
    streams = {"raw": raw, "undegraded": ideal}
    # rdnet restore's own scores off: every stream is scored below, the same way
    run_params = {**params, "restore": {**params.get("restore", {}), "scores": False}}
    for name, (method, ck) in (METHODS if methods is None else methods).items():
        out = tmp / f"{name.replace('/', '_')}.h5"
        restore_recording(rec, out, run_params, method=method, checkpoint=None if ck is None else ROOT / ck,
                          progress=False)
        streams[name] = read_events(out, "events").slice_time(int(t[0]), int(t[-1]))
    s = section(params, "sensor")
    bins = int(section(params, "voxel").bins)
    lf = LogFrames.of(sub, raw, s.log_eps)
    truth = window_counts(ideal, t, bins)
    rows = {}
    for name, ev in streams.items():
        pair = {"raw": raw} if name == "raw" else {"raw": raw, name: ev}
        c = compare_consistency(lf, pair, s.threshold_on, s.threshold_off)[name]
        m = match_metrics(window_counts(ev, t, bins), truth)
        rows[name] = {"r2_fitted": c["r2_fitted"], "r2_nominal": c["r2_nominal"], "events": len(ev),
                      "f1": m["f1"], "count_ratio": m["count_ratio"], "voxel_l1_all": m["voxel_l1_all"]}
    return rows


def sources(kind: str, params: dict, tmp: Path, draws: int, scales) -> list[tuple[str, Path]]:
    from rdnet.study.data import sequences
    test = sequences(ROOT / "data" / "events", "test")
    if kind == "rdnet":
        return [("rdnet", p) for p in test]
    if kind == "clean":
        return [("clean input", p) for p in test]
    if kind == "stress":
        out = []
        for sc in scales:
            tag = f"{float(sc):g}"
            out += [(f"rdnet stress s{tag}", p) for p in sequences(ROOT / "data" / "stress" / f"scale_{tag}" / "events",
                                                                   "test")]
        return out
    from rdnet.study.independent import circuit_file
    from rdnet.study.data import simulation_configs
    sensor = simulation_configs(params)[0]
    out = []
    for d in range(draws):
        for i, p in enumerate(test):
            dst = tmp / f"circuit{d}_{p.name}"
            circuit_file(p, dst, sensor, 1000 * (d + 1) + i)
            out.append(("circuit", dst))
    return out


def summarize(per_seq: list[dict]) -> dict:
    """Per group: the mean of every score per stream, and how often each stream's
    consistency and F1 beat the raw stream's (paired by sequence)."""
    groups: dict[str, list] = {}
    for r in per_seq:
        groups.setdefault(r["group"], []).append(r["streams"])
    out = {}
    for g, seqs in groups.items():
        names = list(seqs[0])
        agg = {}
        for n in names:
            vals = {k: np.array([s[n][k] for s in seqs], float) for k in ("r2_fitted", "f1", "count_ratio",
                                                                         "voxel_l1_all", "events")}
            d_r2 = np.array([s[n]["r2_fitted"] - s["raw"]["r2_fitted"] for s in seqs])
            d_f1 = np.array([s[n]["f1"] - s["raw"]["f1"] for s in seqs])
            agg[n] = {**{k: float(np.nanmean(v)) for k, v in vals.items()},
                      "r2_minus_raw": float(np.nanmean(d_r2)),
                      "r2_minus_raw_std": float(np.nanstd(d_r2, ddof=1)) if len(seqs) > 1 else 0.0,
                      "f1_minus_raw": float(np.nanmean(d_f1)),
                      "r2_above_raw": int(np.sum(d_r2 > 0)), "f1_above_raw": int(np.sum(d_f1 > 0))}
        # across the methods (raw included, the truth left out): does consistency order them as F1 does?
        meth = [n for n in names if n != "undegraded"]
        rho = [_spearman([s[n]["r2_fitted"] for n in meth], [s[n]["f1"] for n in meth]) for s in seqs]
        out[g] = {"sequences": len(seqs), "streams": agg, "spearman_r2_vs_f1": float(np.nanmean(rho)),
                  "spearman_r2_vs_f1_per_sequence": rho}
    return out


def _spearman(a, b) -> float:
    from scipy.stats import spearmanr
    r = spearmanr(a, b).statistic
    return float(r) if np.isfinite(r) else float("nan")


def markdown(res: dict) -> str:
    lines = [f"Event-frame consistency against the truth ({res['command']}; {res['seconds']:.0f} s). "
             f"Recordings: each test sequence's degraded events with every {res['frame_step']}-th sharp frame "
             "(24 Hz); every method through `rdnet restore`'s function. `R^2`: consistency r2_fitted with the raw "
             "stream, as `rdnet restore` scores it; `dR^2`: minus the raw stream's, mean +- spread over sequences; "
             "`above raw`: sequences where the stream beats raw on R^2 / on F1. F1, count ratio and all-voxel L1 "
             "against the undegraded events (10-bin voxels per window). `rho`: Spearman correlation between "
             "R^2 and F1 over the methods (raw included, the truth left out), mean over sequences.", ""]
    for g, s in res["summary"].items():
        lines += [f"**{g}** ({s['sequences']} sequences; rho {s['spearman_r2_vs_f1']:+.2f})", "",
                  "| stream | R^2 | dR^2 | above raw (R^2 / F1) | F1 | count ratio | L1 all | events |",
                  "|---|---|---|---|---|---|---|---|"]
        for n, v in s["streams"].items():
            lines.append(f"| {n} | {v['r2_fitted']:.3f} | {v['r2_minus_raw']:+.3f} +- {v['r2_minus_raw_std']:.3f} | "
                         f"{v['r2_above_raw']} / {v['f1_above_raw']} of {s['sequences']} | {v['f1']:.3f} | "
                         f"{v['count_ratio']:.2f} | {v['voxel_l1_all']:.4f} | {v['events']:,.0f} |")
        lines.append("")
    return "\n".join(lines)


def figure(res: dict, path: Path, before: dict | None = None) -> Path:
    """Consistency gain over raw (left) and count ratio against the undegraded events (right)
    of every stream, per group of recordings; ``before``: another run's summary (the study's
    restorers before identity pairs), drawn hatched beside the learned rows."""
    import numpy as np

    from rdnet.eval.report import _figure, _save_figure
    groups = list(res["summary"])
    names = [n for n in res["summary"][groups[0]]["streams"] if n not in ("raw",)]
    fig, axes = _figure(1, 2, figsize=(12.0, 3.6))
    width = 0.8 / (len(names) + (2 if before else 0))
    x = np.arange(len(groups))
    for ax, key, title in ((axes[0], "r2_minus_raw", "consistency R^2 minus the raw stream's"),
                           (axes[1], "count_ratio", "events / undegraded events")):
        bars = [(n, res["summary"], "", None) for n in names]
        if before:
            bars += [(n, before, " (before identity pairs)", "//") for n in names if n.startswith("rdnet")]
        for i, (n, summ, suffix, hatch) in enumerate(bars):
            v = [summ[g]["streams"][n][key] if g in summ else np.nan for g in groups]
            ax.bar(x + (i - len(bars) / 2 + 0.5) * width, v, width, label=n + suffix, hatch=hatch,
                   color=f"C{names.index(n)}", alpha=0.5 if hatch else 1.0)
        ax.set_xticks(x)
        ax.set_xticklabels([{"rdnet": "test split"}.get(g, g.replace("rdnet stress ", "stress ")) for g in groups],
                           fontsize=7)
        ax.set_title(title, fontsize=9)
        ax.axhline(1.0 if key == "count_ratio" else 0.0, color="k", lw=0.6)
    axes[1].legend(fontsize=6, ncol=2)
    fig.suptitle("Recordings built from the simulated test split: each method through rdnet restore "
                 "(clean input: the undegraded events handed in)", fontsize=9)
    return _save_figure(fig, path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--frame-step", type=int, default=10, help="keep every n-th sharp frame (240 Hz / 10 = 24 Hz)")
    ap.add_argument("--circuit-draws", type=int, default=2, help="circuit generator renderings of the test split")
    ap.add_argument("--scales", type=float, nargs="*", default=[0.5, 1.0, 2.0, 3.0], help="stress scales")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "consistency_validity.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("rdnet").setLevel(logging.WARNING)
    params = load_params(args.params)
    start = time.perf_counter()
    per_seq = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        srcs = (sources("rdnet", params, tmp, 0, ()) + sources("clean", params, tmp, 0, ())
                + sources("stress", params, tmp, 0, args.scales)
                + sources("circuit", params, tmp, args.circuit_draws, ()))
        for group, path in srcs:
            work = tmp / "work"
            work.mkdir(exist_ok=True)
            rows = score_sequence(path, params, args.frame_step, work,
                                  "events_ideal" if group == "clean input" else "events")
            per_seq.append({"group": group, "sequence": path.name, "streams": rows})
            log.info("%s %s: %s", group, path.name, {n: (round(v["r2_fitted"], 3), round(v["f1"], 3))
                                                       for n, v in rows.items()})
    res = {"command": "python benchmarks/consistency_validity.py" + (
               "" if args.circuit_draws == 2 else f" --circuit-draws {args.circuit_draws}"),
           "frame_step": args.frame_step, "seconds": time.perf_counter() - start,
           "summary": summarize(per_seq), "sequences": per_seq}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=1, default=float) + "\n")
    args.out.with_suffix(".md").write_text(markdown(res) + "\n")
    before = args.out.with_name("consistency_validity_clean_fraction0.json")
    figure(res, args.out.with_suffix(".png"), json.loads(before.read_text())["summary"] if before.is_file() else None)
    print(markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
