"""Writing a calibration: ``report.json`` (machine-readable, schema in
:mod:`rdnet.calib`), ``report.md`` (for a person: the finding first, then the evidence)
and PNG figures. Every file is written to a temporary name and renamed."""
from __future__ import annotations

import functools
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from rdnet.calib.calibrate import Calibration, finding
from rdnet.calib.effects import EFFECTS
from rdnet.calib.fit import SIGNATURE_Z
from rdnet.calib.stats import IEI_EDGES, LAG_SMOOTH_BINS, TAIL_BANDS, peak_lag_us, pearson_lag_curve
from rdnet.events.io._common import atomic_directory, atomic_output

if TYPE_CHECKING:
    from rdnet.runtime import ForkedWorker

log = logging.getLogger(__name__)


def _atomic(path: Path, write) -> None:
    with atomic_output(path) as tmp:
        write(tmp)


def _clean(o):
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, (np.floating, float)):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    return o


def write_json(path: Path, data: dict) -> None:
    text = json.dumps(_clean(data), indent=2)
    _atomic(Path(path), lambda p: Path(p).write_text(text + "\n"))


def markdown(cal: Calibration, figures: list[str]) -> str:
    r = cal.report
    d = r["discrepancy"]
    lines = [f"# Sim-to-real calibration: {Path(r['recording']).name}", "", finding(r), ""]
    lines += ["## Discrepancy", "",
              f"Metric: {d['metric']}.", "",
              "| | fit segments | held-out segments |", "|---|---|---|",
              f"| base config | {d['fit_before']:.3f} | {d['heldout_before']:.3f} |",
              f"| after basic refit | | {d['heldout_after_basic_refit']:.3f} |",
              f"| fitted config | {d['fit_after']:.3f} | {d['heldout_after']:.3f} |", "",
              f"Seed std of the held-out discrepancy: {d['heldout_seed_std_before']:.3f} (base), "
              f"{d['heldout_seed_std_after']:.3f} (fitted). Noise floor (fitted config against itself, "
              f"other seeds): {d['heldout_noise_floor']:.3f}; excess over it {d['heldout_excess_before']:.3f} "
              f"-> {d['heldout_excess_after']:.3f}.", ""]
    lines += ["## Effects the base config leaves out", "",
              "Own statistic: the held-out term of the statistic that reveals the effect, before -> after "
              "adding it, and its drop in seed std (z; the signature gate needs > "
              f"{SIGNATURE_Z:g} to name it; a drop beyond calibrate.signature_significance with a gain "
              "in every seed names it on its own).", "",
              "| effect | missing | confidence | rank | parameters | held-out gain | own statistic | where |",
              "|---|---|---|---|---|---|---|---|"]
    for e in r["effects"]:
        p = ", ".join(f"{k}={v:.4g}" for k, v in e["parameters"].items())
        lines.append(f"| {e['name']} | {'**yes**' if e['missing'] else 'no'} | {e['confidence']:.2f} | "
                     f"{e.get('rank') or '-'} | {p} | {e.get('heldout_gain', 0):.3f} | {signature_cell(e)} | "
                     f"{e['where']} |")
    lines += ["", "Evidence per effect:", ""]
    for e in r["effects"]:
        lines.append(f"- **{e['name']}**: {e['evidence']}")
    alike = [(e, a) for e in r["effects"] if e["missing"] for a in e.get("look_alikes") or []]
    lines += ["", "## Look-alikes", ""]
    lines += [f"- **{e['name']}** is not told apart from **{a['name']}** by these data: held-out "
              f"discrepancy {a['heldout_after']:.3f} with {a['name']}, {a['margin']:.3f} lower with "
              f"{e['name']} ({a['margin'] / max(a['margin_seed_std'], 1e-12):.1f} seed std). What would "
              f"separate them: {a['separate_with']}." for e, a in alike] or [
        "Every named effect fits the held-out segments better than each other fitted candidate of "
        "its round by more than `calibrate.significance` seed spreads."]
    warned = [(e["name"], c) for e in r["effects"] if e["missing"] for c in e.get("caveats") or []]
    warned = [("basic refit", c) for c in r.get("refit_caveats") or []] + warned
    if warned:
        lines += ["", "## Caveats", ""] + [f"- **{name}**: {c}" for name, c in warned]
    lines += ["", "## Basic refit (configured parameters)", "",
              ", ".join(f"{k} = {v:.4g}" for k, v in r["basic_refit"].items()) or "(nothing)", ""]
    fi = r.get("frame_interpolation")
    if fi and len(fi["candidates"]) > 1:
        lines += [f"Frame interpolation (nuisance choice, lowest reachable fit discrepancy on the final pixel sample): "
                  f"**{fi['chosen']}**; " + ", ".join(
                      f"{m} fit {c['fit_after_basic_refit']:.3f} after the basic refit, {c['fit_reachable']:.3f} "
                      f"with {c.get('fit_reachable_with') or 'no effect'} / held-out {c['heldout_after_basic_refit']:.3f} "
                      f"({c['simulated_frames']} frames)" for m, c in fi["candidates"].items()), ""]
    lt = r.get("latency_timing")
    if lt and lt.get("recorded_lag_us") is not None:
        ideal = ", ".join(f"{m} {v / 1000:.3g}" for m, v in lt["ideal_lag_us"].items() if v is not None)
        lo, hi = lt["latency_range_us"]
        lines += [f"Events behind the frames (event-frame consistency of time-shifted events, no simulator): "
                  f"recorded {lt['recorded_lag_us'] / 1000:.3g} ms (95 % {lt['recorded_ci95_us'][0] / 1000:.3g}-"
                  f"{lt['recorded_ci95_us'][1] / 1000:.3g}); an ideal sensor at the basic refit: {ideal} ms"
                  + (f"; so a latency between {lo / 1000:.3g} and {hi / 1000:.3g} ms" if lo is not None else "")
                  + ".", ""]
    lines += ["## Where the base simulation differs", "", "| statistic | held-out before | after |", "|---|---|---|"]
    for k, v in d["terms_heldout_before"].items():
        lines.append(f"| {k} | {v:.3f} | {d['terms_heldout_after'][k]:.3f} |")
    m = r["mismatch"]["base"]
    lines += ["", f"- event rate: {m['rate_real_hz_per_pixel']:.3g} Hz/pixel real vs {m['rate_sim_hz_per_pixel']:.3g} sim",
              f"- static pixels: rate {m['static_rate_hz']['real']:.3g} vs {m['static_rate_hz']['sim']:.3g} Hz, "
              f"ON fraction {m['static_on_fraction']['real']:.2f} vs {m['static_on_fraction']['sim']:.2f}",
              f"- moving pixels ON fraction: {m['moving_on_fraction']['real']:.3f} vs {m['moving_on_fraction']['sim']:.3f}",
              f"- rate cross-correlation lag (real after sim): {m['lag_us'] / 1000:.2f} ms",
              "- worst coarse cells (x, y, log sim/real): " + ", ".join(
                  f"({c['x']}, {c['y']}, {c['log_ratio_sim_real']:+.2f})" for c in m["worst_cells"]), ""]
    c = r["consistency"]
    lines += ["## Event-frame consistency", "",
              "R^2 and correlation of threshold x signed event count against the log-intensity change between "
              "consecutive frames, over active pixels.", "",
              "| events | thresholds | R^2 | correlation | slope | active |", "|---|---|---|---|---|---|"]
    for k, label in (("real_base_thresholds", "real / base"), ("real_fitted_thresholds", "real / fitted"),
                     ("sim_base", "sim base / base"), ("sim_fitted", "sim fitted / fitted")):
        v = c[k]
        lines.append(f"| {label.split(' / ')[0]} | {label.split(' / ')[1]} | {_f(v['r2'])} | "
                     f"{_f(v['correlation'])} | {_f(v['slope'])} | {v['active']} |")
    s = r["setup"]
    lines += ["", "## Setup", "",
              f"{s['sampled_pixels']} sampled pixels (stride {s['pixel_stride']}), {s['real_events_compared']} "
              f"real events compared, {s['simulated_frames']} simulated frames, seeds {s['seeds']}, "
              f"{s['simulations']} simulations, {s['runtime_s']:.1f} s. Fit segments {s['fit_segments']}, "
              f"held-out segments {s['heldout_segments']}."
              + (f" The search ran on {s['search']['search_pixels']} pixels (stride {s['search']['search_stride']})"
                 f" and the pixel circuit {s['search']['kernel_runs']} times." if s.get("search") else ""), ""]
    if figures:
        lines += ["## Figures", ""] + [f"![{f}]({f})" for f in figures] + [""]
    return "\n".join(lines)


