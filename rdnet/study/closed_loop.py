"""Camera-specific restoration (closed loop): calibrate -> simulate -> train -> restore.

``rdnet calibrate`` fits a sensor + degradation to a real recording (its ``report.json``,
``fitted_config``). The closed loop simulates the study's sequences with that fitted
sensor and degradation (the study's own :func:`rdnet.study.data.simulate_sequences` with
``study.degrade_from`` pointing at the report, then :func:`rdnet.study.data.make_pairs`),
trains the image-guided count restorer on them exactly as the ``train_restore`` stage does
(:func:`rdnet.study.training.train_seeds`, task ``restore``, the ``model`` and ``train``
sections), and compares it with the generic restorer on the recording itself
(:func:`rdnet.restore.run.restore_recording`: events out, event-frame consistency R^2,
ESR) and on the calibrated held-out simulated sequences (event-level metrics,
:func:`rdnet.study.rows.restoration_table`).

Degradation strength: every sequence of both splits is simulated with every fitted effect
at exactly ``scale`` x its fitted value (default 1: the camera as calibrated), not with the
study's randomized draws, whose training range (``randomize.train_scale``, 0.5-0.9x) never
reaches the fitted strength itself.
"""
from __future__ import annotations

import copy
import dataclasses
import logging
from pathlib import Path
from typing import Mapping

from rdnet.config import section, to_dict

log = logging.getLogger(__name__)

#: the rows of the comparison on the real recording, in table order (``latency_corrected``:
#: the raw events with the fitted latency subtracted from their timestamps, when the
#: calibration fitted one -- the calibration's own correction, nothing learned;
#: ``<restorer>_latency``: that restorer on the corrected events; ``frames``: the study's
#: frame-pair restorer, ``frames_threshold``: the same with its guide at the fitted
#: threshold, ``frames_threshold_latency`` = ``rdnet restore --calibration`` with it).
ROWS = ("raw", "latency_corrected", "generic", "generic_latency", "camera", "camera_latency",
        "frames", "frames_latency", "frames_threshold", "frames_threshold_latency")
#: what each row reports (summary.json ``recording.rows.<row>``).
ROW_KEYS = ("method", "checkpoint", "events_out", "count_ratio", "not_recorded", "esr", "consistency_r2")


def calibrated_params(params: Mapping, report: str | Path) -> dict:
    """A deep copy of ``params`` whose ``study.degrade_from`` names ``report`` (the input is
    not changed); the report is read and validated here (FormatError naming it)."""
    from rdnet.study.config import calibrated_configs
    calibrated_configs(report)
    p = copy.deepcopy(dict(params))
    p["study"] = {**(p.get("study") or {}), "degrade_from": str(report)}
    section(p, "study")
    return p


def lowest_seed(params: Mapping):
    """The ``study`` section with only its lowest seed (one training, no worker pool)."""
    study = section(params, "study")
    return dataclasses.replace(study, seeds=(min(study.seeds),), parallel=1)


def simulate_calibrated(params: Mapping, report: str | Path, scenes: Path, interp: Path, work: Path, *,
                        scale: float = 1.0, splits=None) -> dict:
    """Events (``work/events/<split>/seq_XXX.h5``) and pairs (``work/pairs/<split>.h5``) of
    the study's sequences simulated with the calibrated sensor + degradation of ``report``,
    every fitted effect at ``scale`` x its value. Returns what was simulated."""
    from rdnet.sim.scenes import SPLITS
    from rdnet.study.config import calibrated_configs
    from rdnet.study.data import make_pairs, simulate_sequences
    splits = tuple(splits or SPLITS)
    p = calibrated_params(params, report)
    sensor, degrade = calibrated_configs(report)
    work = Path(work)
    events = simulate_sequences(p, Path(scenes), Path(interp), work / "events", splits, fixed_scale=scale)
    pairs = make_pairs(p, work / "events", work / "pairs", splits)
    return {"report": str(report), "sensor": to_dict(sensor), "degrade": to_dict(degrade),
            "active_effects": list(degrade.active()), "scale": float(scale), "events": events, "pairs": pairs}


def train_camera_restorer(params: Mapping, train_pairs: Path, out: Path, *, timing: Path | None = None,
                          progress: bool = True) -> dict:
    """The image-guided count restorer (task ``restore``, as stage ``train_restore``)
    trained on ``train_pairs`` into ``out/seed<k>`` for the lowest seed of ``study.seeds``."""
    from rdnet.study.config import NetworkConfig
    from rdnet.study.training import train_seeds
    return train_seeds(NetworkConfig(task="restore"), lowest_seed(params), section(params, "train"),
                       section(params, "model"), train_pairs, out, progress=progress, timing=timing)


