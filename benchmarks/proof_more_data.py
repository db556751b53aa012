"""The calibration proof with more data than the committed one gives it: the recording's
frames at the truth's rate, or a longer recording (issue 12: where the held-out residual
comes from, and what extra measurement the misses need).

Every case gets the scene, the true effect, the draws (:func:`rdnet.calib.proof.case_draws`,
taken in its block's order from ``default_rng(seed)`` as the ``calibration_proof`` stage does)
and the ``calibrate`` settings of params.yaml that it gets in the committed proof; one thing
changes:

* ``--frames fine`` (the ``oversample4`` and ``circuit`` blocks, whose truths are simulated
  from frames rendered 4x denser than the 100 fps the calibration is given): the recording
  carries those 4x-denser frames (400 fps; 240 fps for the 60 fps null). The calibration then
  no longer has to absorb its own interpolation error: does what is left of the held-out
  residual fall to the level of a calibration inverting its own model (the rdnet block's) for
  oversample4, and to the model mismatch alone for the circuit?
* ``--duration-scale K``: the scene (the same texture and motion) runs K times longer (the
  proof's 1 s -> K s), with the same six fit/held-out segments, each K times longer. Do the
  concealed effects the proof misses get named with more data, and do the nulls stay clean?

The simulation budgets (``max_sim_steps``, ``search_max_sim_steps``) are scaled by the same
factor, so the pixel sample stays the proof's (4096 pixels). ``--frames recorded
--duration-scale 1`` reproduces the committed reports (checked on three cases).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/proof_more_data.py --tag fine_frames --frames fine
    PYTHONPATH=$PWD .venv/bin/python benchmarks/proof_more_data.py --tag duration4 --duration-scale 4
    PYTHONPATH=$PWD .venv/bin/python benchmarks/proof_more_data.py --tag duration2 --duration-scale 2
    PYTHONPATH=$PWD .venv/bin/python benchmarks/proof_more_data.py --figure

Writes ``benchmarks/results/proof_more_data_<tag>.{json,md}``: per case what is named, the true
effect's rank, its held-out gain and own-statistic drop in seed spreads, and the held-out
discrepancy before/after and the noise floor, against the committed
``results/calibration/proof``; per statistic, the mean held-out distance after the fit.
``--figure`` draws ``proof_more_data_duration.png`` from the duration runs' JSON files (the true
effect's gain against the recording's length).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from rdnet.calib.calibrate import calibrate, calibration_interpolation, numba_threads
from rdnet.calib.proof import (TRUTH_PREROLL_US, TRUTH_WARMUP_US, block_draws, case_metrics, case_spec,
                               cases_for, make_recording, proof_metrics, run_jobs)
from rdnet.calib.scene import SceneSpec, render
from rdnet.config import section
from rdnet.eval.report import write_text_atomic
from rdnet.events.recording import Frames
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from latency_consistency_scan import md_table_lines  # noqa: E402

log = logging.getLogger("proof_more_data")
OVERSAMPLE = 4          # the stage's --oversample and --circuit-oversample


BLOCKS = ("rdnet", "oversample4", "circuit")


def fine_frames(case, draws, spec: SceneSpec) -> Frames:
    """The frames the case's truth was simulated from (4x the scene's rate, from t = 0 on)."""
    tex, _ = draws
    s = case_spec(case, spec)
    rolled, _ = render(s, None, fps_hz=s.fps_hz * OVERSAMPLE, texture=tex, preroll_us=TRUTH_PREROLL_US)
    k = int(np.searchsorted(rolled.t_us, 0))
    return Frames(rolled.images[k:], rolled.t_us[k:], rolled.exposure_us[k:])


def true_effect_z(report: dict, effect: str | None) -> dict:
    """The true effect's held-out gain in seed spreads and its own statistic's drop (None where
    it was not fitted, or in a null)."""
    e = next((e for e in report["effects"] if e["name"] == effect and e.get("fitted")), None)
    return {"true_gain_z": None if e is None or not e["seed_std"] else e["heldout_gain"] / e["seed_std"],
            "true_signature_z": None if e is None else (e.get("signature") or {}).get("z")}


def run_job(job) -> dict:
    block, case, draws, cfg, interp, frames, duration_scale, reports = job
    base = SceneSpec()
    spec, sensor = dataclasses.replace(base, duration_us=base.duration_us * duration_scale), SensorConfig()
    scale = duration_scale
    with numba_threads(cfg.threads):
        rec, truth = make_recording(case, spec, sensor, None, OVERSAMPLE if block == "oversample4" else 1, interp,
                                    OVERSAMPLE, TRUTH_WARMUP_US, TRUTH_PREROLL_US, draws=draws)
    if frames == "fine":
        rec = dataclasses.replace(rec, frames=fine_frames(case, draws, spec))
        scale *= OVERSAMPLE
    # the proof's pixel sample: the simulation budgets (frames x pixels) scaled with the frames
    cfg = dataclasses.replace(cfg, max_sim_steps=cfg.max_sim_steps * scale,
                              search_max_sim_steps=cfg.search_max_sim_steps * scale)
    t0 = time.perf_counter()
    cal = calibrate(rec, sensor, DegradeConfig(**case.base), cfg, seed=0, interpolate=interp,
                    source=f"proof_more_data:{block}:{case.name}")
    if reports is not None:
        from rdnet.calib.report import write_report
        write_report(cal, Path(reports) / block / case.name, plots=False)
    m = case_metrics(case, cal.report, truth)
    m["runtime_s"] = round(time.perf_counter() - t0, 1)
    m["sampled_pixels"] = cal.report["setup"]["sampled_pixels"]
    m["terms_heldout_after"] = cal.report["discrepancy"]["terms_heldout_after"]
    m["heldout_excess_after"] = cal.report["discrepancy"]["heldout_excess_after"]
    m["search_pixels"] = cal.report["setup"]["search"]["search_pixels"]
    m.update(true_effect_z(cal.report, case.effect))
    m["block"] = block
    log.info("%s %s: named %s (rank %s), held-out %.3f -> %.3f", block, case.name, m["named"], m["rank"],
             m["heldout_before"], m["heldout_after"])
    return m


def jobs_for(blocks, names, seed, cfg, interp, frames, duration_scale=1, reports=None):
    todo = cases_for("both")
    return [(block, c, d, cfg, interp, frames, duration_scale, reports) for block in blocks   # the stage's draws
            for c, d in block_draws(todo["circuit" if block == "circuit" else "rdnet"], SceneSpec(), seed)
            if names is None or c.name in names]


PROOF = ROOT / "results" / "calibration" / "proof"


def committed_cases(block: str) -> dict:
    """The committed proof's case metrics of ``block`` (``rdnet``: the top-level folder), each with
    its report's held-out terms after the fit and its excess over the noise floor."""
    folder = PROOF if block == "rdnet" else PROOF / block
    out = {}
    for r in json.loads((folder / "proof.json").read_text())["cases"]:
        rep = json.loads((folder / r["case"] / "report.json").read_text())
        d = rep["discrepancy"]
        out[r["case"]] = {**r, "terms_heldout_after": d["terms_heldout_after"],
                          "heldout_excess_after": d["heldout_excess_after"], **true_effect_z(rep, r["true_effect"])}
    return out