def signature_cell(effect: dict) -> str:
    """The "own statistic" cell of an effect of report.json: its statistic, the held-out
    term before -> after (``effect["signature"]``), the z of the drop, and "vetoed" when the
    signature gate turned a significant gain down, "significant by it" when the statistic's
    own drop named the effect (``calibrate.signature_significance``); "-" for an effect never
    evaluated."""
    sig = effect.get("signature")
    if not sig:
        return "-"
    z = "" if sig["z"] is None else f" (z {sig['z']:.1f})"
    return (f"{effect['statistic']} {_f(sig['heldout_before'])} -> {_f(sig['heldout_after'])}{z}"
            + (", vetoed" if sig["vetoed"] else "") + (", significant by it" if sig.get("significant_by_it") else ""))


def _f(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3f}"


# --- figures ----------------------------------------------------------------------------

#: statistics drawn with a second y axis on the right (the still pixels' rate)
TWIN_AXIS_STATISTICS = ("static_rate", "static_on_fraction", "on_fraction")

@dataclass(frozen=True)
class FigureData:
    """What the figures draw, taken from a :class:`Calibration`: about 1 MB, picklable (sent
    to the forked workers of ``rdnet calibrate``, :func:`write_report`)."""
    report: dict
    real_stats: dict
    base_stats: dict
    fitted_stats: dict
    intensity_edges: np.ndarray
    time_edges: np.ndarray
    t0: int
    time_bin_us: float
    max_lag_us: float

    @classmethod
    def of(cls, cal: Calibration) -> "FigureData":
        ctx = cal.ctx
        return cls(cal.report, cal.real_stats, cal.base_stats, cal.fitted_stats, ctx.intensity_edges,
                   ctx.time_edges, int(ctx.t0), float(ctx.cfg.time_bin_us), float(ctx.cfg.max_lag_us))


