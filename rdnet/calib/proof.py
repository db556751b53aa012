"""Proof of the calibration on concealed effects.

Each case renders the procedural scene of :mod:`rdnet.calib.scene` and simulates a
"real" recording with a *true* config that holds one effect the *base* config leaves
out, and conceals it: one compensating parameter (the common threshold factor or the shot
noise rate) is solved (:func:`match_count`) so that the total event count equals that of
the base config on the same frames and seed, to :data:`COUNT_MATCH_TOL`. Null cases differ
from the base only in the thresholds (and the values of effects the base already has): the
tool must name nothing.

By default (``oversample=1``) the true events are simulated from the recorded frames
upsampled exactly as the calibration will upsample them, so the concealed effect is the
only difference; ``oversample > 1`` simulates the truth from frames rendered that many
times denser, which adds the calibration's own interpolation error to what it must explain.
Every true simulation starts each pixel at a random point between its thresholds (the
unknown state at the start of a real recording; :func:`rdnet.calib.engine.simulate_random_start`).

:func:`run_proof` runs :func:`rdnet.calib.calibrate.calibrate` blind on every case and
returns per-case metrics: the named effects, the rank of the true effect among the
candidates (by held-out gain), the relative error of its parameters, and the held-out
discrepancy before (base config) and after (fitted config), raw and as excess over the
noise floor (the discrepancy of the fitted simulator against itself with other seeds).

Two generators make the "real" events (``ProofCase.generator``): ``rdnet`` (the simulator
the calibration fits, as above) and ``circuit`` (:mod:`rdnet.circuit`, an independent
continuous-time pixel-circuit model that shares no code with it), which takes frames
rendered ``circuit_oversample`` times denser than the recorded ones from the same analytic
scene and gets the true config through :func:`rdnet.circuit.from_degrade`. The case lists:
:data:`CASES` (the original rdnet cases, unchanged), :data:`RDNET_EXTRA_CASES` and
:data:`CIRCUIT_CASES` (every concealed effect at two strengths and on two scenes, and three
null cases per generator); :func:`cases_for` selects them, ``quick=True`` a small subset.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from rdnet.calib.calibrate import calibrate, calibration_interpolation, numba_threads
from rdnet.calib.effects import EFFECTS, apply
from rdnet.calib.engine import simulate_random_start, warms_up
from rdnet.calib.fit import default_simulate
from rdnet.calib.scene import SceneSpec, draw_texture, render
from rdnet.calib.settings import CalibrateConfig
from rdnet.errors import ConfigError, ValidationError
from rdnet.events.recording import Frames, Recording
from rdnet.sim.settings import DegradeConfig, SensorConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ProofCase:
    """``effect``: the concealed effect (None: a null case). ``base``/``truth``: degrade
    values of the base and the true config; ``truth_threshold_scale``: factor of the true
    thresholds; ``compensate``: the parameter solved so the true event count matches the
    base ('threshold_scale' or a degrade key; None: no concealment needed).
    ``generator``: 'rdnet' or 'circuit' (the model of the true events); ``scene``:
    :class:`SceneSpec` overrides of the recording (e.g. another texture or frame rate);
    ``circuit``: extra :class:`rdnet.circuit.CircuitParams` values of a circuit truth."""

    name: str
    effect: str | None
    base: dict = field(default_factory=dict)
    truth: dict = field(default_factory=dict)
    truth_threshold_scale: float = 1.0
    compensate: str | None = "threshold_scale"
    motion: str = "drift"
    generator: str = "rdnet"
    scene: tuple = ()               # SceneSpec overrides, ((field, value), ...)
    circuit: tuple = ()             # CircuitParams fields of the truth beyond the degrade keys


#: The concealed cases of the issue, and two null cases.
CASES: tuple[ProofCase, ...] = (
    ProofCase("refractory_vs_lower_thresholds", "refractory_period", {}, {"refractory_us": 5000.0}),
    ProofCase("leak_under_shot_noise", "leak_events", {"shot_noise_hz": 2.0},
              {"leak_hz": 0.6, "shot_noise_hz": 1.0}, compensate="shot_noise_hz"),
    ProofCase("bandwidth_in_the_dark", "bandwidth", {}, {"cutoff_hz": 100.0}),
    ProofCase("hot_pixels_in_noise", "hot_pixels", {"shot_noise_hz": 3.0},
              {"hot_pixel_fraction": 0.005, "hot_pixel_hz": 100.0, "shot_noise_hz": 2.0},
              compensate="shot_noise_hz"),
    ProofCase("asymmetry_back_and_forth", "onoff_asymmetry", {}, {"onoff_ratio": 1.5}, motion="backforth"),
    ProofCase("latency_with_jitter", "latency", {"jitter_us": 1000.0},
              {"jitter_us": 1000.0, "latency_us": 4000.0}, compensate=None),
    ProofCase("null_thresholds", None, {}, {}, truth_threshold_scale=1.3, compensate=None),
    ProofCase("null_configured_effects_off", None, {"shot_noise_hz": 1.0, "jitter_us": 300.0},
              {"shot_noise_hz": 2.0, "jitter_us": 600.0}, truth_threshold_scale=0.8, compensate=None),
)


#: the second scene: coarser texture, faster motion, a less dark left half
SCENE_B: tuple = (("texture_px", 2.0), ("speed_px_s", 250.0), ("amplitude_px", 10.0), ("dark_gain", 0.1))

#: (name, effect, base, truth at strength 1, truth at strength 2, compensate, motion)
_EFFECT_TEMPLATES = (
    ("refractory_vs_lower_thresholds", "refractory_period", {}, {"refractory_us": 5000.0},
     {"refractory_us": 2000.0}, "threshold_scale", "drift"),
    ("leak_under_shot_noise", "leak_events", {"shot_noise_hz": 2.0}, {"leak_hz": 0.6, "shot_noise_hz": 1.0},
     {"leak_hz": 1.5, "shot_noise_hz": 1.0}, "shot_noise_hz", "drift"),
    ("bandwidth_in_the_dark", "bandwidth", {}, {"cutoff_hz": 100.0}, {"cutoff_hz": 300.0}, "threshold_scale", "drift"),
    ("hot_pixels_in_noise", "hot_pixels", {"shot_noise_hz": 3.0},
     {"hot_pixel_fraction": 0.005, "hot_pixel_hz": 100.0, "shot_noise_hz": 2.0},
     {"hot_pixel_fraction": 0.01, "hot_pixel_hz": 40.0, "shot_noise_hz": 2.0}, "shot_noise_hz", "drift"),
    ("asymmetry_back_and_forth", "onoff_asymmetry", {}, {"onoff_ratio": 1.5}, {"onoff_ratio": 1.25},
     "threshold_scale", "backforth"),
    ("latency_with_jitter", "latency", {"jitter_us": 1000.0}, {"jitter_us": 1000.0, "latency_us": 4000.0},
     {"jitter_us": 1000.0, "latency_us": 1500.0}, None, "drift"),
    ("threshold_mismatch", "threshold_mismatch", {}, {"threshold_sigma": 0.2}, {"threshold_sigma": 0.1},
     "threshold_scale", "drift"),
)


def _null_cases(generator: str, prefix: str) -> tuple[ProofCase, ...]:
    """The three nulls of the issue: declared values right; only the thresholds off; the
    recording's frames at another rate (60 instead of 100 fps), declared values right."""
    declared = {"shot_noise_hz": 1.0, "jitter_us": 300.0}
    return (ProofCase(f"{prefix}null_declared_right", None, declared, declared, compensate=None, generator=generator),
            ProofCase(f"{prefix}null_thresholds", None, {}, {}, truth_threshold_scale=1.3, compensate=None,
                      generator=generator),
            ProofCase(f"{prefix}null_frame_rate_60", None, declared, declared, compensate=None, generator=generator,
                      scene=(("fps_hz", 60.0),)))


