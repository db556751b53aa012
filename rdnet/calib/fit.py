"""Fitting the simulator to a recording.

1. **Basic refit**: the common factor of both contrast thresholds and the parameters of
   the effects the base config already has are re-fitted first (coordinate descent of
   1-D golden-section searches in log scale), so a wrong value is not mistaken for
   missing physics.
2. **Forward selection** over the effects the base config leaves out: each candidate's
   parameters are fitted on the *fit* segments (log-scale grid, or a data-driven first
   guess, then golden-section refinement, then the thresholds and the effect refined
   together); its *held-out* gain is the drop of the discrepancy on the other segments.
   The best candidate is added when its gain exceeds ``significance`` x the seed spread
   of the discrepancy and ``min_relative_gain`` of it; then the remaining candidates are
   re-fitted on top of it, and so on (at most ``max_effects``).

All candidates are simulated with the same seeds (common random numbers), so the
differences between candidates are not drowned in simulation noise.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from rdnet.calib import stats as st
from rdnet.calib.context import CalibContext
from rdnet.calib.effects import OFF, THRESHOLD_SCALE, Effect, Param, absent_effects, apply, present_effects
from rdnet.events.core import Events
from rdnet.sim.effects import needs_rng
from rdnet.sim.settings import DegradeConfig, SensorConfig

log = logging.getLogger(__name__)

SimulateFn = Callable[[np.ndarray, np.ndarray, SensorConfig, DegradeConfig, np.random.Generator], Events]
GOLDEN = (math.sqrt(5) - 1) / 2
#: smallest seed spread, as a fraction of the held-out discrepancy
SPREAD_FLOOR = 0.01


def default_simulate(images, t_us, sensor, degrade, rng) -> Events:
    """The project's simulator (:func:`rdnet.sim.pair.simulate`) on frames that are
    already upsampled (the calibration context upsamples once, not per candidate)."""
    from rdnet.sim.pair import simulate
    return simulate(images, t_us, sensor, degrade, rng, interpolate=None, chunk=max(1, len(t_us)))


@dataclass(frozen=True)
class Evaluation:
    """Discrepancy of one parameter set, per seed, on the fit and held-out segments."""

    values: dict
    fit: np.ndarray
    held: np.ndarray
    fit_terms: dict
    held_terms: dict

    @property
    def fit_mean(self) -> float:
        return float(self.fit.mean())

    @property
    def held_mean(self) -> float:
        return float(self.held.mean())


class Objective:
    """Simulates parameter sets (memoised) and scores them against the recording."""

    def __init__(self, ctx: CalibContext, sensor: SensorConfig, degrade: DegradeConfig,
                 seeds: list[int], simulate_fn: SimulateFn | None = None):
        self.ctx, self.sensor, self.degrade, self.seeds = ctx, sensor, degrade, list(seeds)
        self.simulate_fn = simulate_fn or default_simulate
        real = st.summarize(ctx.real, ctx)
        self.real_fit = st.aggregate(real, ctx, ctx.fit)
        self.real_held = st.aggregate(real, ctx, ctx.held)
        self.real_all = st.aggregate(real, ctx, range(len(ctx.segments)))
        self.cache: dict = {}
        self.n_sims = 0

    def configs(self, values: dict) -> tuple[SensorConfig, DegradeConfig]:
        return apply(self.sensor, self.degrade, values)

    def simulate(self, values: dict, seed: int) -> Events:
        sensor, degrade = self.configs(values)
        self.n_sims += 1
        return self.simulate_fn(self.ctx.sim_images, self.ctx.sim_t, sensor, degrade,
                                np.random.default_rng(seed))

    def __call__(self, values: dict) -> Evaluation:
        key = tuple(sorted((k, round(float(v), 9)) for k, v in values.items()))
        hit = self.cache.get(key)
        if hit is not None:
            return hit
        fit, held, ft, ht = [], [], [], []
        # a config without random effects gives the same events for every seed
        seeds = self.seeds if needs_rng(self.configs(values)[1]) else self.seeds[:1]
        for seed in seeds:
            s = st.summarize(self.simulate(values, seed), self.ctx)
            df, tf = st.discrepancy(st.aggregate(s, self.ctx, self.ctx.fit), self.real_fit, self.ctx)
            dh, th = st.discrepancy(st.aggregate(s, self.ctx, self.ctx.held), self.real_held, self.ctx)
            fit.append(df); held.append(dh); ft.append(tf); ht.append(th)
        k = len(self.seeds) // len(seeds)
        fit, held, ft, ht = fit * k, held * k, ft * k, ht * k
        names = list(ft[0])
        ev = Evaluation(dict(values), np.array(fit), np.array(held),
                        {k: np.array([t[k] for t in ft]) for k in names},
                        {k: np.array([t[k] for t in ht]) for k in names})
        self.cache[key] = ev
        return ev

    def stats_all(self, values: dict, seed: int) -> dict:
        """Statistics of one simulation over the whole compared window (for figures)."""
        s = st.summarize(self.simulate(values, seed), self.ctx)
        return st.aggregate(s, self.ctx, range(len(self.ctx.segments)))


# --- 1-D searches in log scale ----------------------------------------------------------

def golden(obj: Objective, values: dict, key: str, lo: float, hi: float, steps: int) -> dict:
    """Golden-section search of ``key`` in [lo, hi] (log scale) minimising the mean fit
    discrepancy; returns the best values seen (the start included)."""
    start = obj(values)
    best, best_f = dict(start.values), start.fit_mean
    a, b = math.log(lo), math.log(hi)
    c = b - GOLDEN * (b - a)
    d = a + GOLDEN * (b - a)

    def f(u):
        nonlocal best, best_f
        v = dict(values)
        v[key] = math.exp(u)
        ev = obj(v)
        r = ev.fit_mean
        if r < best_f:
            best, best_f = dict(ev.values), r
        return r

    fc, fd = f(c), f(d)
    for _ in range(max(0, steps - 2)):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - GOLDEN * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + GOLDEN * (b - a)
            fd = f(d)
    return best


def grid_then_golden(obj: Objective, values: dict, p: Param, points: int, steps: int) -> dict:
    """Log-spaced grid over the whole range of ``p``, then golden section between the
    neighbours of the best grid point."""
    grid = np.geomspace(p.lo, p.hi, points)
    evs = []
    for g in grid:
        v = dict(values)
        v[p.key] = float(g)
        evs.append(obj(v))
    i = int(np.argmin([e.fit_mean for e in evs]))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, points - 1)]
    return golden(obj, evs[i].values, p.key, lo, hi, steps)


class Profiled:
    """The objective with ``threshold_scale`` optimised out: evaluating a parameter set
    first runs a short golden-section search of the threshold factor (within ``factor``
    of its current value), so an effect that changes the event count is compared at its
    best thresholds (a profile likelihood; it is how such an effect is concealed)."""

    def __init__(self, obj: Objective, factor: float = 1.6, steps: int = 4):
        self.obj, self.factor, self.steps = obj, factor, steps
        self.ctx = obj.ctx

    def __call__(self, values: dict) -> Evaluation:
        c = values.get(THRESHOLD_SCALE.key, 1.0)
        v = golden(self.obj, values, THRESHOLD_SCALE.key, c / self.factor, c * self.factor, self.steps)
        return self.obj(v)


def _around(v: float, factor: float, p: Param) -> tuple[float, float]:
    return max(p.lo * 0.5, v / factor), min(p.hi * 2.0, v * factor)


# --- data-driven first guesses ------------------------------------------------------------

def _guess(obj: Objective, values: dict, effect: Effect) -> dict | None:
    """A first guess for effects whose parameters can be read off the statistics
    (hot pixels: pixels whose net ON - OFF rate exceeds any simulated one; latency: the rate
    cross-correlation lag; shot noise / leak: the excess (ON - OFF for leak) event rate
    of static pixels); None = use the grid."""
    ctx = obj.ctx
    if effect.name == "latency":
        sim = obj.stats_all(values, obj.seeds[0])
        real = obj.real_all
        lag = st.xcorr_lag_us(sim["rate_time"], real["rate_time"], real["time_mask"],
                              float(ctx.cfg.time_bin_us), float(ctx.cfg.max_lag_us))
        if lag <= 0:
            return None
        v = dict(values)
        v["latency_us"] = float(np.clip(lag + values.get("latency_us", 0.0), 50.0, 50000.0))
        return v
    if effect.name in ("shot_noise", "leak_events"):
        # excess event rate of the static pixels: all of it (shot noise, balanced, its rate
        # falls to shot_noise_bright_factor at I = 1) or the excess of ON over OFF (leak)
        sim = obj.stats_all(values, obj.seeds[0])
        real = obj.real_all
        if effect.name == "shot_noise":
            _, d = obj.configs(values)
            lin = np.clip(ctx.images.mean(0)[ctx.static], 0.0, 1.0)
            shape = float(np.mean(1.0 + (d.shot_noise_bright_factor - 1.0) * lin)) if lin.size else 1.0
            excess = (float(real["static_rate"]) - float(sim["static_rate"])) / max(shape, 1e-3)
        else:
            def on_minus_off(stats):
                return float(stats["static_rate"]) * (2.0 * float(stats["static_on_fraction"]) - 1.0)
            excess = on_minus_off(real) - on_minus_off(sim)
        if excess <= 0:
            return None
        p = effect.params[0]
        v = dict(values)
        v[p.key] = float(np.clip(excess, p.lo, p.hi))
        return v
    if effect.name == "hot_pixels":
        sim = obj.stats_all(values, obj.seeds[0])["net_rate"].ravel()
        real = obj.real_all["net_rate"].ravel()
        top = np.sort(sim)[-max(1, sim.size // 1000):]
        thresh = 2.0 * float(top.mean()) + 1.0
        hot = real[real > thresh]
        for _ in range(3):          # drop busy scene pixels: hot pixels share one rate
            if hot.size == 0:
                return None
            hot = real[real > max(thresh, 0.5 * float(np.median(hot)))]
        v = dict(values)
        v["hot_pixel_fraction"] = float(np.clip(hot.size / real.size, 0.0005, 0.05))
        v["hot_pixel_hz"] = float(np.clip(np.median(hot) - float(np.mean(sim)), 3.0, 3000.0))
        return v
    return None


# --- effect fits -----------------------------------------------------------------------------

def refine(obj: Objective, values: dict, keys_params: list[Param], rounds: int, steps: int,
           factor: float) -> dict:
    """Coordinate descent: golden section of each parameter within ``factor`` of its value."""
    v = dict(values)
    for _ in range(rounds):
        for p in keys_params:
            cur = v.get(p.key, 0.0)
            if cur <= 0:
                continue
            lo, hi = _around(cur, factor, p)
            v = golden(obj, v, p.key, lo, hi, steps)
    return v


def present_params(obj: Objective) -> list[Param]:
    """Parameters of the effects the base config has (those that are on)."""
    return [p for e in present_effects(obj.degrade) for p in e.params
            if getattr(obj.degrade, p.key) != OFF.get(p.key, 0.0)]


def fit_basic(obj: Objective, values: dict) -> dict:
    """Step 2: thresholds (common factor) and the present effects' parameters."""
    cfg = obj.ctx.cfg
    v = grid_then_golden(obj, values, THRESHOLD_SCALE, cfg.search_points + 2, cfg.refine_steps + 2)
    params = present_params(obj)
    for p in params:
        v.setdefault(p.key, float(getattr(obj.degrade, p.key)))
    return refine(obj, v, params + [THRESHOLD_SCALE], rounds=2, steps=cfg.refine_steps, factor=4.0)


