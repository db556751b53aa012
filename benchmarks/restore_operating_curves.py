"""Operating curves of the learned restorer and of the filters on the real recordings (issue 11,
goals "DVXplorer: person kept >= 75 %, background <= 15 %, better than BAF on both" and
"DAVIS346 consistency at least raw").

``restore_real`` scores each method at one setting: the restorer at its fitted decision and its
training window, BAF at ``restore.baf_dt_us``, STCF at ``restore.stcf_k``. A single point can
win on one axis and lose on the other (the restorer on the DVXplorer take keeps more of the
person than BAF, and slightly more background), so this script moves each method along its own
knob and compares the curves, which no choice of setting can tune:

- the restorer ``restore_real`` uses (``models/restore_*`` seed 0, or the packaged one when the
  study has not run): its occupancy threshold times ``--threshold-scales`` (the decision fitted
  on validation rows is 1x), and its window times ``--window-scales`` (the network reads the
  window's events as 10 bins; a shorter window holds fewer events, so more of them look
  isolated); with ``--seeds``, the threshold curve of each of those training seeds too
  (``models/restore_image`` on a recording with frames, ``models/restore_events`` without);
- the same restorer with ``restore.add_events: false`` (it deletes, never adds) along its
  threshold: where its deletions alone put it;
- BAF with its neighbour window ``--baf-dt-ms``;
- STCF with ``--stcf-k`` supporting events (``restore.stcf_tau_us`` window).

Every run is ``restore_real``'s (``restore_training_scenes.score_real``: the hot-pixel pass,
the window loop, the activity mask, the consistency with the recorded frames); only the knob
moves. Writes ``benchmarks/results/restore_operating_curves.{json,md,png}``.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_operating_curves.py     # about 10 min
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import logging
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from restore_training_scenes import restorers_from, score_real  # noqa: E402

log = logging.getLogger("restore_operating_curves")
#: recording -> (x, y) of its curve: the two scores the issue's goals read
AXES = {"dvxplorer_person": (("background", "background kept"), ("activity", "person kept")),
        "davis346_road": (("kept_fraction", "events out / raw"), ("consistency_r2", "event-frame consistency R^2"))}


def knob(threshold_scale: float = 1.0, window_scale: float = 1.0):
    """A restorer lookup wrapper (for :func:`restorers_from`) that moves the loaded restorer's
    fitted occupancy threshold and window by these factors."""
    def wrap(load):
        def lookup(*args, **kw):
            r = load(*args, **kw)
            d = dict(r.decision)
            if d.get("threshold") is not None:
                d["threshold"] = min(1.0, float(d["threshold"]) * threshold_scale)
            window = None if r.window_us is None else int(round(r.window_us * window_scale))
            return dataclasses.replace(r, decision=d, window_us=window)
        return lookup
    return wrap


def point(m: dict) -> dict:
    return {"events_out": m["events_out"], "kept_fraction": m["kept_fraction"],
            "not_recorded_fraction": m["not_recorded_fraction"], "activity": m["activity"],
            "background": m["background"], "consistency_r2": m["consistency_r2"], "esr": m["esr"]}


def sweep(path: Path, name: str, params: dict, args, work: Path) -> dict:
    """Every knob setting on one recording: ``{"events", "curves": {method: [point, ...]}}``."""
    from rdnet.events.io import open_events
    curves: dict[str, list] = {"raw": [], "rdnet threshold": [], "rdnet deletions only": [], "rdnet window": [],
                               "baf": [], "stcf": []}
    out = {}

    def run(label, method, value, p=params, wrap=None, checkpoint=None):
        with tempfile.TemporaryDirectory(dir=work) as tmp:
            if wrap is None:
                sc = score_real(path, name, p, {label: (method, checkpoint)}, Path(tmp))
            else:
                with restorers_from(wrap):
                    sc = score_real(path, name, p, {label: (method, checkpoint)}, Path(tmp))
        out["events"] = sc["events"]
        curves.setdefault(label, []).append({"value": value, **point(sc["methods"][label])})
        log.info("%s %s %s: %s", name, label, value, curves[label][-1])

    run("raw", "raw", None)
    for s in args.threshold_scales:
        run("rdnet threshold", "rdnet", s, wrap=knob(threshold_scale=s))
    no_add = copy.deepcopy(params)
    no_add["restore"]["add_events"] = False
    for s in args.threshold_scales:
        run("rdnet deletions only", "rdnet", s, no_add, wrap=knob(threshold_scale=s))
    with open_events(path) as src:
        frames = src.frames()
    task = "restore_image" if frames is not None and len(frames) else "restore_events"
    for seed in args.seeds:
        checkpoint = args.models / task / f"seed{seed}" / "model.pt"
        if not checkpoint.is_file():
            log.warning("%s not found: seed %d skipped", checkpoint, seed)
            continue
        for s in args.threshold_scales:
            run(f"rdnet threshold seed{seed}", "rdnet", s, wrap=knob(threshold_scale=s), checkpoint=checkpoint)
    for s in args.window_scales:
        run("rdnet window", "rdnet", s, wrap=knob(window_scale=s))
    for dt in args.baf_dt_ms:
        p = copy.deepcopy(params)
        p["restore"]["baf_dt_us"] = int(round(dt * 1000))
        run("baf", "baf", dt, p)
    for k in args.stcf_k:
        p = copy.deepcopy(params)
        p["restore"]["stcf_k"] = int(k)
        run("stcf", "stcf", k, p)
    return {"path": str(path), "events": out["events"], "curves": curves}


def knob_unit(label: str) -> str:
    if label.startswith("rdnet"):
        return "x window" if label == "rdnet window" else "x threshold"
    return {"baf": "ms", "stcf": "k"}.get(label, "")


def at(pts: list, xk: str, yk: str, x: float) -> float | None:
    """The curve's ``yk`` at ``xk == x``, linear between its points (None outside them)."""
    import numpy as np
    q = sorted((p[xk], p[yk]) for p in pts if p[xk] is not None and p[yk] is not None)
    if len(q) < 2 or not q[0][0] <= x <= q[-1][0]:
        return None
    return float(np.interp(x, [a for a, _ in q], [b for _, b in q]))


