"""A sensor latency read off a recording with no simulator and no frame interpolation
(issue 12: a check of `rdnet calibrate`'s latency on data and a model it was not built from).

:func:`rdnet.calib.consistency.latency_scan` shifts the events earlier by L and scores, for
every L on a grid, how well the net event count between two frames (ON - OFF) follows the
change of log intensity between them (Pearson correlation over the pixel-intervals whose log
change is at least the threshold); the estimate is the best shift, with a bootstrap interval
over the frame intervals. It shares no code with the simulator, the interpolation or the
calibration's statistics, so it is an independent reading of the same physics.

* The calibration proof's concealed recordings (the stage's cases and draws, 64 x 64, 100 fps:
  frames 10 ms apart), all three blocks: rdnet's simulator, the same with the true events from
  4x denser frames (`oversample4`), and the independent circuit generator. The truth is known:
  the latency cases hide 4 ms (`s1`) and 1.5 ms (`s2`) under 1 ms of jitter, the other cases
  and the nulls have none (a bandwidth limit delays the dark pixels instead).
* DAVIS346 road (frames 40 ms apart, the recorded events), against the latency `rdnet
  calibrate` names there (`results/calibration/davis346/report.json`).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/latency_consistency_scan.py
    # -> benchmarks/results/latency_consistency_scan.{json,md,png} (about 15 min on 2 cores; --skip-proof: DAVIS346 only, about 1 min)
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4"
REPORT = ROOT / "results" / "calibration" / "davis346" / "report.json"
PROOF = ROOT / "results" / "calibration" / "proof"
log = logging.getLogger("latency_consistency_scan")


def frames_ctx(frames, events, log_eps: float) -> SimpleNamespace:
    """What :func:`latency_scan` reads of the frames (:class:`rdnet.calib.consistency.FrameSeries`),
    at full resolution, the compared window where frames and events overlap."""
    g = frames.grey().astype(np.float32)
    return SimpleNamespace(frame_t=frames.t_us.astype(np.int64), log_frames=np.log(g + np.float32(log_eps)),
                           width=g.shape[2], n_pixels=g.shape[1] * g.shape[2],
                           t0=int(max(frames.t_us[0], events.t[0])), t1=int(min(frames.t_us[-1], events.t[-1] + 1)))


def scan(rec, log_eps: float, max_shift_us: float, step_us: float, min_change: float, seed: int = 0) -> dict:
    from rdnet.calib.consistency import latency_scan
    ctx = frames_ctx(rec.frames, rec.events, log_eps)
    return latency_scan(rec.events, ctx, max_shift_us=max_shift_us, step_us=step_us, min_change=min_change,
                        rng=np.random.default_rng(seed))


def reference_scans(rec, report: dict, cfg, max_shift_us: float, step_us: float, min_change: float,
                    extra: dict | None = None) -> dict:
    """The scan of the recording and of rdnet's simulation of it at what ``rdnet calibrate``
    fitted before naming any effect (its report: base config, basic refit, chosen frame
    interpolation), on the calibration's pixel sample. The scan of an ideal stream is not 0:
    a pixel fires only once its change has reached a threshold, so its events trail the
    change (by about half its inter-event time); the simulation carries that lag too, so
    ``scan(recording) - scan(simulation)`` is the latency beyond it. ``extra``: more
    simulated configs on top of the basic refit (name -> values)."""
    from rdnet.calib.consistency import latency_scan
    from rdnet.calib.context import build_context
    from rdnet.calib.fit import Objective
    from rdnet.sim.interpolate import InterpolateConfig
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    sensor = SensorConfig(**report["base_config"]["sensor"])
    degrade = DegradeConfig(**report["base_config"]["degrade"])
    icfg = InterpolateConfig(method=report["frame_interpolation"]["chosen"], max_upsample=cfg.max_upsample)
    ctx = build_context(rec, cfg, sensor.log_eps, interpolate=icfg, source="scan")
    obj = Objective(ctx, sensor, degrade, [0])
    basic = dict(report["basic_refit"])

    def one(ev) -> dict:
        r = latency_scan(ev, ctx, max_shift_us=max_shift_us, step_us=step_us, min_change=min_change,
                         rng=np.random.default_rng(0))
        return {k: r[k] for k in ("latency_us", "ci95_us", "at_edge")}
    out = {"recorded": one(ctx.real), "simulated_basic_refit": one(obj.simulate(basic, 0)),
           "interpolation": icfg.method, "pixel_stride": ctx.stride}
    for name, values in (extra or {}).items():
        out["simulated_" + name] = one(obj.simulate({**basic, **values}, 0))
    out["latency_beyond_simulation_us"] = out["recorded"]["latency_us"] - out["simulated_basic_refit"]["latency_us"]
    return out


def proof_rows(step_us: float, max_shift_us: float, min_change: float, seed: int) -> list[dict]:
    """Every case of the proof's three blocks, rendered as the stage renders it, with its
    reference scans (:func:`reference_scans`, from the case's committed report)."""
    from rdnet.calib.proof import Block, case_draws, generator_blocks, make_recording
    from rdnet.calib.scene import SceneSpec
    from rdnet.config import load_params, section
    from rdnet.sim.interpolate import InterpolateConfig
    from rdnet.sim.settings import SensorConfig
    cfg = section(load_params(ROOT / "params.yaml"), "calibrate")
    interp = InterpolateConfig(max_upsample=cfg.max_upsample)
    blocks = generator_blocks(None, interpolate=interp)
    rd = next(b for b in blocks if b.key == "rdnet")
    blocks.append(Block("oversample4", rd.cases, None, kw=dict(interpolate=interp, oversample=4)))
    sensor = SensorConfig()
    rows = []
    for b in blocks:
        rng = np.random.default_rng(seed)              # the stage's draws (calibration_proof --seed)
        for case in b.cases:
            draws = case_draws(case, SceneSpec(), rng)
            rec, truth = make_recording(case, SceneSpec(), sensor, None, b.kw.get("oversample", 1), interp,
                                        draws=draws)
            r = scan(rec, sensor.log_eps, max_shift_us, step_us, min_change)
            true_lat = float(truth["degrade"].get("latency_us", 0.0))
            folder = PROOF if b.key == "rdnet" else PROOF / b.key
            ref = reference_scans(rec, json.loads((folder / case.name / "report.json").read_text()), cfg,
                                  max_shift_us, step_us, min_change)
            rows.append({"block": b.key, "case": case.name, "effect": case.effect or "none",
                         "true_latency_us": true_lat, "latency_us": r["latency_us"], "ci95_us": r["ci95_us"],
                         "bootstrap_std_us": r["bootstrap_std_us"], "at_edge": r["at_edge"],
                         "peak_correlation": float(np.nanmax(r["correlation"])), "reference": ref})
            log.info("%s %s: truth %.0f us, scan %.0f us [%.0f, %.0f], beyond the simulation %.0f us", b.key,
                     case.name, true_lat, r["latency_us"], *r["ci95_us"], ref["latency_beyond_simulation_us"])
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    """Per block and kind of case: the scan's error against the true latency."""
    kinds = (("latency, 4 ms", lambda r: r["effect"] == "latency" and r["true_latency_us"] == 4000.0),
             ("latency, 1.5 ms", lambda r: r["effect"] == "latency" and r["true_latency_us"] == 1500.0),
             ("bandwidth (no latency)", lambda r: r["effect"] == "bandwidth"),
             ("nulls (no latency)", lambda r: r["effect"] == "none"),
             ("every other effect (no latency)", lambda r: r["effect"] not in ("latency", "bandwidth", "none")))
    out = []
    for block in dict.fromkeys(r["block"] for r in rows):
        for kind, sel in kinds:
            rs = [r for r in rows if r["block"] == block and sel(r)]
            if not rs:
                continue
            err = np.array([r["latency_us"] - r["true_latency_us"] for r in rs])
            beyond = np.array([r["reference"]["latency_beyond_simulation_us"] for r in rs])
            inside = sum(r["ci95_us"][0] <= r["true_latency_us"] <= r["ci95_us"][1] for r in rs)
            out.append({"block": block, "kind": kind, "cases": len(rs),
                        "scan_us": [round(r["latency_us"]) for r in rs],
                        "mean_error_us": float(err.mean()), "max_abs_error_us": float(np.abs(err).max()),
                        "truth_inside_ci95": int(inside),
                        "beyond_simulation_us": [round(v) for v in beyond],
                        "beyond_mean_error_us": float((beyond - [r["true_latency_us"] for r in rs]).mean()),
                        "beyond_max_abs_error_us": float(np.abs(beyond - [r["true_latency_us"] for r in rs]).max())})
    return out


def davis346_sensitivity(rec, report: dict, cfg, min_change: float) -> dict:
    """How much the ideal sensor's lag (and with it the latency beyond the simulation) moves
    with the frame interpolation and the thresholds on DAVIS346, and how much the rate
    cross-correlation that ``rdnet calibrate``'s latency comes from moves with the
    interpolation and with where inside its frame interval each event falls (times spread
    uniformly over the interval: recorded, simulated, both; seed 0 of the basic refit)."""
    import copy

    from rdnet.calib import stats as st
    from rdnet.calib.context import build_context
    from rdnet.calib.fit import Objective
    from rdnet.sim.interpolate import InterpolateConfig
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    lags = []
    for method in ("flow", "linear", "cubic", "selected"):
        for scale in (1.0, 1.5, round(float(report["basic_refit"].get("threshold_scale", 1.0)), 2)):
            r = copy.deepcopy(report)
            r["frame_interpolation"]["chosen"] = method
            r["basic_refit"] = {**r["basic_refit"], "threshold_scale": scale}
            ref = reference_scans(rec, r, cfg, 20000.0, 500.0, min_change)
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
        ctx = build_context(rec, cfg, sensor.log_eps, source="scan",
                            interpolate=InterpolateConfig(method=method, max_upsample=cfg.max_upsample))
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


def report_ranges() -> dict:
    """The ``latency_timing`` of every committed proof report: whether the true latency lies
    in its range (widened by the recorded lag's 95 % half-width), and by how much each named
    latency misses its range, as a fraction of the frame interval."""
    rows = []
    for f in sorted(PROOF.glob("**/report.json")):
        case = str(f.parent.relative_to(PROOF))
        r = json.loads(f.read_text())
        lt = r.get("latency_timing")
        if lt is None or None in lt["latency_range_us"]:
            continue
        name = case.split("/")[-1]
        kind = next((k for k in ("latency", "bandwidth", "refractory", "null") if k in name), "other")
        truth = 0.0 if kind != "latency" else (1500.0 if "_s2" in name else 4000.0)
        lo, hi = lt["latency_range_us"]
        rec, ci = lt["recorded_lag_us"], lt["recorded_ci95_us"]
        half = max(rec - ci[0], ci[1] - rec)
        named = [e for e in r["effects"] if e["name"] == "latency" and e["missing"]]
        fitted = named[0]["parameters"]["latency_us"] if named else None
        miss = None if fitted is None else max(lo - fitted, fitted - hi, 0.0) / lt["frame_interval_us"]
        rows.append({"case": case, "kind": kind, "truth_us": truth, "range_us": [lo, hi], "half_ci_us": half,
                     "truth_inside": bool(lo - half <= truth <= hi + half), "named_latency_us": fitted,
                     "named_miss_of_frame_interval": miss})
    kinds = {}
    for row in rows:
        k = kinds.setdefault(row["kind"], {"cases": 0, "truth_inside": 0})
        k["cases"] += 1
        k["truth_inside"] += int(row["truth_inside"])
    misses = [row["named_miss_of_frame_interval"] for row in rows if row["named_miss_of_frame_interval"] is not None]
    return {"cases": rows, "by_kind": kinds, "named_latencies": len(misses),
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


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
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
        lines += _table(["interpolation", "thresholds x", "ideal lag (ms)", "latency beyond it (ms)"],
                        [[r["interpolation"], f"{r['threshold_scale']:g}", f"{r['ideal_lag_us'] / 1000:.2f}",
                          f"{r['latency_beyond_simulation_us'] / 1000:.2f}"] for r in sens["ideal_lag"]])
        lines += ["", "The rate cross-correlation `rdnet calibrate`'s latency guess reads (`xcorr_lag_us`, "
                  "2 ms bins, basic refit, seed 0), as simulated and recorded, and with the events' times spread "
                  "uniformly inside their frame intervals:", ""]
        keys = ("as_recorded", "simulated_times_uniform", "recorded_times_uniform", "both_uniform")
        lines += _table(["interpolation", "as recorded (ms)", "simulated times uniform", "recorded times uniform",
                         "both"], [[r["interpolation"]] + [f"{r[k] / 1000:.1f}" for k in keys]
                                   for r in sens["rate_xcorr_lag_us"]])
        lines.append("")
    rr = result.get("report_ranges")
    if rr:
        lines += ["## The calibration reports' `latency_timing` (the proof)", "",
                  "The range each committed proof report gives (recorded lag minus each interpolation's ideal lag), "
                  "widened by the recorded lag's 95 % half-width: how often it holds the truth.", "",
                  "| kind of case | cases | truth inside |", "|---|---:|---:|"]
        for k, v in rr["by_kind"].items():
            lines.append(f"| {k} | {v['cases']} | {v['truth_inside']} |")
        lines += ["", f"Named latencies: {rr['named_latencies']}; the largest miss of its range by a named latency: "
                  f"{100 * rr['largest_named_miss_of_frame_interval']:.1f} % of the frame interval"
                  + (f" (DAVIS346: {100 * result['davis346_named_miss_of_frame_interval']:.1f} %)."
                     if result.get("davis346_named_miss_of_frame_interval") is not None else "."), ""]
    lines += ["## The calibration proof's recordings (truth known; frames 10 ms apart)", "",
              "Scan of the recording alone, and the latency beyond rdnet's simulation of it at the case's basic "
              "refit (its committed report); grid step 250 us.", "",
              "| block | cases | n | scan (us) | error (mean / largest, us) | truth inside the 95 % interval "
              "| beyond the simulation (us) | its error (mean / largest, us) |",
              "|---|---|---:|---|---:|---:|---|---:|"]
    for s in result["summary"]:
        lines.append(f"| {s['block']} | {s['kind']} | {s['cases']} | {', '.join(map(str, s['scan_us']))} | "
                     f"{s['mean_error_us']:.0f} / {s['max_abs_error_us']:.0f} | {s['truth_inside_ci95']} of {s['cases']} | "
                     f"{', '.join(map(str, s['beyond_simulation_us']))} | "
                     f"{s['beyond_mean_error_us']:.0f} / {s['beyond_max_abs_error_us']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from rdnet.calib.report import write_json
    from rdnet.eval.report import write_text_atomic
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "latency_consistency_scan")
    ap.add_argument("--seed", type=int, default=2024, help="the proof's seed (calibration_proof --seed)")
    ap.add_argument("--min-change", type=float, default=0.2, help="log change of the scored pixel-intervals")
    ap.add_argument("--skip-proof", action="store_true",
                    help="DAVIS346 only (the proof rows of the results file, when there is one, are kept)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    t = time.perf_counter()
    result = {"benchmark": "latency_consistency_scan", "min_change": args.min_change, "resamples": 200,
              "davis346": None, "cases": [], "summary": []}
    if REAL.is_file():
        from rdnet.events.io import load
        rec = load(REAL)
        result["davis346"] = scan(rec, 0.01, 20000.0, 500.0, args.min_change)
        result["step_us"] = 500.0
        result["davis346_other_min_change"] = [
            {k: v for k, v in scan(rec, 0.01, 20000.0, 500.0, mc).items() if k in ("latency_us", "ci95_us")}
            for mc in (0.1, 0.4)]
        if REPORT.is_file():
            from rdnet.config import load_params, section
            report = json.loads(REPORT.read_text())
            named = [e for e in report["effects"] if e["name"] == "latency" and e["missing"]]
            cal = named[0]["parameters"]["latency_us"] if named else None
            result["davis346_calibrate_latency_us"] = cal
            result["davis346_reference"] = reference_scans(
                rec, report, section(load_params(ROOT / "params.yaml"), "calibrate"), 20000.0, 500.0, args.min_change,
                extra={} if cal is None else {"with_calibrated_latency": {"latency_us": cal}})
        if REPORT.is_file():
            result["davis346_sensitivity"] = davis346_sensitivity(
                rec, report, section(load_params(ROOT / "params.yaml"), "calibrate"), args.min_change)
            davis = report.get("latency_timing")
            if davis and davis["latency_range_us"][0] is not None and cal is not None:
                lo, hi = davis["latency_range_us"]
                result["davis346_named_miss_of_frame_interval"] = max(lo - cal, cal - hi, 0.0) / davis["frame_interval_us"]
    if PROOF.is_dir():
        result["report_ranges"] = report_ranges()
    old = args.out.with_suffix(".json")
    if args.skip_proof and old.is_file():          # keep the proof rows of the last full run
        prev = json.loads(old.read_text())
        result.update({k: prev[k] for k in ("cases", "summary", "proof_step_us") if k in prev})
    if not args.skip_proof:
        result["proof_step_us"] = 250.0
        result["cases"] = proof_rows(250.0, 8000.0, args.min_change, args.seed)
        result["summary"] = summarise(result["cases"])
    result["wall_s"] = time.perf_counter() - t
    result.setdefault("step_us", 250.0)
    write_json(args.out.with_suffix(".json"), result)
    write_text_atomic(args.out.with_suffix(".md"), markdown(result))
    if result["davis346"]:
        figure(result["davis346"], result.get("davis346_calibrate_latency_us"), result.get("davis346_reference"),
               args.out.with_suffix(".png"))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