def fit_effect(obj: Objective, values: dict, effect: Effect) -> dict:
    """Fit ``effect``'s parameters on top of ``values``, then refine them together with
    the threshold factor (a missing effect is often concealed by shifted thresholds) and
    the configured effects' parameters."""
    cfg = obj.ctx.cfg
    v = _guess(obj, values, effect)
    if v is None:
        v = dict(values)
        for p in effect.params:
            v.setdefault(p.key, math.sqrt(p.lo * p.hi))
        search = Profiled(obj) if effect.changes_count else obj
        for p in effect.params:
            v = grid_then_golden(search, v, p, cfg.search_points, cfg.refine_steps)
    else:
        v = refine(obj, v, list(effect.params), rounds=1, steps=cfg.refine_steps, factor=3.0)
    # the configured effects may have absorbed part of this one in the basic refit
    # (e.g. jitter smearing out a latency): refit them with it
    present = present_params(obj)
    if present:
        v = refine(obj, v, present, rounds=1, steps=cfg.refine_steps + 1, factor=8.0)
    return refine(obj, v, [THRESHOLD_SCALE] + list(effect.params) + present, rounds=1,
                  steps=max(3, cfg.refine_steps - 1), factor=1.5)


@dataclass
class Candidate:
    effect: Effect
    values: dict
    evaluation: Evaluation
    gain: float = 0.0           # mean held-out discrepancy drop
    spread: float = 0.0         # seed std of the held-out discrepancy
    relative: float = 0.0       # gain / held-out discrepancy before
    z: float = 0.0              # gain / spread
    significant: bool = False
    round: int = 0
    confidence: float = 0.0     # in [0, 1]; > 0.5 exactly when significant
    before_held: float = 0.0    # held-out discrepancy of the config it is added to
    ablated_held: float = float("nan")   # ... of its own fit with the effect off
    term_gains: dict = field(default_factory=dict)