#: the summary each recording's curves are read at: (label, x key, y key, x value), or, with x
#: None, every restorer curve's fitted point (1x) against BAF and STCF at the same x
SUMMARY = {"dvxplorer_person": [("person kept at 15 % background (the goal's corner)", "background", "activity", 0.15),
                                ("background kept at 75 % of the person", "activity", "background", 0.75)],
           "davis346_road": [("consistency R^2 at each restorer's fitted threshold, and the filters' at the "
                              "same event count", "kept_fraction", "consistency_r2", None)]}


def margins(curves: dict, xk: str, yk: str) -> dict:
    """Per restorer threshold curve and filter: its ``yk`` minus the filter curve's at the same
    ``xk`` (linear between the filter's points), over the restorer points inside the filter's
    range: ``{(label, filter): (min, max, points compared, points)}``."""
    out = {}
    for label, pts in curves.items():
        if not label.startswith("rdnet") or label == "rdnet window":
            continue
        for f in ("baf", "stcf"):
            if f not in curves:
                continue
            d = [q[yk] - y for q in pts if q[xk] is not None and q[yk] is not None
                 for y in [at(curves[f], xk, yk, q[xk])] if y is not None]
            out[(label, f)] = (min(d) if d else None, max(d) if d else None, len(d), len(pts))
    return out


def summary(name: str, r: dict) -> list[str]:
    """Lines reading every curve at the recording's :data:`SUMMARY` points."""
    def fmt(v):
        return "-" if v is None else f"{v:.3f}"
    lines = []
    curves = {k: v for k, v in r["curves"].items() if k not in ("raw", "rdnet window")}
    if name in AXES:
        (xk, _), (yk, _) = AXES[name]
        lines.append(f"- each restorer curve's {yk} minus the filter's at the same {xk} (min to max over its "
                     "points inside the filter's range; points compared of all):")
        for (label, f), (lo, hi, n, total) in margins(curves, xk, yk).items():
            lines.append(f"  - {label} vs {f}: {fmt(lo)} to {fmt(hi)} ({n} of {total})")
    for what, xk, yk, x in SUMMARY.get(name, []):
        if x is not None:
            lines.append(f"- {what} ({xk} = {x:.3f}): "
                         + ", ".join(f"{label} {fmt(at(pts, xk, yk, x))}" for label, pts in curves.items()))
            continue
        lines.append(f"- {what}:")
        for label, pts in curves.items():
            fitted = next((q for q in pts if q["value"] == 1.0), None) if label.startswith("rdnet") else None
            if fitted is None:
                continue
            x = fitted[xk]
            lines.append(f"  - {label}: {fmt(fitted[yk])} at {xk} {x:.3f}; "
                         + ", ".join(f"{f} {fmt(at(curves[f], xk, yk, x))}" for f in ("baf", "stcf") if f in curves))
    return lines