def term_table(rows: list[dict], label: str) -> list[str]:
    """Mean held-out distance after the fit per statistic: the committed rdnet block (its truth
    from the frames the calibration upsamples: the level of a calibration inverting its own
    model) and each block as committed and in this run."""
    ref = list(committed_cases("rdnet").values())
    cols = [("rdnet block, committed", ref)]
    for b in [b for b in BLOCKS if any(r["block"] == b for r in rows)]:
        sel = [r for r in rows if r["block"] == b]
        cols += [(f"{b}, committed", [r["committed"] for r in sel]), (f"{b}, {label}", sel)]
    terms = list(ref[0]["terms_heldout_after"])
    body = [[t, *[f"{np.mean([c['terms_heldout_after'][t] for c in rs]):.3f}" for _, rs in cols]] for t in terms]
    body.append(["**excess over the noise floor**",
                 *[f"**{np.mean([c['heldout_excess_after'] for c in rs]):.3f}**" for _, rs in cols]])
    return md_table_lines(["statistic", *[c for c, _ in cols]], body)


def _fmt_named(named) -> str:
    return ", ".join(named) or "none"


def _z(v) -> str:
    return "-" if v is None else f"{v:.1f}"


def describe(frames: str, duration_scale: int) -> str:
    parts = []
    if frames == "fine":
        parts.append(f"the recording carries the {OVERSAMPLE}x-denser frames the truth was simulated from "
                     "(400 fps; 240 fps for the 60 fps null) instead of the 100 fps ones")
    if duration_scale != 1:
        parts.append(f"the scene runs {duration_scale}x longer ({duration_scale} s instead of 1 s; the same texture "
                     "and motion, the same six fit/held-out segments, each longer)")
    return "; ".join(parts) or "nothing (the committed proof's recordings: a reproduction check)"


