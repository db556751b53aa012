"""A sensor latency read off a recording with no simulator and no frame interpolation
(issue 12: a check of `rdnet calibrate`'s latency on data and a model it was not built from).

:func:`rdnet.calib.consistency.latency_scan` shifts the events earlier by L and scores, for
every L on a grid, how well the net event count between two frames (ON - OFF) follows the
change of log intensity between them (Pearson correlation over the pixel-intervals whose log
change is at least the threshold); the estimate is the best shift, with a bootstrap interval
over the frame intervals. It shares no code with the simulator, the interpolation or the
calibration's statistics, so it is an independent reading of the same physics.

* DAVIS346 road (frames 40 ms apart, the recorded events), against the latency `rdnet
  calibrate` names there (`results/calibration/davis346/report.json`), and how much the
  ideal sensor's lag and the rate cross-correlation behind that latency move with the frame
  interpolation and the thresholds.
* The calibration proof's concealed recordings (64 x 64, frames 10 ms apart; all three blocks:
  rdnet's simulator, the same with the true events from 4x denser frames, `oversample4`, and
  the independent circuit generator), read from the stage's committed reports, whose
  `latency_timing` has the scan of each recording and of each interpolation's basic-refit
  simulation. The truth is known: the latency cases hide 4 ms (`s1`) and 1.5 ms (`s2`) under
  1 ms of jitter, the other cases and the nulls have none (a bandwidth limit delays the dark
  pixels instead). Run `dvc repro calibration_proof` first when rdnet/calib has changed.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/latency_consistency_scan.py
    # -> benchmarks/results/latency_consistency_scan.{json,md,png} (about 1 min on 2 cores)
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4"
REPORT = ROOT / "results" / "calibration" / "davis346" / "report.json"
PROOF = ROOT / "results" / "calibration" / "proof"
log = logging.getLogger("latency_consistency_scan")


def scan(rec, log_eps: float, min_change: float, seed: int = 0) -> dict:
    """:func:`latency_scan` of a recording's events on its frames at full resolution."""
    from rdnet.calib.consistency import latency_scan
    from rdnet.deblur.consistency import LogFrames
    return latency_scan(rec.events, LogFrames.of(rec.frames, rec.events, log_eps), max_shift_us=20000.0,
                        step_us=500.0, min_change=min_change, rng=np.random.default_rng(seed))


def _context(rec, report: dict, cfg, method: str):
    """The calibration's context of ``rec`` (its pixel sample) with ``method``'s frame interpolation."""
    from rdnet.calib.context import build_context
    from rdnet.calib.calibrate import calibration_interpolation
    return build_context(rec, cfg, float(report["base_config"]["sensor"]["log_eps"]), source="scan",
                         interpolate=calibration_interpolation(cfg, method))


def reference_scans(rec, report: dict, cfg, extra: dict | None = None, ctx=None) -> dict:
    """The scan of the recording and of rdnet's simulation of it at what ``rdnet calibrate``
    fitted before naming any effect (its report: base config, basic refit, chosen frame
    interpolation), on the calibration's pixel sample. The scan of an ideal stream is not 0:
    a pixel fires only once its change has reached a threshold, so its events trail the
    change (by about half its inter-event time); the simulation carries that lag too, so
    ``scan(recording) - scan(simulation)`` is the latency beyond it. ``extra``: more
    simulated configs on top of the basic refit (name -> values). The scans are the report's
    own (:func:`rdnet.calib.calibrate.lag_behind_frames`: its grid and scored set). ``ctx``:
    the context of the report's chosen interpolation when already built (:func:`_context`)."""
    from rdnet.calib.calibrate import lag_behind_frames
    from rdnet.calib.fit import Objective
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    sensor = SensorConfig(**report["base_config"]["sensor"])
    degrade = DegradeConfig(**report["base_config"]["degrade"])
    method = report["frame_interpolation"]["chosen"]
    ctx = _context(rec, report, cfg, method) if ctx is None else ctx
    obj = Objective(ctx, sensor, degrade, [0])
    basic = dict(report["basic_refit"])

    def one(ev) -> dict:
        r = lag_behind_frames(ev, ctx, sensor, resamples=200)
        return {k: r[k] for k in ("latency_us", "ci95_us", "at_edge")}
    out = {"recorded": one(ctx.real), "simulated_basic_refit": one(obj.simulate(basic, 0)),
           "interpolation": method, "pixel_stride": ctx.stride}
    for name, values in (extra or {}).items():
        out["simulated_" + name] = one(obj.simulate({**basic, **values}, 0))
    out["latency_beyond_simulation_us"] = out["recorded"]["latency_us"] - out["simulated_basic_refit"]["latency_us"]
    return out