#: DVXplorer-like hot pixels (rdnet generator only; the circuit's hot pixels fire ON only): the
#: polarity keys fitted to the real DVXplorer take's hot pixels (benchmarks/hot_pixel_polarity.py)
_MIXED = {"hot_pixel_on_fraction": 0.66, "hot_pixel_polarity_concentration": 2.9}
_MIXED_HOT_TEMPLATES = tuple(
    ("hot_pixels_mixed_polarity", t[1], t[2], {**t[3], **_MIXED}, {**t[4], **_MIXED}) + t[5:]
    for t in _EFFECT_TEMPLATES if t[0] == "hot_pixels_in_noise")


def _effect_cases(generator: str, prefix: str, skip: frozenset = frozenset(),
                  templates: tuple = _EFFECT_TEMPLATES) -> tuple[ProofCase, ...]:
    out = []
    for name, effect, base, t1, t2, comp, motion in templates:
        for strength, truth in (("s1", t1), ("s2", t2)):
            for scene_name, scene in (("A", ()), ("B", SCENE_B)):
                if (name, strength, scene_name) in skip:
                    continue
                out.append(ProofCase(f"{prefix}{name}_{strength}{scene_name}", effect, base, truth, compensate=comp,
                                     motion=motion, generator=generator, scene=scene))
    return tuple(out)