def markdown(tag: str, label: str, rows: list[dict], summaries: dict, old_summaries: dict, wall_s: float,
             frames: str, duration_scale: int, command: str) -> str:
    out = [f"# The calibration proof with more data: `{tag}`",
           "",
           f"`{command}` ({len(rows)} cases, {wall_s / 60:.1f} min on this host, 2 workers). Each case as in the "
           "committed proof (same scene, same true events, same `calibrate` settings) except: "
           f"{describe(frames, duration_scale)}. The simulation budgets (`max_sim_steps`, `search_max_sim_steps`) "
           "are scaled by the same factor, so the pixel sample stays the proof's (4096 pixels; sampled here: "
           f"{sorted({r['sampled_pixels'] for r in rows})}). Committed: `results/calibration/proof/<block>/proof.json` "
           "and the cases' `report.json`.",
           "", "## Summary", "",
           ]
    keys = ["named_right_first", "ranked_first", "params_within_25pct", "heldout_halved",
            "heldout_excess_over_noise_floor_halved", "null_named_nothing"]
    body = []
    for block in summaries:
        for lab, s in (("committed", old_summaries[block]), (label, summaries[block])):
            conc = s["concealed_cases"]
            body.append([block, lab] + [f"{s[k]} / {s['null_cases'] if k.startswith('null') else conc}" for k in keys])
    out += md_table_lines(["block", "run"] + keys, body)
    out += ["", "Mean held-out discrepancy over the block's cases (before the fit / after / the noise floor):", ""]
    body = []
    for block in summaries:
        sel = [r for r in rows if r["block"] == block]
        cells = []
        for vals in ([r["committed"] for r in sel], sel):
            cells.append(" / ".join(f"{np.mean([v[k] for v in vals]):.3f}"
                                    for k in ("heldout_before", "heldout_after", "heldout_noise_floor")))
        body.append([block, *cells])
    out += md_table_lines(["block", "committed", label], body)
    out += ["", "Mean held-out distance after the fit, per statistic of the discrepancy, over the cases (and all "
            "cases of the committed rdnet block, whose truth comes from the very frames the calibration upsamples: "
            "the level of a calibration inverting its own model):", ""]
    out += term_table(rows, label)
    out += ["", "## Per case", "",
            "The true effect's held-out gain in seed spreads (`gain z`; naming needs 3 in the mean and a gain in "
            "every seed, `calibrate.significance`) and its own statistic's drop (`own z`; naming by it needs 10, "
            "`calibrate.signature_significance`).", ""]
    head = ["block", "case", f"named ({label})", "rank", "gain z / own z", "held-out before -> after (floor)",
            "committed: named", "rank", "gain z / own z", "before -> after (floor)"]
    body = []
    for r in rows:
        c = r["committed"]
        body.append([r["block"], r["case"], _fmt_named(r["named"]), str(r["rank"] or "-"),
                     f"{_z(r['true_gain_z'])} / {_z(r['true_signature_z'])}",
                     f"{r['heldout_before']:.3f} -> {r['heldout_after']:.3f} ({r['heldout_noise_floor']:.3f})",
                     _fmt_named(c["named"]), str(c["rank"] or "-"),
                     f"{_z(c['true_gain_z'])} / {_z(c['true_signature_z'])}",
                     f"{c['heldout_before']:.3f} -> {c['heldout_after']:.3f} ({c['heldout_noise_floor']:.3f})"])
    out += md_table_lines(head, body)
    return "\n".join(out) + "\n"