def table(res: dict) -> str:
    lines = ["# Operating curves of the restorer and the filters on the real recordings", "",
             "Each method moved along its own knob (`benchmarks/restore_operating_curves.py`); the "
             "restorer is `restore_real`'s (seed 0), its fitted decision and training window at 1x.", ""]
    for name, r in res["recordings"].items():
        (xk, xl), (yk, yl) = AXES.get(name, (("background", "background kept"), ("activity", "activity kept")))
        lines += [f"## {name} ({r['events']:,} recorded events)", "", *summary(name, r), "",
                  f"| method | knob | events out | {xl} | {yl} | not recorded | ESR |", "|---|---|---:|---:|---:|---:|---:|"]
        for label, pts in r["curves"].items():
            for q in pts:
                value = "" if q["value"] is None else f"{q['value']:g} {knob_unit(label)}"
                fmt = (lambda v: "-" if v is None else f"{v:.3f}")
                lines.append(f"| {label} | {value} | {q['events_out']:,} | {fmt(q[xk])} | {fmt(q[yk])} | "
                             f"{fmt(q['not_recorded_fraction'])} | {fmt(q['esr'])} |")
        lines.append("")
    return "\n".join(lines)


def figure(res: dict, path: Path) -> Path:
    from rdnet.eval.report import _figure, _save_figure
    names = [n for n in res["recordings"] if n in AXES]
    fig, axes = _figure(1, max(1, len(names)), figsize=(5.2 * max(1, len(names)), 4.0), squeeze=False)
    style = {"rdnet threshold": ("C3", "o-"), "rdnet window": ("C1", "s--"), "rdnet deletions only": ("C4", "d-."),
             "baf": ("C0", "^-"),
             "stcf": ("C2", "v-"), "raw": ("k", "*")}
    for ax, name in zip(axes[0], names):
        (xk, xl), (yk, yl) = AXES[name]
        for label, pts in res["recordings"][name]["curves"].items():
            pts = [q for q in pts if q[xk] is not None and q[yk] is not None]
            if not pts:
                continue
            seed = label not in style
            color, fmt = ("C3", ":") if seed else style[label]
            ax.plot([q[xk] for q in pts], [q[yk] for q in pts], fmt, color=color, label=label,
                    ms=5, lw=0.8 if seed else 1.5, alpha=0.6 if seed else 1.0)
            for q in ([] if seed else pts):
                if q["value"] is not None:
                    ax.annotate(f"{q['value']:g}", (q[xk], q[yk]), fontsize=6, xytext=(3, 3),
                                textcoords="offset points", color=color)
        if name == "dvxplorer_person":
            ax.axvline(0.15, color="grey", lw=0.8, ls=":")
            ax.axhline(0.75, color="grey", lw=0.8, ls=":")
        ax.set(xlabel=xl, ylabel=yl, title=name)
        ax.legend(fontsize=7)
    return _save_figure(fig, path)


def main() -> None:
    from rdnet.config import load_params
    from rdnet.eval.report import write_text_atomic
    from rdnet.restore.real import recordings

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--recordings", nargs="+", default=list(AXES))
    ap.add_argument("--threshold-scales", type=float, nargs="+", default=[0.5, 0.75, 1.0, 1.5, 2.0, 2.5])
    ap.add_argument("--window-scales", type=float, nargs="+", default=[0.5, 0.75, 1.0, 1.5, 2.0])
    ap.add_argument("--baf-dt-ms", type=float, nargs="+", default=[2.5, 5.0, 10.0, 20.0, 40.0])
    ap.add_argument("--stcf-k", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--seeds", type=int, nargs="*", default=[],
                    help="training seeds whose threshold curves are added (checkpoints under --models)")
    ap.add_argument("--models", type=Path, default=ROOT / "models")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/restore_operating_curves")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    params = load_params(args.params)
    found = dict(recordings([ROOT / "data" / "real", ROOT.parent / "shared" / "real"]))
    res = {"seeds": args.seeds, "models": str(args.models), "recordings": {}}
    with tempfile.TemporaryDirectory() as work:
        for name in args.recordings:
            if name not in found:
                log.warning("%s not found under data/real or ../shared/real: skipped", name)
                continue
            r = sweep(found[name], name, params, args, Path(work))
            r["path"] = str(Path(r["path"]).resolve().relative_to(ROOT.parent))
            res["recordings"][name] = r
    write_text_atomic(args.out.with_suffix(".json"), json.dumps(res, indent=2) + "\n")
    write_text_atomic(args.out.with_suffix(".md"), table(res))
    figure(res, args.out.with_suffix(".png"))
    print(table(res))


if __name__ == "__main__":
    main()