#: rdnet-generator cases beyond :data:`CASES` (which are the s1 / scene A ones of the six
#: original effects): the other strength and scene, threshold mismatch, and the nulls
#: that :data:`CASES` lacks, then hot pixels of mixed polarity (last, so that every earlier
#: case keeps its random draws). Run after :data:`CASES`, so those keep their results.
RDNET_EXTRA_CASES: tuple[ProofCase, ...] = _effect_cases(
    "rdnet", "", frozenset((t[0], "s1", "A") for t in _EFFECT_TEMPLATES[:6])) + tuple(
    c for c in _null_cases("rdnet", "") if c.name != "null_thresholds") + _effect_cases(
    "rdnet", "", templates=_MIXED_HOT_TEMPLATES)

#: Circuit-generator cases: every concealed effect at two strengths on two scenes, and three nulls.
CIRCUIT_CASES: tuple[ProofCase, ...] = _null_cases("circuit", "circuit_") + _effect_cases("circuit", "circuit_")

#: the ``quick`` subset (names)
QUICK = ("null_thresholds", "latency_with_jitter", "refractory_vs_lower_thresholds",
         "circuit_null_declared_right", "circuit_null_thresholds", "circuit_latency_with_jitter_s1A",
         "circuit_refractory_vs_lower_thresholds_s1A")


def cases_for(generator: str = "both", quick: bool = False) -> dict[str, tuple[ProofCase, ...]]:
    """Case lists per generator ('rdnet', 'circuit' or 'both'), each run with its own
    scene generator; ``quick``: only :data:`QUICK`."""
    if generator not in ("rdnet", "circuit", "both"):
        raise ValidationError("generator", f"expected rdnet, circuit or both, got {generator!r}")
    lists = {"rdnet": CASES + RDNET_EXTRA_CASES, "circuit": CIRCUIT_CASES}
    out = {g: lists[g] for g in ("rdnet", "circuit") if generator in (g, "both")}
    if quick:
        out = {g: tuple(c for c in cs if c.name in QUICK) for g, cs in out.items()}
    return out


#: how long the sensor of a "real" recording has been running on a still scene before the
#: scene starts to move (both generators; the calibration assumes ``calibrate.warmup_us``)
TRUTH_WARMUP_US = 5_000_000   # --truth-warmup-us; 0 = a sensor that starts with the recording
#: how long the scene has been moving before the recording starts (the true sensor sees
#: it; the calibration gets the frames from t = 0 only)
TRUTH_PREROLL_US = 500_000   # --truth-preroll-us (docs/calibration.md "Stationary truths")


def _recorded(events):
    """The events from t = 0 on (a pre-roll's and a warm-up's are not recorded)."""
    t = events.t
    return events.select(t >= 0) if t.size and bool((t < 0).any()) else events


def _truth_events(frames, sensor, degrade, seed, warmup_us=TRUTH_WARMUP_US):
    """The "real" events: the simulator with every pixel started at a random point between
    its thresholds and warmed up for ``warmup_us`` on the first frame (a sensor running
    before the scene moves, in an unknown pixel state), the same draws for every config of
    one case (``seed``); only those from t = 0 on (``frames`` may start before: a pre-roll)."""
    if frames.images.ndim != 3:
        return default_simulate(frames.images, frames.t_us, sensor, degrade, np.random.default_rng(seed))
    return _recorded(simulate_random_start(frames.images, frames.t_us, sensor, degrade, np.random.default_rng(seed),
                                           np.random.default_rng([seed, 7]), warmup_us=warmup_us))


def _circuit_events(frames, sensor, degrade, seed, extra=(), warmup_us=TRUTH_WARMUP_US):
    """The "real" events from the independent circuit model (:mod:`rdnet.circuit`), its
    array warmed up for ``warmup_us`` on the first frame when the truth has leak or shot
    noise (the rule of :func:`rdnet.calib.engine.warms_up`, so that both generators start
    alike); only those from t = 0 on."""
    from rdnet.circuit import from_degrade, generate
    return _recorded(generate(frames.images, frames.t_us, from_degrade(sensor, degrade, **dict(extra)),
                              np.random.default_rng(seed), random_start=True,
                              warmup_us=warmup_us if warms_up(degrade) else 0.0))


#: the concealment's count match: the true count within this fraction of the base count
COUNT_MATCH_TOL = 5e-4