def _row(res: dict) -> dict:
    cons = (res["scores"].get("consistency") or {}).get("restored") or {}
    esr = res["scores"].get("esr") or {}
    n_in = res["events_in"]
    return {"method": res["method"], "checkpoint": res["checkpoint"], "events_out": res["events_out"],
            "count_ratio": res["events_out"] / n_in if n_in else None,
            # the share of the output that is not a recorded event (added by the restorer)
            "not_recorded": res["events_not_recorded"] / res["events_out"] if res["events_out"] else None,
            "esr": esr.get("restored"), "consistency_r2": cons.get("r2_fitted")}


def compare_on_recording(params: Mapping, recording: Path, restorers: Mapping[str, Path], data_out: Path, *,
                         latency_us: float = 0.0, guide_threshold: float | None = None,
                         progress: bool = False) -> dict:
    """``rdnet restore`` of ``recording`` unchanged (row ``raw``) and with each learned
    restorer of ``restorers`` (row name -> checkpoint: a ``model.pt`` or a network folder,
    its lowest seed); when ``latency_us`` > 0, each of them again with that latency undone
    first (``restore.latency_us``, as ``rdnet restore --calibration``): rows
    ``latency_corrected`` (the raw events shifted) and ``<name>_latency``. The restored
    streams go to ``data_out/<row>.h5``. ``guide_threshold``: the calibrated contrast
    threshold; each frame-pair restorer of ``restorers`` then runs again with its guide at
    it (``restore.guide_threshold``, as ``rdnet restore --calibration``): rows
    ``<name>_threshold`` (and ``<name>_threshold_latency``). Returns ``events_in``,
    ``guide_threshold`` and ``rows`` (:data:`ROW_KEYS` per row; ``count_ratio`` = events out
    / events in)."""
    from rdnet.restore.run import restore_recording
    data_out = Path(data_out)
    data_out.mkdir(parents=True, exist_ok=True)
    shifts = {"": 0.0}
    if latency_us > 0:
        shifts["_latency"] = float(latency_us)
    rows = {}
    raw = None
    for suffix, lat in shifts.items():
        p = {**params, "restore": {**(params.get("restore") or {}), "latency_us": lat}}
        name = "raw" if not suffix else "latency_corrected"
        res = restore_recording(recording, data_out / f"{name}.h5", p, method="raw", progress=progress)
        raw = raw or res
        rows[name] = {**_row(res), "method": "raw" if not suffix else f"raw - {int(round(lat))} us"}
        for rname, ck in restorers.items():
            runs = [("", p)]              # and again at the fitted threshold, for a frame-pair guide
            for infix, q in runs:
                res = restore_recording(recording, data_out / f"{rname}{infix}{suffix}.h5", q, method="rdnet",
                                        checkpoint=ck, progress=progress)
                guide = res["model"].get("guide")
                if guide_threshold is not None and not infix and isinstance(guide, dict):
                    runs.append(("_threshold", {**q, "restore": {**q["restore"],
                                                                 "guide_threshold": float(guide_threshold)}}))
                what = (f" guide at {guide['threshold']:.3g}" if infix else "") + (
                    f" - {int(round(lat))} us" if suffix else "")
                rows[rname + infix + suffix] = {**_row(res), "method": _row(res)["method"] + what}
    return {"recording": str(recording), "events_in": raw["events_in"], "duration_us": raw["duration_us"],
            "has_frames": raw["has_frames"], "latency_us": float(latency_us),
            "guide_threshold": None if guide_threshold is None else float(guide_threshold), "rows": rows}


def in_domain(params: Mapping, pairs: Path, events_dir: Path, restorers: Mapping[str, Path]) -> dict:
    """Event-level metrics (precision, recall, F1, count ratio, voxel L1) of the raw
    degraded events (``raw``) and of each restorer (lowest seed) on the calibrated held-out
    sequences (``pairs``: a pairs file of :func:`simulate_calibrated`)."""
    from rdnet.study.rows import EVENT_KEYS, restoration_table
    seeds = lowest_seed(params).seeds
    table = restoration_table(section(params, "ablation"), Path(pairs), Path(events_dir),
                              {k: Path(v) for k, v in restorers.items()}, filters=(), seeds=seeds)
    out = {}
    for name, entry in table.items():
        ev = entry.get("events") or {}
        out["raw" if name == "degraded" else name] = {k: ev.get(k) for k in EVENT_KEYS}
    return out