def _gain(before: Evaluation, after: Evaluation) -> tuple[float, float]:
    """Mean held-out gain and the seed spread of the held-out discrepancy (floored at
    SPREAD_FLOOR of it, since a config without random effects has no seed spread)."""
    gain = float((before.held - after.held).mean())
    seed_std = math.sqrt(0.5 * (before.held.var(ddof=1) + after.held.var(ddof=1)))
    return gain, float(max(seed_std, SPREAD_FLOOR * before.held_mean))


def score(cand: Candidate, before: Evaluation, cfg, ablated: Evaluation | None = None,
          reference: float | None = None) -> Candidate:
    """Held-out gain, its seed spread, significance and confidence.

    The gain is the smaller of the drop against ``before`` (the current config) and,
    when given, against ``ablated`` (the candidate's own fit with the effect switched
    off): an effect is credited only with what it adds itself, not with what its
    re-fitted thresholds or configured effects would have gained anyway. The relative
    gain is taken of ``reference`` (default: ``before``'s held-out discrepancy; the
    forward selection passes the discrepancy after the basic refit, so a later effect
    must explain a share of the original mismatch, not of a small remainder)."""
    after = cand.evaluation
    gain, spread = _gain(before, after)
    if ablated is not None:
        g2, s2 = _gain(ablated, after)
        if g2 < gain:
            gain, spread = g2, max(spread, s2)
    cand.gain, cand.spread = gain, spread
    cand.before_held = before.held_mean
    cand.ablated_held = ablated.held_mean if ablated is not None else float("nan")
    cand.relative = cand.gain / max(before.held_mean if reference is None else reference, 1e-12)
    cand.z = cand.gain / max(cand.spread, 1e-9)
    cand.significant = bool(cand.z > cfg.significance and cand.relative > cfg.min_relative_gain)
    cand.term_gains = {k: float((before.held_terms[k] - after.held_terms[k]).mean())
                       for k in after.held_terms}
    zc = 1.0 / (1.0 + math.exp(-min(50.0, max(-50.0, cand.z - cfg.significance))))
    rel_scale = max(cfg.min_relative_gain, 1e-3)
    rc = 1.0 / (1.0 + math.exp(-min(50.0, max(-50.0, 5.0 * (cand.relative - cfg.min_relative_gain) / rel_scale))))
    cand.confidence = float(min(zc, rc))
    return cand


