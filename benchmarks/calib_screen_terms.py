"""Why a proof case's effect is or is not screened in: the discrepancy of the screen's points,
term by term (issue 12; docs/calibration.md, "The static pixels' ON fraction against its
sampling error").

Rebuilds one case of the ``calibration_proof`` stage (its generator's block, the draws the
case gets in the whole proof, the ``calibrate`` section of params.yaml) and runs the steps
of ``rdnet calibrate`` up to the screen on one frame interpolation: the context, the three
objectives, the basic refit and :func:`rdnet.calib.fit.screen` of ``--effect``. For the
basic refit, every screen point, the truth and every ``--point``, it reports the fit- and
held-out discrepancy on the search level (as the screen sees them) with every term, and the
static and moving pixels' statistics of ``--stat-seeds`` simulations (whole window), against
the recording's (whole window, fit and held-out segments).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_screen_terms.py --case leak_under_shot_noise
    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_screen_terms.py --case leak_under_shot_noise_s1B \\
        --point shot_noise_hz=2.0 --results /tmp/terms
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from rdnet.calib import stats as st
from rdnet.calib.calibrate import _objectives, calibration_interpolation
from rdnet.calib.context import build_context
from rdnet.calib.effects import EFFECTS
from rdnet.calib.fit import fit_basic, screen
from rdnet.calib.proof import case_draws, generator_blocks, make_recording
from rdnet.calib.scene import SceneSpec
from rdnet.config import load_params, section
from rdnet.eval.report import write_text_atomic
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("calib_screen_terms")
STAT_KEYS = ("static_rate", "static_on_fraction", "static_count", "on_fraction")


def _stats(a: dict) -> dict:
    return {k: float(a[k]) for k in STAT_KEYS}


def rebuild(case_name: str, generator: str, cfg, seed: int):
    """The case and its recording and truth, as the ``calibration_proof`` stage makes them."""
    interp = calibration_interpolation(cfg)
    block = generator_blocks(None, generator=generator, names=[case_name], cfg=cfg, interpolate=interp)[0]
    rng, spec = np.random.default_rng(seed), SceneSpec()
    draws = {c.name: case_draws(c, spec, rng) for c in block.cases}      # in block order, as the stage
    case = next(c for c in block.cases if c.name == case_name)
    rec, truth = make_recording(case, spec, SensorConfig(), None, interpolate=interp, draws=draws[case_name])
    return case, rec, truth


def run(args) -> dict:
    cfg = section(load_params(args.params), "calibrate")
    case, rec, truth = rebuild(args.case, args.generator, cfg, args.seed)
    sensor, degrade = SensorConfig(), DegradeConfig(**case.base)
    ctx = build_context(rec, cfg, sensor.log_eps, source=case.name,
                        interpolate=calibration_interpolation(cfg, args.interpolation))
    seeds = list(range(cfg.seeds))                      # rdnet calibrate --seed 0
    _, fine, search = _objectives(ctx, sensor, degrade, seeds, None)
    basic, beta = fit_basic(search, fine)
    evs, _, _ = screen(search, basic, EFFECTS[args.effect], cfg.search_points, beta)
    truth_values = {**truth["degrade"], "threshold_scale": truth["threshold_scale"]}
    points = [("basic refit", basic)] + [(f"screen point {i + 1}", e.values) for i, e in enumerate(evs)]
    points += [("truth", truth_values)]
    for p in args.point:
        points.append((p, {**basic, **{k: float(v) for k, v in (kv.split("=") for kv in p.split(","))}}))
    real = st.summarize(ctx.real, ctx)
    out = {"case": case.name, "generator": case.generator, "interpolation": args.interpolation,
           "effect": args.effect, "truth": truth_values, "search_pixels": search.ctx.n_pixels,
           "real": {"all": _stats(search.real_all), "fit": _stats(search.real_fit), "held": _stats(search.real_held),
                    "final_sample_all": _stats(st.aggregate(real, ctx, range(len(ctx.segments))))},
           "points": []}
    for label, values in points:
        ev = search(values)
        out["points"].append({
            "label": label, "values": {k: float(v) for k, v in ev.values.items()},
            "fit": ev.fit_mean, "held": ev.held_mean,
            "fit_terms": {k: float(v.mean()) for k, v in ev.fit_terms.items()},
            "held_terms": {k: float(v.mean()) for k, v in ev.held_terms.items()},
            "seed_stats": [_stats(search.stats_all(values, s)) for s in range(args.stat_seeds)]})
        log.info("%s %s: fit %.3f held-out %.3f", label, values, ev.fit_mean, ev.held_mean)
    return out


def markdown(r: dict) -> str:
    pts = r["points"]
    head = ["term"] + [p["label"] for p in pts]
    lines = [f"# Screen of `{r['effect']}` in proof case `{r['case']}` ({r['generator']} generator)", "",
             f"Frame interpolation {r['interpolation']}, the search level ({r['search_pixels']} pixels, its seeds), "
             f"truth {r['truth']}. Discrepancy fit / held-out per point; the screen keeps an effect whose best "
             "point lowers the fit discrepancy (calibrate.screen_gain).", "",
             "| " + " | ".join(head) + " |", "|---|" + "---:|" * len(pts),
             "| values | " + " | ".join(", ".join(f"{k}={v:.4g}" for k, v in p["values"].items()) for p in pts) + " |",
             "| **total** | " + " | ".join(f"{p['fit']:.3f} / {p['held']:.3f}" for p in pts) + " |"]
    for k in pts[0]["fit_terms"]:
        lines.append(f"| {k} | " + " | ".join(f"{p['fit_terms'][k]:.3f} / {p['held_terms'][k]:.3f}" for p in pts)
                     + " |")
    rr = r["real"]
    lines += ["", "Static and moving pixels' statistics, whole window (static ON fraction, static rate Hz, "
              "moving ON fraction). Recording: all " + _fmt(rr["all"]) + "; fit segments " + _fmt(rr["fit"])
              + "; held-out " + _fmt(rr["held"]) + ".", "",
              "| point | per simulation seed |", "|---|---|"]
    for p in pts:
        lines.append(f"| {p['label']} | " + "; ".join(_fmt(s) for s in p["seed_stats"]) + " |")
    return "\n".join(lines) + "\n"


def _fmt(s: dict) -> str:
    return f"{s['static_on_fraction']:.3f} / {s['static_rate']:.3f} / {s['on_fraction']:.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", required=True, help="a case name of the proof (its report folder's name)")
    ap.add_argument("--generator", choices=("rdnet", "circuit"), default="rdnet")
    ap.add_argument("--interpolation", default="flow", choices=("flow", "linear", "selected"))
    ap.add_argument("--effect", default="leak_events", choices=sorted(EFFECTS))
    ap.add_argument("--point", action="append", default=[], metavar="KEY=VALUE[,KEY=VALUE]",
                    help="another parameter set on top of the basic refit")
    ap.add_argument("--stat-seeds", type=int, default=8, help="simulation seeds of the statistics per point")
    ap.add_argument("--seed", type=int, default=2024, help="the proof's seed (calibration_proof --seed)")
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--results", type=Path, default=None,
                    help="path stem of the .json / .md (default benchmarks/results/calib_screen_terms_<case>)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    result = run(args)
    stem = args.results or ROOT / "benchmarks" / "results" / f"calib_screen_terms_{args.case}"
    write_text_atomic(Path(f"{stem}.json"), json.dumps(result, indent=1) + "\n")
    write_text_atomic(Path(f"{stem}.md"), markdown(result))
    print(markdown(result))


if __name__ == "__main__":
    main()