def davis346_sensitivity(rec, report: dict, cfg) -> dict:
    """How much the ideal sensor's lag (and with it the latency beyond the simulation) moves
    with the frame interpolation and the thresholds on DAVIS346, and how much the rate
    cross-correlation that ``rdnet calibrate``'s latency comes from moves with the
    interpolation and with where inside its frame interval each event falls (times spread
    uniformly over the interval: recorded, simulated, both; seed 0 of the basic refit)."""
    import copy

    from rdnet.calib import stats as st
    from rdnet.calib.fit import Objective
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    lags = []
    contexts = {}                     # one context (flows, warps) per interpolation, for every use
    for method in ("flow", "linear", "cubic", "selected"):
        contexts[method] = _context(rec, report, cfg, method)
        for scale in (1.0, 1.5, round(float(report["basic_refit"].get("threshold_scale", 1.0)), 2)):
            r = copy.deepcopy(report)
            r["frame_interpolation"]["chosen"] = method
            r["basic_refit"] = {**r["basic_refit"], "threshold_scale": scale}
            ref = reference_scans(rec, r, cfg, ctx=contexts[method])
            lags.append({"interpolation": method, "threshold_scale": scale,
                         "ideal_lag_us": ref["simulated_basic_refit"]["latency_us"],
                         "recorded_lag_us": ref["recorded"]["latency_us"],
                         "latency_beyond_simulation_us": ref["latency_beyond_simulation_us"]})
    sensor = SensorConfig(**report["base_config"]["sensor"])
    degrade = DegradeConfig(**report["base_config"]["degrade"])
    rng = np.random.default_rng(0)

    def uniform(t, ft):
        i = np.searchsorted(ft, t, side="right") - 1
        ok = (i >= 0) & (i < len(ft) - 1)
        out = t.astype(np.float64)
        out[ok] = ft[i[ok]] + rng.random(int(ok.sum())) * (ft[i[ok] + 1] - ft[i[ok]])
        return out
    xcorr = []
    for method in ("flow", "linear", "cubic"):
        ctx = contexts[method]
        sim = Objective(ctx, sensor, degrade, [0]).simulate(dict(report["basic_refit"]), 0)
        edges = np.arange(ctx.t0, ctx.t1 + 1, cfg.time_bin_us)
        mask = np.ones(len(edges) - 1, bool)

        def lag(a, b) -> float:
            ra, rb = (np.histogram(v, bins=edges)[0].astype(float) for v in (a, b))
            return float(st.xcorr_lag_us(ra, rb, mask, float(cfg.time_bin_us), float(cfg.max_lag_us)))
        st_, rt = sim.t.astype(np.float64), ctx.real.t.astype(np.float64)
        xcorr.append({"interpolation": method, "as_recorded": lag(st_, rt),
                      "simulated_times_uniform": lag(uniform(sim.t, ctx.frame_t), rt),
                      "recorded_times_uniform": lag(st_, uniform(ctx.real.t, ctx.frame_t)),
                      "both_uniform": lag(uniform(sim.t, ctx.frame_t), uniform(ctx.real.t, ctx.frame_t))})
    return {"ideal_lag": lags, "rate_xcorr_lag_us": xcorr}


#: the kinds of proof case the summary groups (name test on the case, truth in us)
KINDS = (("latency, 4 ms", lambda n: "latency" in n and "_s2" not in n),
         ("latency, 1.5 ms", lambda n: "latency" in n and "_s2" in n),
         ("bandwidth (no latency)", lambda n: "bandwidth" in n),
         ("refractory (no latency)", lambda n: "refractory" in n),
         ("nulls (no latency)", lambda n: "null" in n),
         ("every other effect (no latency)", lambda n: True))