def match_count(count_at, start: tuple, target: int, slope: float, lo: float, hi: float,
                tol: float = COUNT_MATCH_TOL, max_runs: int = 12) -> tuple:
    """Solve ``count(x) = target`` for the log parameter ``x`` in ``[lo, hi]``, the count
    rising with ``x`` when ``slope`` > 0 and falling when < 0. ``count_at(x)`` runs the
    generator and returns ``(x, count, payload)``; ``start``: that triple at the first
    guess (already run). Like a bisection it keeps a bracket, at first the whole range (its
    ends are not run), and shrinks it by each run's side of the target; each step is a
    secant on log count against ``x`` through the two runs nearest the target (``slope``
    until two runs give a slope of its sign), and the bracket's midpoint instead when that
    step leaves the bracket or, once runs lie on both sides of the target, the last two
    steps did not halve it. Stops when a count is within ``tol`` of the target, after
    ``max_runs`` runs, or when the bracket is narrower than 1e-6. Returns the triple of the
    count nearest the target (the first of equals), whose events are then the recording's:
    on the proof's cases 1-6 circuit runs where the bisection took 14, and 3-13 of rdnet's
    simulator where it took 18 (``benchmarks/proof_count_match.py``)."""
    target = max(int(target), 1)
    rising = slope > 0

    def err(c):
        return math.log(max(c, 1) / target)

    pts = [start]
    a, b = lo, hi
    widths = [b - a]

    def shrink(x, c):
        nonlocal a, b
        if (c > target) == rising:
            b = min(b, x)
        else:
            a = max(a, x)

    shrink(start[0], start[1])
    for _ in range(max_runs):
        near = sorted(pts, key=lambda q: abs(q[1] - target))
        best = near[0]
        if abs(best[1] - target) <= tol * target or b - a < 1e-6:
            break
        s = slope
        if len(near) >= 2 and near[0][0] != near[1][0]:
            observed = (err(near[0][1]) - err(near[1][1])) / (near[0][0] - near[1][0])
            if observed * slope > 0:
                s = observed
        x = best[0] - err(best[1]) / s
        sides = {q[1] > target for q in pts if q[1] != target}
        stalled = len(sides) == 2 and len(widths) >= 3 and b - a > 0.5 * widths[-3]
        if stalled or not a < x < b:
            x = 0.5 * (a + b)
        q = count_at(x)
        pts.append(q)
        shrink(q[0], q[1])
        widths.append(b - a)
    return min(pts, key=lambda q: abs(q[1] - target))


def case_spec(case: ProofCase, spec: SceneSpec) -> SceneSpec:
    """The scene of ``case``: ``spec`` with the case's motion and scene overrides."""
    return dataclasses.replace(spec, motion=case.motion, **dict(case.scene))