def _plot_statistic(ax, name: str, data: FigureData) -> None:
    series = (("real", data.real_stats, "k"), ("base", data.base_stats, "tab:red"),
              ("fitted", data.fitted_stats, "tab:blue"))
    if name in ("rate_vs_intensity", "on_vs_intensity"):
        e = data.intensity_edges
        xc = 0.5 * (e[:-1] + e[1:])
        for lab, s, col in series:
            ax.plot(xc, s[name], "o-", color=col, label=lab)
        ax.set_xlabel("log intensity")
        ax.set_ylabel("events / pixel / s" if name == "rate_vs_intensity" else "ON fraction")
        if name == "rate_vs_intensity":
            ax.set_yscale("log")
    elif name == "iei":
        xc = np.concatenate([[IEI_EDGES[0] - 0.25], IEI_EDGES])
        for lab, s, col in series:
            ax.step(xc, s["iei"], where="post", color=col, label=lab)
        ax.set_xlabel("log10 inter-event interval (us)")
        ax.set_ylabel("fraction")
    elif name in ("rate_time", "lag"):
        t = (data.time_edges[:-1] - data.t0) * 1e-3
        for lab, s, col in series:
            ax.plot(t, s["rate_time"], color=col, lw=0.8, label=lab)
        ax.set_xlabel("time (ms)")
        ax.set_ylabel("events / s")
    elif name == "lag_smoothed":
        # the correlation curve itself: where its peak sits is the statistic
        real, bin_us = data.real_stats, data.time_bin_us
        for lab, s, col in series[1:]:
            lags, c = pearson_lag_curve(s["rate_time"], real["rate_time"], real["time_mask"], bin_us,
                                        data.max_lag_us)
            if lags.size:
                peak_ms = peak_lag_us(c, lags, bin_us) * 1e-3
                ax.plot(lags * bin_us * 1e-3, np.where(np.isfinite(c), c, np.nan), "o-", ms=3, color=col,
                        label=f"{lab} vs real: peak {peak_ms:.2f} ms")
        ax.axvline(0.0, color="k", lw=0.6)
        ax.set_xlabel("delay of the simulation (ms)")
        ax.set_ylabel(f"Pearson correlation, rates smoothed over {LAG_SMOOTH_BINS} bins")
    elif name in ("pixel_tail", "pixel_quantiles", "pixel_isolated"):
        for lab, s, col in series:
            ax.plot(np.arange(len(s[name])), s[name], "o-", color=col, label=lab)
        ax.set_yscale("symlog" if name == "pixel_isolated" else "log")   # isolated rates are 0 in most bands
        ax.set_xlabel("quantile band" + (f" {TAIL_BANDS}" if name != "pixel_quantiles" else ""))
        ax.set_ylabel({"pixel_tail": "mean |ON - OFF| rate (Hz)",
                       "pixel_isolated": "mean rate above the busiest neighbour (Hz)"}.get(name, "mean rate (Hz)"))
    elif name == "pixel_persistence":
        # one number per stream: how much each pixel's excess over the declared config
        # repeats between the two halves of the segments (threshold mismatch repeats)
        for i, (lab, s, col) in enumerate(series):
            ax.bar(i, float(s[name]), color=col, label=f"{lab}: {float(s[name]):.4f}")
        ax.set_xticks([])
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel("cov. of per-pixel log excess, halves")
    elif name in TWIN_AXIS_STATISTICS:
        # the still pixels' rate in Hz on its own (right) axis: a ratio to the recording's
        # rate means nothing where its still pixels hardly fire (DAVIS346: none at all)
        w = 0.25
        rate_ax = ax.twinx()
        for i, (lab, s, col) in enumerate(series):
            rate_ax.bar((i - 1) * w, float(s["static_rate"]), w, color=col)
            ax.bar(np.arange(1, 3) + (i - 1) * w, [float(s["static_on_fraction"]), float(s["on_fraction"])], w,
                   color=col, label=lab)
        ax.set_xticks(range(3), ["static rate\n(right axis)", "static ON\nfraction", "moving ON\nfraction"])
        ax.set_ylim(0, 1)
        ax.set_ylabel("ON fraction")
        rate_ax.set_ylabel("still pixels: events / pixel / s")
    else:  # rate_map
        ax.imshow(data.real_stats["rate_map"], cmap="magma")
    # y given: the automatic placement measures every tick label to clear what sits above the
    # axes (0.03 s of the statistics figure); nothing does, so the title lands where it would
    ax.set_title(name, y=1.0)
    ax.legend(fontsize=7)


