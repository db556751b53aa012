"""``rdnet calibrate``: simulate a recording from its frames, locate where the events
differ from the recorded ones, re-fit the configured parameters, name the missing
effects (held-out gain significant against the seed spread) and fit them.

Use::

    cal = calibrate(recording, sensor, degrade, CalibrateConfig(), seed=0)
    cal.report          # the report.json dict
    write_report(cal, "out/")   # rdnet.calib.report
"""
from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from tqdm.auto import tqdm

from rdnet.calib.consistency import consistency
from rdnet.calib.context import CalibContext, build_context, subsample_context
from rdnet.calib.effects import absent_effects, apply
from rdnet.calib.fit import FitResult, Objective, SimulateFn, calibrate_fit
from rdnet.calib.locate import residuals, where
from rdnet.calib.settings import CalibrateConfig
from rdnet.calib.stats import STATISTICS
from rdnet.config import to_dict
from rdnet.events.recording import Recording
from rdnet.sim.effects import needs_rng
from rdnet.sim.settings import DegradeConfig, SensorConfig

log = logging.getLogger(__name__)

METRIC = ("weighted sum of normalised distances of event statistics (rdnet.calib.stats): "
          + ", ".join(STATISTICS) + "; mean over simulation seeds")


@dataclass
class Calibration:
    """Everything a report needs: the context, the fit, whole-window statistics of the
    recording and of the base / basic-refit / fitted simulations (first seed)."""

    ctx: CalibContext
    fit: FitResult
    report: dict
    real_stats: dict
    base_stats: dict
    basic_stats: dict
    fitted_stats: dict
    runtime_s: float


def _configs_dict(sensor: SensorConfig, degrade: DegradeConfig) -> dict:
    return {"sensor": to_dict(sensor), "degrade": to_dict(degrade)}


def _evidence(c, fit: FitResult) -> str:
    top = sorted(c.term_gains.items(), key=lambda kv: -kv[1])[:2]
    terms = ", ".join(f"{k} {v:+.3f}" for k, v in top)
    head = "" if c.fitted else (
        f"not fitted (its best screen point lowered the fit discrepancy by {c.screen_gain:+.3f}: below "
        f"calibrate.screen_gain, or not among the calibrate.max_fitted best screened), so never named; "
        f"that point on the search sample, {len(c.evaluation.held)} seed(s): ")
    return (head + f"held-out discrepancy {c.before_held:.3f} -> {c.evaluation.held_mean:.3f} with it "
            f"({c.ablated_held:.3f} in its own fit with it switched off); credited gain {c.gain:.3f} "
            f"= {c.z:.1f} x seed std {c.spread:.3f} ({100 * c.relative:.1f} %, round {c.round}); "
            f"statistics improved most: {terms}")


def calibrate(rec: Recording, sensor: SensorConfig, degrade: DegradeConfig,
              cfg: CalibrateConfig = CalibrateConfig(), *, seed: int = 0, interpolate=None,
              source: str = "recording", simulate_fn: SimulateFn | None = None,
              progress: bool = True) -> Calibration:
    """Diagnose ``rec`` against the simulator configured by ``sensor``/``degrade``.

    ``simulate_fn``: simulate every parameter set with this function instead of the
    composed engine (:mod:`rdnet.calib.engine`; a slow reference path). ``progress``: show
    a progress bar (on a terminal)."""
    with numba_threads(cfg.threads):
        return _calibrate(rec, sensor, degrade, cfg, seed=seed, interpolate=interpolate, source=source,
                          simulate_fn=simulate_fn, progress=progress)


@contextmanager
def numba_threads(n: int):
    """Run the block with ``n`` numba threads and ``n`` OpenCV threads (0: leave the
    settings alone). The calibration's work comes in short pieces (hundreds of small
    simulations, one optical flow per frame pair), which run fastest single-threaded
    when the cores are shared: a parallel region waits for its slowest thread."""
    import cv2
    import numba
    if n <= 0:
        yield
        return
    old, old_cv = numba.get_num_threads(), cv2.getNumThreads()
    numba.set_num_threads(min(int(n), numba.config.NUMBA_NUM_THREADS))
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        numba.set_num_threads(old)
        cv2.setNumThreads(old_cv)