def case_draws(case: ProofCase, spec: SceneSpec, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """The random draws of one case, in the order :func:`make_recording` takes them: the
    scene's texture, then the seed of the true events (above every calibration seed).
    They are all a case takes from ``rng``, so :func:`run_proof` draws them for every case
    first and the cases can then run in any order, or process, with a serial run's results."""
    tex = draw_texture(case_spec(case, spec), rng)
    return tex, int(rng.integers(1 << 30)) + 10_000_000


def make_recording(case: ProofCase, spec: SceneSpec, sensor: SensorConfig, rng: np.random.Generator | None,
                   oversample: int = 1, interpolate=None, circuit_oversample: int = 4,
                   truth_warmup_us: float = TRUTH_WARMUP_US,
                   truth_preroll_us: int = TRUTH_PREROLL_US,
                   draws: tuple[np.ndarray, int] | None = None) -> tuple[Recording, dict]:
    """The concealed recording of ``case`` and the truth: ``{"degrade": {...},
    "threshold_scale": s, "base_count": n, "count": n, "uncompensated_count": n}`` (and
    ``"circuit"``: the full circuit parameters, for a circuit case).

    rdnet generator: ``oversample`` > 1: the true events come from frames rendered that many
    times denser than the recorded ones (the calibration must then also absorb its own
    interpolation error); 1: from the recorded frames upsampled exactly as the calibration
    will (``interpolate``), so the only difference is the concealed effect (and the
    start: the truth's sensor has seen the scene move for ``truth_preroll_us`` before the
    recording, after running ``truth_warmup_us`` on its first frame held still). Circuit
    generator: always from frames rendered ``circuit_oversample`` times denser (the circuit
    interpolates linearly between them and integrates in sub-steps). ``draws``: the case's
    :func:`case_draws` (taken from ``rng`` when None)."""
    tex, seed = case_draws(case, spec, rng) if draws is None else draws
    spec = case_spec(case, spec)
    pre = int(truth_preroll_us)
    rolled, _ = render(spec, rng, texture=tex, preroll_us=pre)
    k = int(np.searchsorted(rolled.t_us, 0))                     # the recorded frames: from t = 0 on
    frames = Frames(rolled.images[k:], rolled.t_us[k:], rolled.exposure_us[k:]) if k else rolled
    circuit = case.generator == "circuit"
    if circuit:
        fine, _ = render(spec, rng, fps_hz=spec.fps_hz * circuit_oversample, texture=tex, preroll_us=pre)
    elif oversample > 1:
        fine, _ = render(spec, rng, fps_hz=spec.fps_hz * oversample, texture=tex, preroll_us=pre)
    else:
        from rdnet.sim.interpolate import InterpolateConfig, upsample_all
        im, t = upsample_all(rolled.images, rolled.t_us, interpolate or InterpolateConfig(), sensor.log_eps)
        fine = Frames(im, t, np.zeros(len(t), np.int64))
    if circuit:
        def events_of(s_, d_):
            return _circuit_events(fine, s_, d_, seed, case.circuit, truth_warmup_us)
    else:
        def events_of(s_, d_):
            return _truth_events(fine, s_, d_, seed, truth_warmup_us)
    base_deg = DegradeConfig(**case.base)
    n_base = len(events_of(sensor, base_deg))
    values = dict(case.truth)
    values["threshold_scale"] = case.truth_threshold_scale

    def run_at(x: float | None) -> tuple:
        vals = dict(values)
        if x is not None:
            vals[case.compensate] = math.exp(x)
        ev = events_of(*apply(sensor, DegradeConfig(), vals))
        return x, len(ev), ev

    key = case.compensate
    x0 = None if key is None else math.log(values[key])
    first = run_at(x0)
    n_unc, events = first[1], first[2]
    if key is not None:
        # the count falls as the thresholds rise and rises with the noise rate
        x, _, events = match_count(run_at, first, n_base, -1.0 if key == "threshold_scale" else 0.5,
                                   math.log(1e-4) if key != "threshold_scale" else x0 - 3.0, x0 + 3.0)
        values[key] = math.exp(x)
    s, d = apply(sensor, DegradeConfig(), values)
    rec = Recording(spec.width, spec.height, events=events, frames=frames,
                    sensor="proof scene (circuit generator)" if circuit else "proof scene")
    truth = {"degrade": {k: float(getattr(d, k)) for k in d.active()},
             "threshold_scale": float(values["threshold_scale"]), "base_count": n_base,
             "count": len(events), "uncompensated_count": n_unc, "generator": case.generator}
    if circuit:
        from rdnet.circuit import from_degrade
        truth["circuit"] = dataclasses.asdict(from_degrade(s, d, **dict(case.circuit)))
    return rec, truth


def case_metrics(case: ProofCase, report: dict, truth: dict) -> dict:
    """Named effects, rank and parameter error of the true effect, discrepancies."""
    named = [e["name"] for e in report["effects"] if e["missing"]]
    d = report["discrepancy"]
    out = {"case": case.name, "true_effect": case.effect, "generator": case.generator, "named": named,
           "heldout_before": d["heldout_before"], "heldout_after": d["heldout_after"],
           "heldout_ratio": d["heldout_after"] / d["heldout_before"] if d["heldout_before"] > 0 else float("nan"),
           "heldout_noise_floor": d["heldout_noise_floor"],
           "heldout_excess_ratio": (d["heldout_excess_after"] / d["heldout_excess_before"]
                                    if d["heldout_excess_before"] > 0 else float("nan")),
           "truth": truth}
    if case.effect is None:
        out["outcome"] = "right (none)" if not named else "wrong"
        out["rank"] = None
        out["param_rel_error"] = None
        return out
    entry = next((e for e in report["effects"] if e["name"] == case.effect), None)
    out["rank"] = entry.get("rank") if entry else None
    out["confidence"] = entry["confidence"] if entry else None
    errs = {}
    if entry:
        for k in EFFECTS[case.effect].keys:
            tv = truth["degrade"].get(k, DegradeConfig().__getattribute__(k))
            ev = entry["parameters"].get(k)
            if ev is not None and tv:
                errs[k] = abs(ev - tv) / abs(tv)
    out["param_rel_error"] = errs
    out["param_max_rel_error"] = max(errs.values()) if errs else None
    out["fitted_parameters"] = entry["parameters"] if entry else {}
    if not named:
        out["outcome"] = "none"
    elif named[0] == case.effect:
        out["outcome"] = "right"
    else:
        out["outcome"] = "wrong" if case.effect not in named else "right (not first)"
    return out


def run_case(case: ProofCase, draws: tuple[np.ndarray, int], out_dir: str | Path | None, *,
             spec: SceneSpec = SceneSpec(), sensor: SensorConfig = SensorConfig(),
             cfg: CalibrateConfig = CalibrateConfig(), oversample: int = 1, interpolate=None,
             seed: int = 0, circuit_oversample: int = 4, truth_warmup_us: float = TRUTH_WARMUP_US,
             truth_preroll_us: int = TRUTH_PREROLL_US) -> dict:
    """One case of :func:`run_proof` from its :func:`case_draws`: the concealed recording,
    the calibration run blind on it (report under ``out_dir/<case>/`` when given), and the
    case's metrics (:func:`case_metrics`, with the calibration's ``runtime_s``)."""
    from rdnet.calib.report import write_report
    with numba_threads(cfg.threads):
        rec, truth = make_recording(case, spec, sensor, None, oversample, interpolate, circuit_oversample,
                                    truth_warmup_us, truth_preroll_us, draws=draws)
    log.info("proof case %s: truth %s", case.name, truth)
    cal = calibrate(rec, sensor, DegradeConfig(**case.base), cfg, seed=seed, interpolate=interpolate,
                    source=f"proof:{case.name}")
    if out_dir is not None:
        write_report(cal, Path(out_dir) / case.name)
    m = case_metrics(case, cal.report, truth)
    m["runtime_s"] = cal.runtime_s
    log.info("proof case %s: named %s (rank of truth %s), held-out %.3f -> %.3f", case.name,
             m["named"], m["rank"], m["heldout_before"], m["heldout_after"])
    return m


def proof_metrics(results: list[dict], out_dir: str | Path | None) -> dict:
    """``{"cases": results, "summary": {...}}`` of a list of :func:`run_case` results
    (written to ``out_dir/proof.json`` when given)."""
    from rdnet.calib.report import write_json
    conc = [r for r in results if r["true_effect"]]
    null = [r for r in results if not r["true_effect"]]
    summary = {
        "concealed_cases": len(conc),
        "named_right_first": sum(r["outcome"] == "right" for r in conc),
        "ranked_first": sum(r["rank"] == 1 for r in conc),
        "params_within_25pct": sum((r.get("param_max_rel_error") is not None and r["param_max_rel_error"] <= 0.25)
                                   for r in conc),
        "heldout_halved": sum(r["heldout_ratio"] <= 0.5 for r in conc),
        "heldout_excess_over_noise_floor_halved": sum(r["heldout_excess_ratio"] <= 0.5 for r in conc),
        "null_cases": len(null),
        "null_named_nothing": sum(not r["named"] for r in null),
    }
    metrics = {"cases": list(results), "summary": summary}
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        write_json(Path(out_dir) / "proof.json", metrics)
    return metrics


def run_proof(cases: Sequence[ProofCase] | None, out_dir: str | Path | None, rng: np.random.Generator, *,
              spec: SceneSpec = SceneSpec(), **kw) -> dict:
    """Run the calibration blind on every case (:func:`run_case`; ``kw``: its settings:
    ``sensor``, ``cfg``, ``oversample``, ``interpolate``, ``seed`` (of the calibration),
    ``circuit_oversample``, ``truth_warmup_us`` (how long the true sensor runs on the first
    frame before the scene moves, :data:`TRUTH_WARMUP_US`), ``truth_preroll_us`` (how long
    the scene moves before the recording, :data:`TRUTH_PREROLL_US`)); write each case's
    report under ``out_dir/<case>/`` (when given) and return :func:`proof_metrics`. Every
    case's draws are taken from ``rng`` first (:func:`case_draws`)."""
    cases = CASES if cases is None else cases
    draws = [case_draws(c, spec, rng) for c in cases]
    return proof_metrics([run_case(c, d, out_dir, spec=spec, **kw) for c, d in zip(cases, draws)], out_dir)


def generator_dir(out_dir: str | Path, generator: str) -> Path:
    """Where :func:`run_generators` writes a generator's reports: ``out_dir`` for rdnet,
    ``out_dir/<generator>`` otherwise."""
    return Path(out_dir) if generator == "rdnet" else Path(out_dir) / generator


@dataclass(frozen=True)
class Block:
    """A list of cases run by :func:`run_proof` from a fresh ``default_rng(seed)`` (so its
    results do not depend on what else runs, nor where), reports in ``out_dir``; ``kw``:
    further :func:`run_proof` arguments. ``only``: the names of the cases to run (None:
    all); the draws are still taken for every case of ``cases``, so a case run alone gets
    the draws, and the result, it gets in the whole block."""

    key: str
    cases: tuple
    out_dir: Path | None
    kw: dict = field(default_factory=dict)
    only: frozenset | None = None

    @property
    def to_run(self) -> tuple:
        return tuple(c for c in self.cases if self.only is None or c.name in self.only)


def _run_job(job: tuple) -> dict:
    block, case, draws = job
    return run_case(case, draws, block.out_dir, **block.kw)


def block_draws(cases: Sequence[ProofCase], spec: SceneSpec, seed: int) -> list[tuple[ProofCase, tuple]]:
    """Every case of a block with its :func:`case_draws`, taken in the block's order from a
    fresh ``default_rng(seed)``: a case's draws do not depend on which cases run."""
    rng = np.random.default_rng(seed)
    return [(c, case_draws(c, spec, rng)) for c in cases]


def run_jobs(fn: Callable, jobs: Sequence, workers: int = 1, first: Callable | None = None) -> list:
    """``[fn(job) for job in jobs]`` in ``workers`` forked processes (in this one with one
    worker), the jobs for which ``first(job)`` holds submitted first (the slow circuit cases);
    the results in the order of ``jobs``."""
    if workers <= 1 or len(jobs) <= 1:
        return [fn(j) for j in jobs]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    order = sorted(range(len(jobs)), key=lambda i: not first(jobs[i])) if first else range(len(jobs))   # stable
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=mp.get_context("fork")) as ex:
        futures = {i: ex.submit(fn, jobs[i]) for i in order}
        return [futures[i].result() for i in range(len(jobs))]