#: Subplot margins of each figure, fixed: ``tight_layout`` measured every tick label's
#: extent and cost about a third of the figures' time (0.35 of 1.1 s on DAVIS346).
_MAPS_LAYOUT = dict(left=0.025, right=0.965, bottom=0.1, top=0.88, wspace=0.32)
_STATS_LAYOUT = dict(left=0.06, right=0.95, bottom=0.09, top=0.95, wspace=0.36, hspace=0.34)
_EFFECT_LAYOUT = dict(left=0.16, right=0.95, bottom=0.14, top=0.9)
#: right margin of a panel with a second y axis on the right (:func:`_plot_statistic`)
_TWIN_RIGHT = 0.86


def _figure_jobs(cal: FigureData) -> list[tuple[str, Callable]]:
    """``(file name, draw)`` of every figure, in the report's order; ``draw()`` returns the
    figure (a standalone Agg figure, :func:`rdnet.eval.report._figure`: no pyplot, no
    global backend state)."""
    from rdnet.eval.report import _figure

    floor = 0.05 * max(float(cal.real_stats["rate"]), 1e-6)

    def maps():
        fig, axes = _figure(1, 5, figsize=(17, 3.4))
        maps = [cal.real_stats["rate_map"], cal.base_stats["rate_map"], cal.fitted_stats["rate_map"]]
        vmax = max(float(m.max()) for m in maps) or 1.0
        for ax, m, t in zip(axes[:3], maps, ("real", "sim base", "sim fitted")):
            im = ax.imshow(m, cmap="magma", vmin=0, vmax=vmax)
            ax.set_title(f"rate map {t} (Hz)", y=1.0)
            fig.colorbar(im, ax=ax, fraction=0.046)
        for ax, m, t in zip(axes[3:], maps[1:], ("base", "fitted")):
            lr = np.log((m + floor) / (maps[0] + floor))
            im = ax.imshow(lr, cmap="coolwarm", vmin=-2, vmax=2)
            ax.set_title(f"log(sim {t} / real)", y=1.0)
            fig.colorbar(im, ax=ax, fraction=0.046)
        fig.subplots_adjust(**_MAPS_LAYOUT)
        return fig

    def statistics():
        stat_names = ["rate_vs_intensity", "on_vs_intensity", "iei", "rate_time", "pixel_tail", "static_rate"]
        fig, axes = _figure(2, 3, figsize=(15, 8))
        for ax, n in zip(axes.ravel(), stat_names):
            _plot_statistic(ax, n, cal)
        fig.subplots_adjust(**_STATS_LAYOUT)
        return fig

    def effect(name: str):
        stat = EFFECTS[name].statistic
        fig, ax = _figure(figsize=(6, 4))
        _plot_statistic(ax, stat, cal)
        ax.set_title(f"{name}: {stat} (before = base, after = fitted)", fontsize=9, y=1.0)
        fig.subplots_adjust(**{**_EFFECT_LAYOUT, **({"right": _TWIN_RIGHT} if stat in TWIN_AXIS_STATISTICS else {})})
        return fig

    return ([("mismatch_maps.png", maps), ("statistics.png", statistics)]
            + [(f"effect_{e['name']}.png", functools.partial(effect, e["name"]))
               for e in cal.report["effects"] if e["missing"]])