def _calibrate(rec: Recording, sensor: SensorConfig, degrade: DegradeConfig, cfg: CalibrateConfig, *,
               seed: int, interpolate, source: str, simulate_fn: SimulateFn | None,
               progress: bool) -> Calibration:
    t_start = time.perf_counter()
    ctx = build_context(rec, cfg, sensor.log_eps, interpolate=interpolate, source=source)
    k = 1
    while cfg.search_max_sim_steps and k < 64 and \
            len(ctx.sim_t) * len(range(0, ctx.height, k)) * len(range(0, ctx.width, k)) > cfg.search_max_sim_steps:
        k += 1
    sctx = subsample_context(ctx, k)
    log.info("calibrating %s: %d sampled pixels (stride %d; search: %d, stride %d), %d real events, "
             "%d simulated frames", source, ctx.n_pixels, ctx.stride, sctx.n_pixels, sctx.stride,
             len(ctx.real), len(ctx.sim_t))
    seeds = [int(seed) * 1000 + j for j in range(cfg.seeds)]
    obj = Objective(ctx, sensor, degrade, seeds, simulate_fn, name="final")
    fine = obj
    if cfg.search_seeds < cfg.seeds:
        # the final pixel sample with the search seeds: shares the engine and simulations
        fine = Objective(ctx, sensor, degrade, seeds[:cfg.search_seeds], simulate_fn, engine=obj.engine,
                         name="fine")
        fine._summaries = obj._summaries
    search = fine if sctx is ctx else Objective(sctx, sensor, degrade, seeds[:cfg.search_seeds], simulate_fn,
                                                name="search")
    bar = tqdm(desc="calibrate", unit="step", disable=None if progress else True)
    try:
        fit = calibrate_fit(search, obj, fine, progress=lambda msg: (bar.set_postfix_str(msg), bar.update(1)))
    finally:
        bar.close()

    base_stats = obj.stats_all({}, seeds[0])
    basic_stats = obj.stats_all(fit.basic_values, seeds[0])
    fitted_stats = obj.stats_all(fit.final_values, seeds[0])
    res_basic = residuals(basic_stats, obj.real_all, ctx)
    fitted_sensor, fitted_degrade = apply(sensor, degrade, fit.final_values)

    rank = {c.effect.name: i + 1 for i, c in enumerate(fit.first_round)}
    selected = {c.effect.name for c in fit.selected}
    effects = []
    for eff in absent_effects(degrade):
        c = fit.candidates.get(eff.name)
        params = {k: float(c.values.get(k, 0.0)) for k in eff.keys} if c else {}
        effects.append({
            "name": eff.name,
            "missing": eff.name in selected,
            "parameters": params,
            "where": where(eff.name, res_basic, ctx, params),
            "evidence": _evidence(c, fit) if c else "not evaluated",
            "confidence": float(np.clip(c.confidence, 0.0, 1.0)) if c else 0.0,
            "rank": rank.get(eff.name),
            "heldout_gain": float(c.gain) if c else 0.0,
            "seed_std": float(c.spread) if c else 0.0,
            "fitted": bool(c.fitted) if c else False,
            "screen_gain": float(c.screen_gain) if c else 0.0,
            "statistic": eff.statistic,
        })
    effects.sort(key=lambda e: (not e["missing"], e["rank"] or 99))

    real_ev = ctx.real
    cons = {
        "real_base_thresholds": consistency(real_ev, ctx, sensor.threshold_on, sensor.threshold_off),
        "real_fitted_thresholds": consistency(real_ev, ctx, fitted_sensor.threshold_on, fitted_sensor.threshold_off),
        "sim_base": consistency(obj.simulate({}, seeds[0]), ctx, sensor.threshold_on, sensor.threshold_off),
        "sim_fitted": consistency(obj.simulate(fit.final_values, seeds[0]), ctx,
                                  fitted_sensor.threshold_on, fitted_sensor.threshold_off),
    }
    floor = noise_floor(obj, fit.final_values)
    runtime = time.perf_counter() - t_start
    n_sims = sum(o.n_sims for o in {id(o): o for o in (obj, fine, search)}.values())
    log.info("calibration of %s: %.1f s, %d simulations (%d pixel-circuit runs)", source, runtime,
             n_sims, fit.search.get("kernel_runs", 0))
    report = {
        "recording": source,
        "base_config": _configs_dict(sensor, degrade),
        "fitted_config": _configs_dict(fitted_sensor, fitted_degrade),
        "effects": effects,
        "discrepancy": {
            "metric": METRIC,
            "fit_before": fit.base.fit_mean,
            "fit_after": fit.final.fit_mean,
            "heldout_before": fit.base.held_mean,
            "heldout_after": fit.final.held_mean,
            "heldout_after_basic_refit": fit.basic.held_mean,
            "heldout_noise_floor": floor,
            "heldout_excess_before": fit.base.held_mean - floor,
            "heldout_excess_after": fit.final.held_mean - floor,
            "heldout_seed_std_before": float(fit.base.held.std(ddof=1)),
            "heldout_seed_std_after": float(fit.final.held.std(ddof=1)),
            "weights": dict(STATISTICS),
            "terms_heldout_before": {k: float(v.mean()) for k, v in fit.base.held_terms.items()},
            "terms_heldout_after": {k: float(v.mean()) for k, v in fit.final.held_terms.items()},
        },
        "basic_refit": {k: float(v) for k, v in fit.basic_values.items()},
        "mismatch": {"base": residuals(base_stats, obj.real_all, ctx),
                     "after_basic_refit": res_basic,
                     "fitted": residuals(fitted_stats, obj.real_all, ctx)},
        "consistency": cons,
        "setup": {"seeds": seeds, "pixel_stride": ctx.stride, "sampled_pixels": ctx.n_pixels,
                  "segments_us": ctx.segments.tolist(), "fit_segments": list(ctx.fit),
                  "heldout_segments": list(ctx.held), "real_events_compared": len(real_ev),
                  "simulated_frames": int(len(ctx.sim_t)),
                  "simulations": n_sims,
                  "search": fit.search, "runtime_s": runtime, "calibrate": to_dict(cfg)},
    }
    return Calibration(ctx=ctx, fit=fit, report=report, real_stats=obj.real_all, base_stats=base_stats,
                       basic_stats=basic_stats, fitted_stats=fitted_stats, runtime_s=runtime)