def _fmt(v, spec=".3f"):
    return "-" if v is None else format(v, spec)


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def _ordered(rows: Mapping) -> list:
    """Row names in :data:`ROWS` order, others after (summary.json stores sorted keys)."""
    return [n for n in ROWS if n in rows] + sorted(n for n in rows if n not in ROWS)


def summary_markdown(summary: Mapping) -> str:
    """The tables of ``summary.json`` (real recording; in-domain check when present)."""
    rec = summary["recording"]
    note = ""
    if "latency_corrected" in rec["rows"]:
        note = (f"; `latency_corrected`: the raw events with the fitted latency ({rec['latency_us'] / 1e3:.2f} ms) "
                "subtracted from their timestamps (`rdnet restore --calibration`), `*_latency`: the "
                "restorer on those")
    if rec.get("guide_threshold") is not None:
        note += (f"; `frames`: the study's frame-pair restorer, its guide at the trained threshold, "
                 f"`frames_threshold`: at the fitted {rec['guide_threshold']:.3g} (`restore.guide_threshold`; "
                 "with the latency undone: `rdnet restore --calibration`); not recorded: the share of the "
                 "output that is not a recorded event")
    lines = [f"Closed loop on `{rec['recording']}` ({rec['events_in']:,} raw events): "
             "the generic restorer (`generic`) against the one trained on the "
             f"calibrated degradation (`camera`){note}.", "",
             "| row | method | checkpoint | events out | count ratio | not recorded | ESR | consistency R^2 |",
             "|---|---|---|---|---|---|---|---|"]
    for name in _ordered(rec["rows"]):
        r = rec["rows"][name]
        lines.append(f"| {name} | {r['method']} | {r['checkpoint'] or '-'} | {r['events_out']:,} | "
                     f"{_fmt(r['count_ratio'], '.3f')}x | {_pct(r.get('not_recorded'))} | {_fmt(r['esr'])} | "
                     f"{_fmt(r['consistency_r2'])} |")
    dom = summary.get("in_domain")
    if dom:
        lines += ["", "In-domain check: the calibrated-degradation held-out (test) sequences, event-level "
                  "metrics against the undegraded events.", "",
                  "| row | precision | recall | F1 | count ratio | voxel L1 (all) | voxel L1 (event) |",
                  "|---|---|---|---|---|---|---|"]
        for name in _ordered(dom):
            m = dom[name]
            lines.append(f"| {name} | {_fmt(m['precision'])} | {_fmt(m['recall'])} | {_fmt(m['f1'])} | "
                         f"{_fmt(m['count_ratio'])} | {_fmt(m['voxel_l1_all'], '.4f')} | "
                         f"{_fmt(m['voxel_l1_event'], '.4f')} |")
    return "\n".join(lines) + "\n"


def summary_figure(summary: Mapping, path: Path) -> Path:
    """Bars of consistency R^2, count ratio and ESR per row on the real recording."""
    from rdnet.eval.report import _figure, _save_figure
    rows = summary["recording"]["rows"]
    names = _ordered(rows)
    fig, axes = _figure(1, 3, figsize=(10.5, 3.0))
    for ax, (key, title) in zip(axes, (("consistency_r2", "event-frame consistency R^2"),
                                       ("count_ratio", "events out / raw"), ("esr", "ESR"))):
        vals = [rows[n][key] if rows[n][key] is not None else float("nan") for n in names]
        colors = {"raw": "0.6", "latency_corrected": "0.35", "generic": "tab:blue", "camera": "tab:orange",
                  "generic_latency": "tab:cyan", "camera_latency": "tab:red", "frames": "tab:green",
                  "frames_latency": "yellowgreen", "frames_threshold": "tab:purple",
                  "frames_threshold_latency": "orchid"}
        ax.bar([n.replace("latency_corrected", "raw-latency") for n in names], vals,
               color=[colors.get(n, "tab:brown") for n in names])
        for i, v in enumerate(vals):
            ax.text(i, v, format(v, ".2f" if key == "count_ratio" else ".3f"), ha="center", va="bottom",
                    fontsize=6)
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=7)
        ax.tick_params(axis="x", labelrotation=60, labelsize=6)
        ax.set_ylim(0, 1.12 * max([v for v in vals if v == v] or [1.0]))
    fig.suptitle(f"{Path(summary['recording']['recording']).name}: generic, camera-specific and frame-pair restorers",
                 fontsize=9, y=1.02)
    return _save_figure(fig, path)