def run_blocks(blocks: Sequence[Block], seed: int, workers: int = 1) -> dict[str, dict]:
    """:func:`run_proof` of every block, each from its own ``default_rng(seed)``; returns
    ``{block.key: metrics}`` in the order of ``blocks``. The cases of all blocks run in
    ``workers`` processes, the slow circuit cases first (each case's draws are taken in
    the block's order beforehand, :func:`block_draws`, so the results equal a serial run's)."""
    jobs = [(b, c, d) for b in blocks for c, d in block_draws(b.cases, b.kw.get("spec", SceneSpec()), seed)
            if b.only is None or c.name in b.only]
    rows = run_jobs(_run_job, jobs, workers, first=lambda job: job[1].generator == "circuit")
    out, k = {}, 0
    for b in blocks:
        n = len(b.to_run)
        out[b.key] = proof_metrics(rows[k:k + n], b.out_dir)
        k += n
    return out


def generator_blocks(out_dir: str | Path | None, *, generator: str = "both", quick: bool = False,
                     names: Sequence[str] | None = None, **kw) -> list[Block]:
    """One :class:`Block` per generator of :func:`cases_for` (only the cases in ``names``
    run when given, with the draws they get in the whole list: a case reruns as in the
    stage; a generator left without cases is skipped); reports go to
    :func:`generator_dir`. ``kw``: further :func:`run_proof` arguments."""
    blocks = []
    only = None if names is None else frozenset(names)
    todo = cases_for(generator, quick)
    unknown = sorted(only - {c.name for cases in todo.values() for c in cases}) if only is not None else []
    if unknown:
        raise ConfigError("cases", f"no such case {', '.join(unknown)} (generator {generator}"
                          f"{', quick subset' if quick else ''}: the names of the proof's reports)")
    for gen, cases in todo.items():
        if any(only is None or c.name in only for c in cases):
            blocks.append(Block(gen, cases, None if out_dir is None else generator_dir(out_dir, gen), dict(kw),
                                only=only))
    return blocks