def noise_floor(obj: Objective, values: dict) -> float:
    """Held-out discrepancy between simulations of the same config with different seeds
    (mean over seed pairs): what a perfect simulator would still score against a
    recording, from the randomness of the events alone. 0 for a deterministic config."""
    from itertools import combinations

    from rdnet.calib import stats as st
    if not needs_rng(obj.configs(values)[1]):
        return 0.0
    held = [st.aggregate(obj.summary(values, s), obj.ctx, obj.ctx.held) for s in obj.seeds]
    return float(np.mean([st.discrepancy(a, b, obj.ctx)[0] for a, b in combinations(held, 2)]))


def finding(report: dict) -> str:
    """The finding in one sentence."""
    missing = [e for e in report["effects"] if e["missing"]]
    d = report["discrepancy"]
    change = f"held-out discrepancy {d['heldout_before']:.3g} -> {d['heldout_after']:.3g}"
    if not missing:
        scale = report.get("basic_refit", {}).get("threshold_scale", 1.0)
        return (f"No missing effect: after re-fitting the configured parameters (thresholds x{scale:.3g}) "
                f"no left-out effect improves the held-out match beyond the seed spread ({change}).")
    parts = []
    for e in missing:
        p = ", ".join(f"{k}={v:.3g}" for k, v in e["parameters"].items())
        parts.append(f"{e['name'].replace('_', ' ')} ({p}; confidence {e['confidence']:.2f})")
    return f"The simulator is missing {' and '.join(parts)}; fitting it brings the {change}."