def ablate(values: dict, effect: Effect) -> dict:
    """``values`` with ``effect`` switched off (everything else kept)."""
    v = dict(values)
    for k in effect.keys:
        v.pop(k, None)
    return v


@dataclass
class FitResult:
    base: Evaluation
    basic: Evaluation
    final: Evaluation
    basic_values: dict
    final_values: dict
    selected: list           # Candidate, in the order added
    candidates: dict         # effect name -> last Candidate (every absent effect)
    first_round: list        # Candidates of round 1 sorted by gain (the ranking)
    n_sims: int


def calibrate_fit(obj: Objective) -> FitResult:
    """Steps 2 and 3: basic refit, then forward selection of missing effects."""
    cfg = obj.ctx.cfg
    base = obj({})
    log.info("base: fit %.3f held-out %.3f", base.fit_mean, base.held_mean)
    values = fit_basic(obj, {})
    basic = obj(values)
    log.info("basic refit %s: fit %.3f held-out %.3f", _fmt(values), basic.fit_mean, basic.held_mean)
    current, cur_eval = values, basic
    remaining = [e for e in absent_effects(obj.degrade) if not cfg.candidates or e.name in cfg.candidates]
    selected: list[Candidate] = []
    candidates: dict[str, Candidate] = {}
    first_round: list[Candidate] = []
    rnd = 0
    while remaining and len(selected) < cfg.max_effects:
        rnd += 1
        round_c = []
        for eff in remaining:
            v = fit_effect(obj, current, eff)
            c = score(Candidate(eff, v, obj(v), round=rnd), cur_eval, cfg, obj(ablate(v, eff)),
                      reference=basic.held_mean)
            log.info("round %d %-19s gain %.4f (z %.1f, rel %.3f) %s", rnd, eff.name, c.gain, c.z,
                     c.relative, _fmt({p.key: v.get(p.key, 0.0) for p in eff.params}))
            round_c.append(c)
            candidates[eff.name] = c
        round_c.sort(key=lambda c: -c.gain)
        if rnd == 1:
            first_round = list(round_c)
        best = round_c[0]
        if not best.significant:
            break
        selected.append(best)
        current, cur_eval = best.values, best.evaluation
        remaining = [e for e in remaining if e.name != best.effect.name]
        # only candidates that helped at all are worth another round
        helped = {c.effect.name for c in round_c[1:] if c.gain > 0}
        remaining = [e for e in remaining if e.name in helped]
    return FitResult(base=base, basic=basic, final=cur_eval, basic_values=values, final_values=current,
                     selected=selected, candidates=candidates, first_round=first_round, n_sims=obj.n_sims)


def _fmt(values: dict) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in values.items())
