"""Profile of one proof case's true effect parameter, per frame interpolation: where the
calibration's discrepancy is lowest and what the effect's own statistic says there.

For a case of the ``calibration_proof`` stage (the same scene, draws and true events as the
stage: every case of its block is drawn first, in the stage's order), each interpolation of
``calibrate.interpolation`` is built as the calibration builds it, the configured parameters
re-fitted (``fit_basic``), and the effect's main parameter set to each value of ``--values``
at count-matched thresholds (``Compensated``, as the fit compares count-changing effects);
per point: the threshold factor, the fit and held-out discrepancies and the held-out terms.
It shows whether the simulator reproduces the truth at the true parameter on an
interpolation, and which interpolation a coarse screen could mistake for the better one.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_case_profile.py \\
        --case refractory_vs_lower_thresholds_s2B --values 500 1000 1500 2000 3000 7071
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from rdnet.calib import proof as P
from rdnet.calib.calibrate import _objectives, calibration_interpolation, interpolation_configs
from rdnet.calib.context import build_context
from rdnet.calib.effects import EFFECTS
from rdnet.calib.fit import Compensated, fit_basic
from rdnet.calib.report import write_json
from rdnet.calib.scene import SceneSpec
from rdnet.config import load_params, section
from rdnet.eval.report import write_text_atomic
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
TERMS = ("iei", "on_vs_intensity", "rate_map", "pixel_quantiles", "lag", "rate_time")
log = logging.getLogger("calib_case_profile")


def case_recording(name: str, generator: str, oversample: int, cfg, interp, seed: int):
    """The case's recording and truth exactly as the stage makes them."""
    cases = P.cases_for(generator)[generator]
    rng = np.random.default_rng(seed)
    draws = [P.case_draws(c, SceneSpec(), rng) for c in cases]
    names = [c.name for c in cases]
    if name not in names:
        raise SystemExit(f"no case {name!r} in the {generator} block")
    i = names.index(name)
    rec, truth = P.make_recording(cases[i], SceneSpec(), SensorConfig(), None, oversample, interp, draws=draws[i])
    return cases[i], rec, truth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", required=True)
    ap.add_argument("--generator", choices=("rdnet", "circuit"), default="rdnet")
    ap.add_argument("--oversample", type=int, default=1, help="4: the stage's oversample4 block")
    ap.add_argument("--values", type=float, nargs="+", required=True, help="values of the effect's main parameter")
    ap.add_argument("--seed", type=int, default=2024, help="the stage's --seed")
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "calib_case_profile")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    cfg = section(load_params(args.params), "calibrate")
    interp = calibration_interpolation(cfg)
    case, rec, truth = case_recording(args.case, args.generator, args.oversample, cfg, interp, args.seed)
    effect = EFFECTS[case.effect]
    key = effect.params[0].key
    sensor = SensorConfig()
    seeds = list(range(cfg.seeds))
    out = {"case": case.name, "generator": args.generator, "oversample": args.oversample, "truth": truth,
           "parameter": key, "interpolations": {}}
    for icfg in interpolation_configs(cfg, interp):
        ctx = build_context(rec, cfg, sensor.log_eps, interpolate=icfg, source=case.name)
        obj, fine, search = _objectives(ctx, sensor, DegradeConfig(**case.base), seeds, None)
        values, beta = fit_basic(search, fine)
        f = Compensated(obj, beta, steps=4, tol=0.01) if effect.changes_count else obj
        rows = []
        for x in [0.0] + list(args.values):
            v = dict(values)
            if x > 0:
                v[key] = x
            ev = f(v) if x > 0 else obj(v)
            rows.append({key: x, "threshold_scale": float(ev.values.get("threshold_scale", 1.0)),
                         "fit": ev.fit_mean, "heldout": ev.held_mean,
                         "terms_heldout": {t: float(ev.held_terms[t].mean()) for t in TERMS}})
            log.warning("%s %s=%g: %s", icfg.method, key, x, rows[-1])
        out["interpolations"][icfg.method] = {"basic_refit": values, "profile": rows}
    res = args.results.with_name(f"{args.results.name}_{case.name}")
    write_json(res.with_suffix(".json"), out)
    lines = [f"# `{case.name}` ({args.generator}{', oversample ' + str(args.oversample) if args.oversample > 1 else ''})"
             f": profile of `{key}` per frame interpolation", "",
             f"Truth: {json.dumps(truth['degrade'])}, threshold factor {truth['threshold_scale']:.3f}. "
             "Final pixel sample, all calibration seeds; thresholds count-matched at each point "
             "(0: the basic refit, without the effect). `benchmarks/calib_case_profile.py`.", "",
             f"| interpolation | {key} | threshold factor | fit | held-out | " + " | ".join(TERMS) + " |",
             "|---|---:|---:|---:|---:|" + "---:|" * len(TERMS)]
    for method, d in out["interpolations"].items():
        for r in d["profile"]:
            lines.append(f"| {method} | {r[key]:g} | {r['threshold_scale']:.3f} | {r['fit']:.3f} | {r['heldout']:.3f} | "
                         + " | ".join(f"{r['terms_heldout'][t]:.3f}" for t in TERMS) + " |")
    write_text_atomic(res.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
