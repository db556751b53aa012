"""``rdnet calibrate``: simulate a recording from its frames, locate where the events
differ from the recorded ones, re-fit the configured parameters, name the missing
effects (held-out gain significant against the seed spread, and the effect's own statistic
moved: the signature gate of :mod:`rdnet.calib.fit`) and fit them.

Use::

    cal = calibrate(recording, sensor, degrade, CalibrateConfig(), seed=0)
    cal.report          # the report.json dict
    write_report(cal, "out/")   # rdnet.calib.report
"""
from __future__ import annotations

import dataclasses
import logging
import math
import os
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
from tqdm.auto import tqdm

from rdnet.calib.consistency import consistency, latency_scan
from rdnet.calib.context import CalibContext, build_context, subsample_context
from rdnet.calib.effects import EFFECTS, THRESHOLD_SCALE, absent_effects, apply, present_effects
from rdnet.calib.fit import (SIGNATURE_Z, Evaluation, FitResult, Objective, SimulateFn, calibrate_fit, fit_basic,
                             look_alikes, screen_gains)
from rdnet.calib.locate import residuals, where
from rdnet.calib.settings import CalibrateConfig
from rdnet.calib.stats import STATISTICS
from rdnet.config import to_dict
from rdnet.events.recording import Recording
from rdnet.sim.settings import DegradeConfig, SensorConfig

log = logging.getLogger(__name__)