def proof_reports() -> dict:
    """Every committed proof report's ``latency_timing``: the latency beyond the simulation
    at the interpolation the calibration chose (recorded lag - that interpolation's ideal
    lag), whether the true latency lies in the range over the interpolations (widened by the
    recorded lag's 95 % half-width), and by how much a named latency misses that range, as
    a fraction of the frame interval; summarised per block and kind of case."""
    rows = []
    for f in sorted(PROOF.glob("**/report.json")):
        case = str(f.parent.relative_to(PROOF))
        r = json.loads(f.read_text())
        lt = r.get("latency_timing")
        if lt is None or None in lt["latency_range_us"]:
            continue
        name = case.split("/")[-1]
        kind = next(k for k, sel in KINDS if sel(name))
        truth = 4000.0 if kind == "latency, 4 ms" else 1500.0 if kind == "latency, 1.5 ms" else 0.0
        lo, hi = lt["latency_range_us"]
        rec, ci = lt["recorded_lag_us"], lt["recorded_ci95_us"]
        half = max(rec - ci[0], ci[1] - rec)
        named = [e for e in r["effects"] if e["name"] == "latency" and e["missing"]]
        fitted = named[0]["parameters"]["latency_us"] if named else None
        miss = None if fitted is None else max(lo - fitted, fitted - hi, 0.0) / lt["frame_interval_us"]
        rows.append({"case": case, "block": case.split("/")[0] if "/" in case else "rdnet", "kind": kind,
                     "truth_us": truth, "beyond_chosen_us": rec - lt["ideal_lag_us"][r["frame_interpolation"]["chosen"]],
                     "range_us": [lo, hi], "half_ci_us": half, "truth_inside": bool(lo - half <= truth <= hi + half),
                     "named_latency_us": fitted, "named_miss_of_frame_interval": miss})
    summary = []
    for block in dict.fromkeys(row["block"] for row in rows):
        for kind, _ in KINDS:
            rs = [row for row in rows if row["block"] == block and row["kind"] == kind]
            if rs:
                err = np.array([row["beyond_chosen_us"] - row["truth_us"] for row in rs])
                summary.append({"block": block, "kind": kind, "cases": len(rs),
                                "beyond_chosen_us": [round(row["beyond_chosen_us"]) for row in rs],
                                "mean_error_us": float(err.mean()), "max_abs_error_us": float(np.abs(err).max()),
                                "truth_inside_range": sum(row["truth_inside"] for row in rs)})
    misses = [row["named_miss_of_frame_interval"] for row in rows if row["named_miss_of_frame_interval"] is not None]
    return {"cases": rows, "summary": summary, "named_latencies": len(misses),
            "largest_named_miss_of_frame_interval": max(misses) if misses else None}