def duration_figure(results: Path, significance: float) -> Path:
    """``proof_more_data_duration.png`` from the committed proof and every
    ``proof_more_data_duration<K>.json`` in ``results`` (recorded frames): per concealed case,
    the true effect's held-out gain in seed spreads against the recording's length, named
    (filled) or not (open), and the naming threshold."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = {}
    for f in sorted(results.glob("proof_more_data_duration*.json")):
        d = json.loads(f.read_text())
        if d["frames"] != "recorded":
            continue
        runs[d["duration_scale"]] = {(r["block"], r["case"]): r for r in d["rows"] if r["true_effect"]}
        runs.setdefault(1, {(r["block"], r["case"]): {**r["committed"], "true_effect": r["true_effect"]}
                            for r in d["rows"] if r["true_effect"]})
    if not runs:
        raise SystemExit(f"--figure: no proof_more_data_duration*.json (recorded frames) in {results}")
    scales = sorted(runs)
    keys = sorted(set.intersection(*[set(v) for v in runs.values()]))
    colors = {"rdnet": "tab:blue", "oversample4": "tab:orange", "circuit": "tab:green"}
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    rng = np.random.default_rng(0)
    for key in keys:
        jit = rng.uniform(-0.04, 0.04)
        xs = [s * (1 + jit) for s in scales]
        zs = [runs[s][key]["true_gain_z"] for s in scales]
        ax.plot(xs, zs, "-", color=colors[key[0]], alpha=0.25, lw=0.8)
        for x_, s in zip(xs, scales):
            r = runs[s][key]
            named = bool(r["named"]) and r["named"][0] == r["true_effect"]
            ax.plot(x_, r["true_gain_z"], "o", ms=4, color=colors[key[0]], mfc=colors[key[0]] if named else "white")
    ax.axhline(significance, color="k", ls="--", lw=1)
    ax.annotate(f"naming by the gain needs {significance:g} (and a gain in every seed; filled below it: named by the "
                "effect's own statistic)", (0.5, significance * 1.15), xycoords=("axes fraction", "data"), ha="center",
                fontsize=7)
    ax.set_xscale("log", base=2)
    ax.set_xticks(scales, [f"{s} s" for s in scales])
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel("length of the proof's recording (same scene, truth and draws)")
    ax.set_ylabel("true effect's held-out gain / seed spread")
    for b, c in colors.items():
        ax.plot([], [], "o", color=c, label=b)
    ax.plot([], [], "o", color="gray", mfc="white", label="not named first")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"Calibration proof: {len(keys)} concealed effects, 1 s committed", fontsize=10)
    fig.tight_layout()
    out = results / "proof_more_data_duration.png"
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--figure", action="store_true",
                    help="only draw proof_more_data_duration.png from the committed duration runs' JSON and exit")
    ap.add_argument("--tag", help="names the results files (required unless --figure)")
    ap.add_argument("--blocks", nargs="+", choices=BLOCKS, default=None,
                    help="default: oversample4 and circuit with --frames fine, else all three")
    ap.add_argument("--cases", nargs="+", default=None, help="case names (default: every case of the blocks)")
    ap.add_argument("--frames", choices=("fine", "recorded"), default="recorded",
                    help="fine: the recording carries the frames its truth was simulated from (oversample4, circuit)")
    ap.add_argument("--duration-scale", type=int, default=1, help="the scene runs this many times longer")
    ap.add_argument("--seed", type=int, default=2024, help="the stage's --seed (as committed)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reports", type=Path, default=None, help="also write each case's report.json/md here")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args()
    if args.figure:
        cfg = section(yaml.safe_load((ROOT / "params.yaml").read_text()), "calibrate")
        print(duration_figure(args.results, cfg.significance))
        return
    if not args.tag:
        ap.error("--tag is required (unless --figure)")
    blocks = args.blocks or (["oversample4", "circuit"] if args.frames == "fine" else list(BLOCKS))
    if args.frames == "fine" and "rdnet" in blocks:
        raise SystemExit("--frames fine: the rdnet block's truth comes from the recorded frames (use oversample4)")
    if args.duration_scale < 1:
        raise SystemExit(f"--duration-scale must be >= 1, got {args.duration_scale}")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    cfg = section(params, "calibrate")
    interp = calibration_interpolation(cfg)
    jobs = jobs_for(blocks, None if args.cases is None else set(args.cases), args.seed, cfg, interp, args.frames,
                    args.duration_scale, args.reports)
    t0 = time.perf_counter()
    rows = run_jobs(run_job, jobs, args.workers, first=lambda job: job[0] == "circuit")   # slow circuit cases first
    wall = time.perf_counter() - t0
    summaries, old_summaries = {}, {}
    for block in blocks:
        sel = [r for r in rows if r["block"] == block]
        if not sel:
            continue
        old = committed_cases(block)
        for r in sel:
            r["committed"] = {k: old[r["case"]][k] for k in (
                "named", "outcome", "rank", "heldout_before", "heldout_after", "heldout_noise_floor", "heldout_ratio",
                "heldout_excess_ratio", "param_max_rel_error", "terms_heldout_after", "heldout_excess_after",
                "true_gain_z", "true_signature_z") if k in old[r["case"]]}
        summaries[block] = proof_metrics([{k: v for k, v in r.items() if k != "committed"} for r in sel], None)["summary"]
        old_summaries[block] = proof_metrics([old[r["case"]] for r in sel], None)["summary"]
    label = " and ".join(([f"{OVERSAMPLE * 100} fps"] if args.frames == "fine" else [])
                         + ([f"{args.duration_scale} s"] if args.duration_scale != 1 else [])) or "rerun"
    command = "python benchmarks/proof_more_data.py " + " ".join(sys.argv[1:])
    out = {"tag": args.tag, "frames": args.frames, "duration_scale": args.duration_scale, "seed": args.seed,
           "oversample": OVERSAMPLE, "wall_s": round(wall, 1), "summary": summaries, "committed_summary": old_summaries,
           "rows": [{k: v for k, v in r.items() if k != "truth"} for r in rows]}
    write_text_atomic(args.results / f"proof_more_data_{args.tag}.json", json.dumps(out, indent=1, default=float) + "\n")
    md = markdown(args.tag, label, rows, summaries, old_summaries, wall, args.frames, args.duration_scale, command)
    write_text_atomic(args.results / f"proof_more_data_{args.tag}.md", md)
    print(md)


if __name__ == "__main__":
    main()