def run_generators(out_dir: str | Path | None, seed: int, *, generator: str = "both", quick: bool = False,
                   names: Sequence[str] | None = None, workers: int = 1, **kw) -> dict[str, dict]:
    """:func:`run_blocks` of :func:`generator_blocks`: each generator from a fresh
    ``default_rng(seed)`` (so the rdnet cases keep their results whatever else runs)."""
    return run_blocks(generator_blocks(out_dir, generator=generator, quick=quick, names=names, **kw), seed, workers)


def add_proof_arguments(ap) -> None:
    """The options this module's ``main`` and the ``calibration_proof`` stage share (each
    adds its own ``--oversample``: here it replaces the rdnet truth, there it adds a block)."""
    ap.add_argument("--seed", type=int, default=2024, help="seed of the scenes and true events")
    ap.add_argument("--circuit-oversample", type=int, default=4,
                    help="circuit truth from frames this many times denser than the recorded ones")
    ap.add_argument("--generator", choices=("rdnet", "circuit", "both"), default="both",
                    help="model of the true events")
    ap.add_argument("--quick", action="store_true", help=f"only the subset {', '.join(QUICK)}")
    ap.add_argument("--truth-warmup-us", type=float, default=TRUTH_WARMUP_US,
                    help="the true sensor runs this long on the first frame held still before the scene moves (0: off)")
    ap.add_argument("--truth-preroll-us", type=int, default=TRUTH_PREROLL_US,
                    help="the scene moves this long before the recording starts (the true sensor sees it)")