METRIC = ("weighted sum of normalised distances of event statistics (rdnet.calib.stats): "
          + ", ".join(k for k, w in STATISTICS.items() if w) + "; mean over simulation seeds")


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


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _evidence(c, fit: FitResult) -> str:
    top = sorted(c.term_gains.items(), key=lambda kv: -kv[1])[:2]
    terms = ", ".join(f"{k} {v:+.3f}" for k, v in top)
    own = (f" and the score its search runs on (the fit discrepancy plus {c.effect.statistic}'s fit term) by "
           f"too little" if c.effect.fit_own > 0 else "")
    head = "" if c.fitted else (
        f"not fitted (its best screen point lowered the fit discrepancy by {c.screen_gain:+.3f}{own}: below "
        f"calibrate.screen_gain, or not among the calibrate.max_fitted best screened), so never named; "
        f"that point on the search sample, {len(c.evaluation.held)} seed(s): ")
    if c.vetoed:
        head += (f"not named: its gain is significant but its own statistic ({c.effect.statistic}) moved only "
                 f"{c.signature_z:.1f} seed std ({c.signature_before:.3f} -> {c.signature_after:.3f}; the signature "
                 f"gate needs > {SIGNATURE_Z:g}): a structural difference, not this effect; ")
    if c.by_signature:
        head += (f"significant by its own statistic ({c.effect.statistic} {c.signature_before:.3f} -> "
                 f"{c.signature_after:.3f}, {c.signature_z:.1f} seed std; gain > 0 in every seed); ")
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
    a progress bar (on a terminal). Large freed blocks stay with the process for reuse
    (:func:`rdnet.runtime.keep_freed_memory`: the simulations allocate and free tens of
    MB each, and zeroing fresh pages took about 12 % of the CPU time on DAVIS346)."""
    from rdnet.runtime import keep_freed_memory
    keep_freed_memory()
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


def selection_threads(cfg: CalibrateConfig, candidates: int) -> int:
    """Numba threads of the forward selection, which runs after the interpolation
    candidates' refits, alone: ``calibrate.threads`` for each candidate that ran side by
    side, at most the machine's cores (0: leave the setting alone). The events do not depend
    on the number of threads (:mod:`rdnet.sim.sensor`)."""
    if cfg.threads <= 0:
        return 0
    return max(1, min(cfg.threads * max(candidates, 1), os.cpu_count() or 1))


@dataclass
class _Trial:
    """One frame interpolation's basic refit and round-1 screen (the nuisance choice keeps
    the lowest ``reach``)."""
    method: str
    ctx: CalibContext
    obj: Objective
    fine: Objective
    search: Objective
    values: dict                 # the basic refit
    beta: float                  # its count slope
    basic: Evaluation            # on the final pixel sample (search seeds)
    reach: float                 # the lowest fit discrepancy: the basic refit or a screened effect on it
    reach_by: str | None         # the effect that reached it (None: the basic refit)
    best_screened: str | None    # the effect with the largest screen gain
    lag: dict                    # lag_behind_frames of the basic refit


def _calibrate(rec: Recording, sensor: SensorConfig, degrade: DegradeConfig, cfg: CalibrateConfig, *,
               seed: int, interpolate, source: str, simulate_fn: SimulateFn | None,
               progress: bool) -> Calibration:
    t_start = time.perf_counter()
    seeds = [int(seed) * 1000 + j for j in range(cfg.seeds)]
    bar = tqdm(desc="calibrate", unit="step", disable=None if progress else True)

    def tick(msg: str) -> None:
        bar.set_postfix_str(msg)
        bar.update(1)

    try:
        interps = interpolation_configs(cfg, interpolate)
        trials = [None] * len(interps)

        def trial(i: int, ctx: CalibContext) -> tuple:
            # in the context's own thread: the kernels release the GIL, so the candidates'
            # refits and screens share the cores
            icfg = interps[i]
            obj, fine, search = _objectives(ctx, sensor, degrade, seeds, simulate_fn)
            values, beta = fit_basic(search, fine)
            method = "given" if icfg is None else icfg.method
            gains, points = screen_gains(search, fine, values, beta) if len(interps) > 1 else ({}, {})
            best = max(gains, key=gains.get, default=None)
            # judged on the final pixel sample (search seeds), where the effects are scored:
            # a coarser search sample can miss what a few rows or columns hold (in a proof
            # scene, the dark column next to the still illumination edge, where flow drags
            # bright texture, holds about a fifth of the events; no even column does)
            ev = fine(values)            # seed 0 of the final scoring's basic refit: shared
            reach, reach_by = ev.fit_mean, None
            for name, v in points.items():
                if gains[name] <= 0.0:      # no gain on its own level: not simulated again
                    continue
                f = fine(v).fit_mean
                if f < reach:
                    reach, reach_by = f, name
            log.info("frame interpolation %s: %d simulated frames, basic refit %s: fit %.3f held-out %.3f; "
                     "reachable %.3f (with %s; best screened effect %s)", method, len(ctx.sim_t), values,
                     ev.fit_mean, ev.held_mean, reach, reach_by, best)
            # how far an ideal sensor's events trail the frames when they come from this
            # interpolation (the report's latency timing; seed 0 of the basic refit: shared)
            lag = lag_behind_frames(fine.simulate(values, seeds[0]), ctx, sensor)
            return _Trial(method, ctx, obj, fine, search, values, beta, ev, reach, reach_by, best, lag)

        for i, tr in contexts_as_built(rec, cfg, sensor.log_eps, interps, source, then=trial):
            trials[i] = tr
            tick(f"basic refit ({tr.method})")
        chosen = min(trials, key=lambda tr: tr.reach)
        method, ctx, obj, fine, search = chosen.method, chosen.ctx, chosen.obj, chosen.fine, chosen.search
        basic = (chosen.values, chosen.beta)
        timing = latency_timing(ctx, sensor, {tr.method: tr.lag["latency_us"] for tr in trials},
                                np.random.default_rng(seed))
        candidates = {tr.method: {"fit_after_basic_refit": tr.basic.fit_mean,
                                  "fit_reachable": tr.reach, "fit_reachable_with": tr.reach_by,
                                  "best_screened_effect": tr.best_screened,
                                  "heldout_after_basic_refit": tr.basic.held_mean,
                                  "basic_refit": {k: float(v) for k, v in tr.values.items()},
                                  "simulated_frames": int(len(tr.ctx.sim_t))} for tr in trials}
        # the losing interpolations' simulations count too; their frames, engines and caches
        # are dropped before the forward selection (a few hundred MB on DAVIS346)
        lost = [o for tr in trials if tr is not chosen
                for o in {id(o): o for o in (tr.obj, tr.fine, tr.search)}.values()]
        lost_sims = sum(o.n_sims for o in lost)
        lost_kernel = sum(e.n_kernel for e in {id(o.engine): o.engine for o in lost}.values())
        del trials, chosen, lost, tr
        log.info("calibrating %s: %d sampled pixels (stride %d; search: %d, stride %d), %d real events, "
                 "%d simulated frames (%s interpolation)", source, ctx.n_pixels, ctx.stride, search.ctx.n_pixels,
                 search.ctx.stride, len(ctx.real), len(ctx.sim_t), method)
        # the forward selection runs alone: it gets the threads the candidates had together
        with numba_threads(selection_threads(cfg, len(interps))):
            fit = calibrate_fit(search, obj, fine, progress=tick, basic=basic)
    finally:
        bar.close()
    frame_interp = {
        "chosen": method,
        "rule": ("nuisance choice before any effect is named: the frames are upsampled with each "
                 "method, the configured parameters re-fitted and every left-out effect screened on "
                 "each; kept: the lowest reachable fit-segment discrepancy on the final pixel sample (the "
                 "basic refit, or one of its calibrate.screen_refine best screened effects refined "
                 "between its grid points on top of it, whichever fits best), so "
                 "an interpolation cannot win by mimicking a missing effect; effects are tested on the kept "
                 "one only"),
        "level": "final pixel sample, search seeds (the basic refit and the screen run on the search sample)",
        "candidates": candidates,
    }
    base_stats = obj.stats_all({}, seeds[0])
    basic_stats = obj.stats_all(fit.basic_values, seeds[0])
    fitted_stats = obj.stats_all(fit.final_values, seeds[0])
    res_basic = residuals(basic_stats, obj.real_all, ctx)
    fitted_sensor, fitted_degrade = apply(sensor, degrade, fit.final_values)

    rank = {c.effect.name: i + 1 for i, c in enumerate(fit.first_round)}
    selected = {c.effect.name for c in fit.selected}
    alike = {c.effect.name: look_alikes(c, fit.rounds[c.round - 1], cfg) for c in fit.selected}
    effects = []
    for eff in absent_effects(degrade):
        c = fit.candidates.get(eff.name)
        params = {p.key: float(c.values.get(p.key, getattr(degrade, p.key) if p in eff.shape + eff.tuning else 0.0))
                  for p in eff.fitted} if c else {}
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
            "signature": ({"heldout_before": _finite(c.signature_before), "heldout_after": _finite(c.signature_after),
                           "z": _finite(c.signature_z), "vetoed": bool(c.vetoed),
                           "significant_by_it": bool(c.by_signature)} if c else None),
            # named effects: the candidates of the same round the data do not tell apart from it
            "look_alikes": [{"name": o.effect.name, "heldout_after": o.evaluation.held_mean,
                             "margin": margin, "margin_seed_std": spread,
                             "separate_with": separating_measurement(eff.name, o.effect.name)}
                            for o, margin, spread in alike.get(eff.name, [])],
            "caveats": caveats(eff.name, params, degrade, method, timing, fitted=bool(c and c.fitted)),
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
    kept = {id(o): o for o in (obj, fine, search)}.values()
    n_kernel = lost_kernel + sum(e.n_kernel for e in {id(o.engine): o.engine for o in kept}.values())
    n_sims = lost_sims + sum(o.n_sims for o in kept)
    log.info("calibration of %s: %.1f s, %d simulations (%d pixel-circuit runs)", source, runtime,
             n_sims, n_kernel)
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
        "refit_caveats": refit_caveats(fit.final_values, degrade, fit.base.fit_count, obj.real_fit_count),
        "frame_interpolation": frame_interp,
        "latency_timing": timing,
        "mismatch": {"base": residuals(base_stats, obj.real_all, ctx),
                     "after_basic_refit": res_basic,
                     "fitted": residuals(fitted_stats, obj.real_all, ctx)},
        "consistency": cons,
        "setup": {"seeds": seeds, "pixel_stride": ctx.stride, "sampled_pixels": ctx.n_pixels,
                  "segments_us": ctx.segments.tolist(), "fit_segments": list(ctx.fit),
                  "heldout_segments": list(ctx.held), "real_events_compared": len(real_ev),
                  "simulated_frames": int(len(ctx.sim_t)),
                  "simulations": n_sims, "pixel_circuit_runs": n_kernel,
                  "search": fit.search, "runtime_s": runtime, "calibrate": to_dict(cfg)},
    }
    return Calibration(ctx=ctx, fit=fit, report=report, real_stats=obj.real_all, base_stats=base_stats,
                       basic_stats=basic_stats, fitted_stats=fitted_stats, runtime_s=runtime)


def contexts_as_built(rec: Recording, cfg: CalibrateConfig, log_eps: float, interps: list,
                      source: str, then: Callable[[int, CalibContext], object] | None = None) -> Iterator[tuple]:
    """:func:`build_context` for every interpolation config of ``interps``, each in its
    own thread, yielding ``(index, context)`` as they are ready, or ``(index, then(index,
    context))`` when ``then`` is given (run in the same thread, with ``cfg.threads`` numba
    threads: the setting is per thread). OpenCV, numpy and the simulator's kernels release
    the GIL, so the candidates share the cores; the flow of one is computed while another
    is already fitting on linear blending. A context does not depend on when it was built."""
    def job(i: int, flows) -> object:
        ctx = build_context(rec, cfg, log_eps, interpolate=interps[i], source=source, flows=flows)
        if then is None:
            return ctx
        with numba_threads(cfg.threads):
            return then(i, ctx)

    if len(interps) == 1:
        yield 0, job(0, None)
        return
    from rdnet.sim.interpolate import FLOW_METHODS, PairFlowCache
    users = sum(icfg.method in FLOW_METHODS for icfg in interps)
    flows = PairFlowCache(users) if users > 1 else None   # flow and selected warp with the same pair flows
    with ThreadPoolExecutor(max_workers=len(interps), thread_name_prefix="rdnet-calib-context") as pool:
        futures = {pool.submit(job, i, flows): i for i in range(len(interps))}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()


def interpolation_configs(cfg: CalibrateConfig, interpolate) -> list:
    """The ``InterpolateConfig`` of every method of ``cfg.interpolation`` (the rest of
    ``interpolate``'s settings kept, its warp replaced by ``cfg.warp`` unless that is None);
    ``[interpolate]`` (with that warp) when the list is empty."""
    if not cfg.interpolation:
        return [interpolate if interpolate is None and cfg.warp is None else calibration_interpolation(cfg, base=interpolate)]
    return [calibration_interpolation(cfg, m, base=interpolate) for m in cfg.interpolation]


def calibration_interpolation(cfg: CalibrateConfig, method: str | None = None, base=None):
    """``base`` (None: the ``InterpolateConfig`` defaults with ``cfg.max_upsample``, as the
    proof's scenes are upsampled) as the calibration runs it: ``method`` when given, and
    ``cfg.warp`` unless that is None."""
    from rdnet.sim.interpolate import InterpolateConfig
    ip = InterpolateConfig(max_upsample=cfg.max_upsample) if base is None else base
    if method is not None:
        ip = dataclasses.replace(ip, method=method)
    return ip if cfg.warp is None else dataclasses.replace(ip, warp=cfg.warp)


def _objectives(ctx: CalibContext, sensor: SensorConfig, degrade: DegradeConfig, seeds: list[int],
                simulate_fn: SimulateFn | None) -> tuple[Objective, Objective, Objective]:
    """The final objective (every seed, final pixel sample), the fine one (search seeds,
    final sample; shares the engine) and the search one (search seeds, the coarser pixel
    sample that fits ``cfg.search_max_sim_steps``)."""
    cfg = ctx.cfg
    k = 1
    while cfg.search_max_sim_steps and k < 64 and \
            len(ctx.sim_t) * len(range(0, ctx.height, k)) * len(range(0, ctx.width, k)) > cfg.search_max_sim_steps:
        k += 1
    sctx = subsample_context(ctx, k)
    obj = Objective(ctx, sensor, degrade, seeds, simulate_fn, name="final")
    fine = obj
    if cfg.search_seeds < cfg.seeds:
        # the final pixel sample with the search seeds: shares the engine and simulations
        fine = Objective(ctx, sensor, degrade, seeds[:cfg.search_seeds], simulate_fn, engine=obj.engine,
                         name="fine")
        fine._summaries = obj._summaries
    search = fine if sctx is ctx else Objective(sctx, sensor, degrade, seeds[:cfg.search_seeds], simulate_fn,
                                                name="search")
    return obj, fine, search


def noise_floor(obj: Objective, values: dict) -> float:
    """Held-out discrepancy between simulations of the same config with different seeds
    (mean over seed pairs): what a perfect simulator would still score against a
    recording, from the randomness of the events alone (the random initial reference
    included). 0 when the events do not depend on the seed."""
    from itertools import combinations

    from rdnet.calib import stats as st
    if len(obj.seeds_for(values)) < 2:
        return 0.0
    held = [st.aggregate(obj.summary(values, s), obj.ctx, obj.ctx.held) for s in obj.seeds]
    return float(np.mean([st.discrepancy(a, b, obj.ctx)[0] for a, b in combinations(held, 2)]))


#: what would tell a pair of look-alike effects apart (docs/calibration.md "What is still open (issue 12)")
SEPARATING_MEASUREMENTS = (
    ({"refractory_period", "readout_saturation"},
     "a fine-binned inter-event-interval histogram of the busiest pixels (a refractory period leaves "
     "none below it, a period readout only thins them), or a small flashing spot on a still, dark "
     "background (one pixel busy, the array idle)"),
    ({"latency", "bandwidth", "timestamp_jitter"},
     "a flashing LED filmed at two or three brightnesses: a bandwidth lag grows as the light falls, a "
     "latency does not, jitter spreads the step instead of shifting it"),
    ({"onoff_asymmetry", "threshold_mismatch"},
     "a uniform full-field flicker (every pixel sees the same log change): each pixel's ON and OFF "
     "counts directly"),
    ({"hot_pixels", "threshold_mismatch", "onoff_asymmetry"},
     "a still scene (nothing moves) for a second or more: hot pixels keep firing at their rate, while "
     "threshold mismatch and ON/OFF asymmetry only show where the light changes"),
    ({"leak_events", "onoff_asymmetry"},
     "the ON share of still pixels, of a still scene held for a second or more (or of this recording's "
     "still pixels, in 'where' above, when they hold enough events): leak events come with no change of "
     "light and are mostly ON, while an ON/OFF asymmetry only shows where the light changes"),
    ({"leak_events", "shot_noise", "hot_pixels"},
     "a static scene recorded in the dark (lens cap) and lit: leak grows with light, shot noise is "
     "strongest in the dark, hot pixels stay a few pixels far above the rest"),
)


#: relative change of a tuning parameter from its declared value that :func:`caveats` reports
TUNING_MOVED = 0.01

#: a main parameter this close (relative) to an end of its search range is reported as a
#: bound by :func:`caveats` (a search that ran into its range's end has not found a minimum)
AT_BOUND = 0.01

#: per tuning parameter (``Effect.tuning``): what its move does, what outside the effect
#: vocabulary does the same (``{how}``: the frames as the calibration interpolated them),
#: where the proof shows it, and the measurement that separates the two (:func:`caveats`)
TUNING_LOOK_ALIKES = {
    "cutoff_floor": {
        "lower": "a lower floor slows the darkest pixels",
        "higher": "a higher floor speeds up the darkest pixels",
        "look_alike": "an error of {how} in the dark part of the scene shifts their events the same way",
        "shown": "rdnet's proof shows it on recordings whose truth came from 4x denser frames: rdnet's "
                 "docs/calibration.md, \"Bandwidth: the dark current is fitted\"",
        "measure": "the floor",
        "separate_with": "a still scene under a flashing LED at a few brightnesses; the delay of the events "
                         "after each step, against brightness, gives the cutoff at each intensity with no frame "
                         "interpolation involved",
    },
}


def caveats(name: str, params: dict, degrade: DegradeConfig, interpolation: str | None,
            timing: dict | None = None, fitted: bool = True) -> list[str]:
    """What the user should know before trusting effect ``name``'s fitted ``params``
    beyond its held-out gain: look-alikes outside the effect vocabulary, which the
    forward selection cannot list (:func:`rdnet.calib.fit.look_alikes` compares effects only).

    One per tuning parameter (``Effect.tuning``) fitted away from its declared value by more
    than :data:`TUNING_MOVED`, from :data:`TUNING_LOOK_ALIKES`. The bandwidth's dark-current
    floor sets how much slower the darkest pixels are, and a frame interpolation that errs in
    the dark part of the scene moves the dark pixels' events the same way (docs/calibration.md "Bandwidth:
    the dark current is fitted": in the proof's block whose truths come from 4x denser frames,
    the true floor 0.078 was fitted as 0.025-0.061 while the held-out discrepancy fell).

    A main parameter fitted at an end of its search range (:func:`range_end`; only
    when ``fitted``: a screened-out effect reports a screen grid point): the search stopped
    at the range, not at a minimum, so the value is a bound.

    Latency, with ``timing`` (:func:`latency_timing`): how far the recorded events trail the
    frames, read without a simulator, against how far an ideal sensor's events trail them
    under each frame interpolation tried; the latency the data support lies between the
    differences, and a fitted value outside that range is reported as such."""
    eff = EFFECTS.get(name)
    how = f"the {interpolation} interpolation of the recorded frames" if interpolation else "the frames"
    out = []
    for p in eff.tuning if eff else ():
        if p.key not in params:
            continue
        value, declared = float(params[p.key]), float(getattr(degrade, p.key))
        if abs(value - declared) <= TUNING_MOVED * max(abs(declared), 1e-12):
            continue
        t = TUNING_LOOK_ALIKES[p.key]
        out.append(f"{p.key} fitted {value:.3g} against the declared {declared:.3g}: "
                   f"{t['lower' if value < declared else 'higher']}, and {t['look_alike'].format(how=how)}, so "
                   f"these frames and events do not tell the two apart ({t['shown']}). To measure "
                   f"{t['measure']} on its own: {t['separate_with']}.")
    for p in eff.params if eff and fitted else ():
        v = float(params.get(p.key, math.nan))
        edge = range_end(v, p, beyond=False)       # a fit stays inside its search range
        if edge:
            out.append(f"{p.key} fitted {v:.3g}, {edge} its search range [{p.lo:g}, {p.hi:g}]: the "
                       f"recording may ask for a value beyond it, or for something else that this effect only "
                       f"approximates; read it as a bound, not a measurement.")
    if name == "latency" and timing and "latency_us" in params:
        text = _latency_caveat(float(params["latency_us"]), timing)
        if text:
            out.append(text)
    return out


def range_end(v: float, p, beyond: bool = True) -> str | None:
    """Where ``v`` lies against the ends of ``p``'s range [lo, hi] (a :class:`Param`): "at the
    top of" / "at the bottom of" within :data:`AT_BOUND` of an end, "above" / "below" beyond
    it (None there with ``beyond=False``), None inside (and for NaN)."""
    if v > p.hi or v < p.lo:
        return ("above" if v > p.hi else "below") if beyond else None
    if v >= p.hi * (1.0 - AT_BOUND):
        return "at the top of"
    if v <= p.lo * (1.0 + AT_BOUND):
        return "at the bottom of"
    return None


def refit_caveats(values: dict, degrade: DegradeConfig, base_count: float, real_count: float) -> list[str]:
    """The re-fitted threshold factor and parameters of the effects the base config has
    (``values``: the fitted config's) that ended at or beyond an end of their declared range
    (within :data:`AT_BOUND`; the basic refit searches up to half / twice it). There the base
    config is far from the recording, the re-fit stopped at a corner and not at a minimum,
    and what is named or not named on top of it cannot be trusted. ``base_count`` /
    ``real_count``: the simulated events of the base config and the recorded ones on the fit
    segments, which say how far (params.yaml's study degradation on DAVIS346, session 50:
    thresholds x6.99 and an ON/OFF ratio of 0.28, held-out discrepancy 22.4 against 8.37 from
    the ideal sensor)."""
    ranges = {THRESHOLD_SCALE.key: THRESHOLD_SCALE}
    ranges.update({p.key: p for e in present_effects(degrade) for p in e.params + e.tuning})
    out = []
    for key, p in ranges.items():
        if key not in values:
            continue
        v = float(values[key])
        edge = range_end(v, p)
        if edge:
            out.append(f"{key} to {v:.3g} ({edge} its range [{p.lo:g}, {p.hi:g}])")
    if not out:
        return []
    moved = (", ".join(out[:-1]) + " and " if len(out) > 1 else "") + out[-1]
    return [f"The re-fit moved {moved}. The base config is far from this recording (at its declared values it "
            f"simulates {base_count:.0f} events where the recording has {real_count:.0f} on the fit segments), so "
            f"the re-fit stopped at a corner of its ranges, not at a minimum, and neither these values nor the "
            f"effects named or not named on top of them can be trusted. Start from the ideal sensor (rdnet "
            f"calibrate --base ideal: the effects the camera has beyond it) or set the base config's effects "
            f"nearer the camera with --set."]


def lag_behind_frames(events, ctx: CalibContext, sensor: SensorConfig, rng: np.random.Generator | None = None,
                      resamples: int = 0) -> dict:
    """:func:`rdnet.calib.consistency.latency_scan` of ``events`` on the context's frames
    (pixel-intervals whose log change reaches the smaller declared threshold; shifts up to
    ``calibrate.max_lag_us`` in steps of a quarter of ``calibrate.time_bin_us``)."""
    cfg = ctx.cfg
    return latency_scan(events, ctx, max_shift_us=float(cfg.max_lag_us), step_us=cfg.time_bin_us / 4.0,
                        min_change=min(sensor.threshold_on, sensor.threshold_off),
                        rng=rng if rng is not None else np.random.default_rng(0), resamples=resamples)


def latency_timing(ctx: CalibContext, sensor: SensorConfig, ideal: dict, rng: np.random.Generator) -> dict:
    """The report's ``latency_timing``: how far the recorded events trail the frames
    (:func:`lag_behind_frames`, with a bootstrap interval; no simulator, no interpolation)
    and how far an ideal sensor's do at the basic refit under each frame interpolation
    tried (``ideal``: method -> lag, us). Even an ideal pixel's events trail the frames (it
    fires only once its change reaches a threshold), by an amount the interpolation sets:
    between frames the simulator does not know when the intensity changed. So the latency
    these data support is ``recorded - ideal`` over the interpolations: ``latency_range_us``."""
    rec = lag_behind_frames(ctx.real, ctx, sensor, rng, resamples=200)
    vals = [v for v in ideal.values() if np.isfinite(v)]
    rng_us = ([_finite(rec["latency_us"] - max(vals)), _finite(rec["latency_us"] - min(vals))]
              if vals and np.isfinite(rec["latency_us"]) else [None, None])
    return {"statistic": "event-frame consistency of time-shifted events (rdnet.calib.consistency.latency_scan): "
                         "the shift, undone, that makes the net events between two frames follow their log change best",
            "recorded_lag_us": _finite(rec["latency_us"]), "recorded_ci95_us": [_finite(v) for v in rec["ci95_us"]],
            "recorded_at_grid_edge": rec["at_edge"],
            "ideal_lag_us": {k: _finite(v) for k, v in ideal.items()},
            "latency_range_us": rng_us,
            "frame_interval_us": float(np.median(np.diff(ctx.frame_t))) if len(ctx.frame_t) > 1 else None,
            "grid_us": {"max": float(ctx.cfg.max_lag_us), "step": ctx.cfg.time_bin_us / 4.0}}


#: how far outside :func:`latency_timing`'s range a fitted latency may lie and still be called
#: inside it, as a fraction of the frame interval (or the recorded lag's 95 % half-width, when
#: larger): the correctly named latencies of the proof lie outside it by at most 0.039 of their
#: 10 ms frame interval (docs/calibration.md, "The latency against the frames' own timing"; the
#: tolerance scales with the interval on the assumption that what the interpolation cannot pin
#: grows with the time between frames)
TIMING_TOLERANCE = 0.05


def latency_verdict(fitted_us: float, timing: dict) -> tuple[str, float] | None:
    """Whether a fitted latency lies ``"inside"`` or ``"outside"`` the range of a report's
    ``latency_timing`` (:func:`latency_timing`), give or take the tolerance (us, returned
    with it): the recorded lag's 95 % half-width or :data:`TIMING_TOLERANCE` of the frame
    interval, the larger. None when the timing has no range."""
    lo, hi = timing.get("latency_range_us") or (None, None)
    rec, frames = timing.get("recorded_lag_us"), timing.get("frame_interval_us")
    if lo is None or hi is None or rec is None or frames is None:
        return None
    ci = timing["recorded_ci95_us"]
    half = max(rec - ci[0], ci[1] - rec) if None not in ci else 0.0
    tol = max(half, TIMING_TOLERANCE * frames)
    return ("inside" if lo - tol <= fitted_us <= hi + tol else "outside"), tol


def _latency_caveat(fitted_us: float, timing: dict) -> str | None:
    verdict = latency_verdict(fitted_us, timing)
    if verdict is None:
        return None
    where, tol = verdict
    lo, hi = timing["latency_range_us"]
    rec, frames, ci = timing["recorded_lag_us"], timing["frame_interval_us"], timing["recorded_ci95_us"]
    ideal = ", ".join(f"{m} {v / 1000:.2g} ms" for m, v in timing["ideal_lag_us"].items() if v is not None)
    return (f"latency_us fitted {fitted_us / 1000:.3g} ms. Read off the frames and events alone (no simulator), "
            f"the recorded events trail the frames by {rec / 1000:.3g} ms (95 % {ci[0] / 1000:.3g}-"
            f"{ci[1] / 1000:.3g}); an ideal sensor's events, simulated from the frames at the basic refit, trail "
            f"them by {ideal} (even an ideal pixel fires only once its change reaches a threshold, and the frame "
            "interpolation decides when between two frames the intensity changes). Under these interpolations the "
            f"frames' timing puts the latency between {lo / 1000:.3g} and {hi / 1000:.3g} ms; the fitted value, read "
            f"off the event rate over time, is {where} that range give or take {tol / 1000:.2g} ms "
            f"({100 * TIMING_TOLERANCE:g} % of the "
            f"{frames / 1000:.3g} ms between frames, or the recorded lag's interval). The interpolation cannot pin "
            "the latency more closely; to measure it on its own: a recording with much faster frames, or a still "
            "sensor watching a light of known timing (a flashing LED): the delay of the events after each flash.")


def separating_measurement(a: str, b: str) -> str:
    """The recording that would separate effects ``a`` and ``b`` (:data:`SEPARATING_MEASUREMENTS`)."""
    for pair, text in SEPARATING_MEASUREMENTS:
        if a in pair and b in pair:
            return text
    return "a recording that drives one of the two effects and not the other"


def finding(report: dict) -> str:
    """The finding in one sentence."""
    missing = [e for e in report["effects"] if e["missing"]]
    d = report["discrepancy"]
    change = f"held-out discrepancy {d['heldout_before']:.3g} -> {d['heldout_after']:.3g}"
    doubt = (" The re-fit ran to the end of a parameter's range, so this cannot be trusted: see the "
             "report's caveats." if report.get("refit_caveats") else "")
    if not missing:
        scale = report.get("basic_refit", {}).get("threshold_scale", 1.0)
        return (f"No missing effect: after re-fitting the configured parameters (thresholds x{scale:.3g}) "
                f"no left-out effect improves the held-out match beyond the seed spread ({change}).{doubt}")
    parts = []
    for e in missing:
        p = ", ".join(f"{k}={v:.3g}" for k, v in e["parameters"].items())
        parts.append(f"{e['name'].replace('_', ' ')} ({p}; confidence {e['confidence']:.2f})")
    return f"The simulator is missing {' and '.join(parts)}; fitting it brings the {change}.{doubt}"