#: how :func:`write_report` shares the figures between two forked workers: the 2 x 3
#: statistics figure takes about as long as all the others together (0.44 of 0.73 s on
#: DAVIS346)
_ALONE = "statistics.png"


def draw_figures(data: FigureData, out: Path, names: list[str] | None = None) -> list[str]:
    """Write the PNG figures of ``data`` (or those of ``names``) into ``out``; returns the
    file names of every figure of the report, in its order."""
    jobs = _figure_jobs(data)
    for name, draw in jobs:
        if names is None or name in names:
            fig = draw()
            _atomic(out / name, lambda p: fig.savefig(p, dpi=90, format="png"))
    return [name for name, _ in jobs]


def figures(cal: Calibration, out: Path) -> list[str]:
    """Write the PNG figures into ``out`` (here, one after the other); returns their file
    names."""
    return draw_figures(FigureData.of(cal), out)


def write_report(cal: Calibration, out_dir: str | Path, *, plots: bool = True,
                 workers: "list[ForkedWorker] | None" = None) -> list[Path]:
    """Write report.json, report.md and the figures into ``out_dir`` (created). With
    ``workers`` (:func:`rdnet.runtime.forked_workers`, forked before the calibration with
    :func:`rdnet.eval.report.prepare_figures` as their preparation, as ``rdnet calibrate``
    does), they draw the figures, the statistics figure in the first and the others in the
    second, while this process writes the text; the files are the same. A worker that
    fails (its traceback goes to stderr) has its figures drawn here instead, so a figure
    never costs the calibration's report."""
    from rdnet.runtime import ChildFailed

    out = Path(out_dir)
    workers = list(workers or [])[:2] if plots else []
    shares: list[list[str]] = []               # the figures each worker draws
    with atomic_directory(out) as stage:      # all files or none (other files of out are kept)
        try:
            if not plots:
                figs = []
            elif workers:
                data = FigureData.of(cal)
                figs = [name for name, _ in _figure_jobs(data)]     # names only: no matplotlib here
                shares = ([[_ALONE], [f for f in figs if f != _ALONE]] if len(workers) == 2 else [figs])
                for w, share in zip(workers, shares):
                    w.submit(draw_figures, data, stage, share)
                log.debug("figures drawn by %d forked workers: %s", len(workers), shares)
            else:
                figs = figures(cal, stage)
            write_json(stage / "report.json", cal.report)
            (stage / "report.md").write_text(markdown(cal, figs))
            for w, share in zip(workers, shares):
                try:
                    w.wait()
                except ChildFailed as e:
                    log.warning("%s; drawing %s here", e, ", ".join(share))
                    draw_figures(data, stage, share)
        except BaseException:
            for w in workers:                 # nothing written into the stage after it is gone
                w.kill()
            raise
    return [out / "report.json", out / "report.md"] + [out / f for f in figs]