def main(argv: list[str] | None = None) -> int:
    """``python -m rdnet.calib.proof OUT_DIR``: run the proof, write OUT_DIR/proof.json and
    one report per case (circuit cases under OUT_DIR/circuit), print the tables."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m rdnet.calib.proof", description=main.__doc__)
    ap.add_argument("out", type=Path)
    add_proof_arguments(ap)
    ap.add_argument("--oversample", type=int, default=1,
                    help="rdnet truth from frames this many times denser (1: same)")
    ap.add_argument("--cases", nargs="*", default=None, help="case names (default: all of the generator)")
    ap.add_argument("--max-upsample", type=int, default=16, help="interpolate.max_upsample of the scenes")
    ap.add_argument("--warmup-us", type=int, default=None,
                    help="calibrate.warmup_us of the calibration (default: CalibrateConfig's)")
    args = ap.parse_args(argv)
    cfg = CalibrateConfig() if args.warmup_us is None else CalibrateConfig(warmup_us=args.warmup_us)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    runs = run_generators(args.out, args.seed, generator=args.generator, quick=args.quick, names=args.cases,
                          oversample=args.oversample,
                          interpolate=dataclasses.replace(calibration_interpolation(cfg), max_upsample=args.max_upsample), cfg=cfg,
                          circuit_oversample=args.circuit_oversample, truth_warmup_us=args.truth_warmup_us,
                          truth_preroll_us=args.truth_preroll_us)
    for gen, m in runs.items():
        print(f"generator {gen}:")
        print(format_table(m))
    return 0


def format_table(metrics: dict) -> str:
    """Markdown table of :func:`run_proof` metrics."""
    rows = ["| case | true effect | named | rank | parameter rel. error | held-out before | after | "
            "noise floor | excess ratio |", "|---|---|---|---|---|---|---|---|---|"]
    for r in metrics["cases"]:
        err = r.get("param_rel_error") or {}
        e = ", ".join(f"{k} {100 * v:.1f} %" for k, v in err.items()) or "-"
        rows.append(f"| {r['case']} | {r['true_effect'] or '(none)'} | {', '.join(r['named']) or 'none'} | "
                    f"{r['rank'] or '-'} | {e} | {r['heldout_before']:.3f} | {r['heldout_after']:.3f} | "
                    f"{r['heldout_noise_floor']:.3f} | {r['heldout_excess_ratio']:.3f} |")
    rows.append("")
    rows.append("summary: " + ", ".join(f"{k} {v}" for k, v in metrics["summary"].items()))
    return "\n".join(rows)


#: (summary key, column) of :func:`goals_table`, in the order of the issue's goals
GOAL_COLUMNS = (("named_right_first", "named first"), ("ranked_first", "ranked first"),
                ("params_within_25pct", "parameters within 25 %"), ("heldout_halved", "held-out halved"),
                ("heldout_excess_over_noise_floor_halved", "excess over noise floor halved"))


def metric_blocks(metrics: dict) -> dict[str, dict]:
    """{block: its ``summary`` and ``cases``} of the ``calibration_proof`` stage's metrics
    (``metrics/calibration_proof.json``: the rdnet block at the top level, the other
    blocks under their keys, beside ``reliability``); a block's reports are in
    :func:`generator_dir` of the stage's folder and the block's name."""
    return {"rdnet": {k: metrics[k] for k in ("summary", "cases") if k in metrics},
            **{k: v for k, v in metrics.items() if isinstance(v, dict) and "summary" in v}}


def goals_table(metrics: dict) -> str:
    """The proof against the goals of issue 12, one row per block and a total row, from
    the ``calibration_proof`` stage's metrics (:func:`metric_blocks`)."""
    blocks = [(k, v["summary"]) for k, v in metric_blocks(metrics).items()]
    head = ["block", "concealed"] + [c for _, c in GOAL_COLUMNS] + ["nulls naming nothing"]
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    keys = [k for k, _ in GOAL_COLUMNS] + ["concealed_cases", "null_cases", "null_named_nothing"]
    total = {k: sum(int(s[k]) for _, s in blocks) for k in keys}
    for name, s in blocks + [("all", total)]:
        cells = [name, str(s["concealed_cases"])] + [str(s[k]) for k, _ in GOAL_COLUMNS]
        cells.append(f"{s['null_named_nothing']} of {s['null_cases']}")
        lines.append("| " + " | ".join(f"**{c}**" if name == "all" else c for c in cells) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