def figure(davis: dict, calibrated_us: float | None, ref: dict | None, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rdnet.events.io._common import atomic_output
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    x = np.asarray(davis["shifts_us"]) / 1000.0
    ax.plot(x, davis["correlation"], color="C0", label="event-frame correlation (recorded events shifted)")
    lo, hi = davis["ci95_us"]
    ax.axvspan(lo / 1000.0, hi / 1000.0, color="C0", alpha=0.2,
               label=f"scan: {davis['latency_us'] / 1000:.2f} ms (95 % {lo / 1000:.2f}-{hi / 1000:.2f})")
    if ref:
        sim = ref["simulated_basic_refit"]["latency_us"] / 1000.0
        ax.axvline(sim, color="C2", ls=":", label=f"ideal sensor simulated ({ref['interpolation']} frames): {sim:.2f} ms")
        if calibrated_us is not None and "simulated_with_calibrated_latency" in ref:
            both = ref["simulated_with_calibrated_latency"]["latency_us"] / 1000.0
            ax.axvline(both, color="C3", ls="--",
                       label=f"the same + the latency rdnet calibrate names ({calibrated_us / 1000:.2f} ms): {both:.2f} ms")
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.set_xlabel("events moved earlier by (ms)")
    ax.set_ylabel("correlation of ON - OFF with d log I")
    ax.set_title("DAVIS346 road: latency read off frames and events alone", fontsize=10)
    ax.legend(fontsize=6.5, loc="lower center")
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def md_table_lines(head: list[str], rows: list[list[str]]) -> list[str]:
    """Markdown table lines: the first column left-aligned, the others right-aligned."""
    return (["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
            + ["| " + " | ".join(r) + " |" for r in rows])


def markdown(result: dict) -> str:
    d = result["davis346"]
    lines = ["# A latency read off frames and events alone (no simulator, no interpolation)", "",
             f"`benchmarks/latency_consistency_scan.py`: the shift that, undone, makes the net event count "
             f"between two frames follow their log change best (`rdnet.calib.consistency.latency_scan`; "
             f"pixel-intervals with |d log I| >= {result['min_change']:g}, grid step {result['step_us']:g} us, "
             f"{result['resamples']} bootstrap draws of the frame intervals).", ""]
    if d:
        cal = result.get("davis346_calibrate_latency_us")
        lines += ["## DAVIS346 road (recorded events, frames 40 ms apart)", "",
                  f"- scan: **{d['latency_us'] / 1000:.2f} ms** (95 % {d['ci95_us'][0] / 1000:.2f}-"
                  f"{d['ci95_us'][1] / 1000:.2f} ms; {d['intervals']} frame intervals, "
                  f"{d['pixel_intervals']:,} pixel-intervals); correlation {d['correlation'][len(d['shifts_us']) // 2]:.3f} "
                  f"as recorded, {max(d['correlation']):.3f} at the peak",
                  "- `rdnet calibrate` (seed 0, `results/calibration/davis346/report.json`): "
                  + (f"{cal / 1000:.2f} ms" if cal is not None else "no latency named"),
                  "- the scan with |d log I| >= 0.1 / 0.4: " + " / ".join(
                      f"{r['latency_us'] / 1000:.2f} ms" for r in result["davis346_other_min_change"]), ""]
        ref = result.get("davis346_reference")
        if ref:
            lines += [f"On the calibration's pixel sample (stride {ref['pixel_stride']}), against rdnet's simulation at "
                      f"what `rdnet calibrate` fitted before naming an effect ({ref['interpolation']} frames, the basic "
                      "refit): an ideal stream scans above 0, because a pixel fires only once its change reaches a "
                      "threshold, so the difference is the latency beyond the simulation.", "",
                      "| stream | scan (ms) | 95 % (ms) |", "|---|---:|---|"]
            for key, label in (("recorded", "recorded events"), ("simulated_basic_refit", "simulated, basic refit"),
                               ("simulated_with_calibrated_latency", "simulated, basic refit + the named latency")):
                if key in ref:
                    r = ref[key]
                    lines.append(f"| {label} | {r['latency_us'] / 1000:.2f} | {r['ci95_us'][0] / 1000:.2f}-"
                                 f"{r['ci95_us'][1] / 1000:.2f} |")
            lines += ["", f"Latency beyond the simulation: **{ref['latency_beyond_simulation_us'] / 1000:.2f} ms**.", ""]
        lines += ["![scan](latency_consistency_scan.png)", ""]
    sens = result.get("davis346_sensitivity")
    if sens:
        lines += ["### DAVIS346: what the interpolation and the thresholds do", "",
                  "The ideal sensor's lag behind the frames (basic-refit simulation, seed 0, every 2nd pixel) and "
                  "the latency beyond it, per interpolation and threshold scale:", ""]
        lines += md_table_lines(["interpolation", "thresholds x", "ideal lag (ms)", "latency beyond it (ms)"],
                        [[r["interpolation"], f"{r['threshold_scale']:g}", f"{r['ideal_lag_us'] / 1000:.2f}",
                          f"{r['latency_beyond_simulation_us'] / 1000:.2f}"] for r in sens["ideal_lag"]])
        lines += ["", "The rate cross-correlation `rdnet calibrate`'s latency guess reads (`xcorr_lag_us`, "
                  "2 ms bins, basic refit, seed 0), as simulated and recorded, and with the events' times spread "
                  "uniformly inside their frame intervals:", ""]
        keys = ("as_recorded", "simulated_times_uniform", "recorded_times_uniform", "both_uniform")
        lines += md_table_lines(["interpolation", "as recorded (ms)", "simulated times uniform", "recorded times uniform",
                         "both"], [[r["interpolation"]] + [f"{r[k] / 1000:.1f}" for k in keys]
                                   for r in sens["rate_xcorr_lag_us"]])
        lines.append("")
    pr = result.get("proof")
    if pr:
        lines += ["## The calibration proof's recordings (truth known; frames 10 ms apart)", "",
                  "From the committed reports (`latency_timing`): the latency beyond rdnet's simulation at the "
                  "interpolation each case's calibration chose (recorded lag minus its ideal lag), its error against "
                  "the truth, and how often the range over the interpolations tried, widened by the recorded lag's "
                  "95 % half-width, holds the truth.", ""]
        lines += md_table_lines(["block", "cases", "n", "beyond the simulation (us)", "error (mean / largest, us)",
                         "truth inside the range"],
                        [[x["block"], x["kind"], str(x["cases"]), ", ".join(map(str, x["beyond_chosen_us"])),
                          f"{x['mean_error_us']:.0f} / {x['max_abs_error_us']:.0f}",
                          f"{x['truth_inside_range']} of {x['cases']}"] for x in pr["summary"]])
        lines += ["", f"Named latencies: {pr['named_latencies']}; the largest miss of its range by a named latency: "
                  f"{100 * pr['largest_named_miss_of_frame_interval']:.1f} % of the frame interval"
                  + (f" (DAVIS346: {100 * result['davis346_named_miss_of_frame_interval']:.1f} %)."
                     if result.get("davis346_named_miss_of_frame_interval") is not None else "."), ""]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from rdnet.calib.report import write_json
    from rdnet.eval.report import write_text_atomic
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "latency_consistency_scan")
    ap.add_argument("--min-change", type=float, default=0.2,
                    help="log change of the pixel-intervals the full-resolution DAVIS346 scan scores")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    t = time.perf_counter()
    result = {"benchmark": "latency_consistency_scan", "min_change": args.min_change, "resamples": 200,
              "step_us": 500.0, "davis346": None}
    if REAL.is_file():
        from rdnet.config import load_params, section
        from rdnet.events.io import load
        rec = load(REAL)
        result["davis346"] = scan(rec, 0.01, args.min_change)
        result["davis346_other_min_change"] = [
            {k: v for k, v in scan(rec, 0.01, mc).items() if k in ("latency_us", "ci95_us")} for mc in (0.1, 0.4)]
        if REPORT.is_file():
            cfg = section(load_params(ROOT / "params.yaml"), "calibrate")
            report = json.loads(REPORT.read_text())
            named = [e for e in report["effects"] if e["name"] == "latency" and e["missing"]]
            cal = named[0]["parameters"]["latency_us"] if named else None
            result["davis346_calibrate_latency_us"] = cal
            result["davis346_reference"] = reference_scans(
                rec, report, cfg, extra={} if cal is None else {"with_calibrated_latency": {"latency_us": cal}})
            result["davis346_sensitivity"] = davis346_sensitivity(rec, report, cfg)
            lt = report.get("latency_timing")
            if lt and lt["latency_range_us"][0] is not None and cal is not None:
                lo, hi = lt["latency_range_us"]
                result["davis346_named_miss_of_frame_interval"] = max(lo - cal, cal - hi, 0.0) / lt["frame_interval_us"]
    if PROOF.is_dir():
        result["proof"] = proof_reports()
    result["wall_s"] = time.perf_counter() - t
    write_json(args.out.with_suffix(".json"), result)
    write_text_atomic(args.out.with_suffix(".md"), markdown(result))
    if result["davis346"]:
        figure(result["davis346"], result.get("davis346_calibrate_latency_us"), result.get("davis346_reference"),
               args.out.with_suffix(".png"))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
