"""Proof of the calibration on concealed effects.

Each case renders the procedural scene of :mod:`rdnet.calib.scene` and simulates a
"real" recording with a *true* config that holds one effect the *base* config leaves
out, and conceals it: one compensating parameter (the common threshold factor or the shot
noise rate) is solved by bisection so that the total event count equals that of the base
config on the same frames and seed. Null cases differ from the base only in the thresholds
(and the values of effects the base already has): the tool must name nothing.

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
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from rdnet.calib.calibrate import calibrate, numba_threads
from rdnet.calib.effects import EFFECTS, apply
from rdnet.calib.engine import simulate_random_start
from rdnet.calib.fit import default_simulate
from rdnet.calib.scene import SceneSpec, render
from rdnet.calib.settings import CalibrateConfig
from rdnet.events.recording import Frames, Recording
from rdnet.sim.settings import DegradeConfig, SensorConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ProofCase:
    """``effect``: the concealed effect (None: a null case). ``base``/``truth``: degrade
    values of the base and the true config; ``truth_threshold_scale``: factor of the true
    thresholds; ``compensate``: the parameter solved so the true event count matches the
    base ('threshold_scale' or a degrade key; None: no concealment needed)."""

    name: str
    effect: str | None
    base: dict = field(default_factory=dict)
    truth: dict = field(default_factory=dict)
    truth_threshold_scale: float = 1.0
    compensate: str | None = "threshold_scale"
    motion: str = "drift"


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


def _truth_events(frames, sensor, degrade, seed):
    """The "real" events: the simulator with every pixel started at a random point between
    its thresholds (a recording starts in an unknown pixel state), the same draws for every
    config of one case (``seed``)."""
    if frames.images.ndim != 3:
        return default_simulate(frames.images, frames.t_us, sensor, degrade, np.random.default_rng(seed))
    return simulate_random_start(frames.images, frames.t_us, sensor, degrade, np.random.default_rng(seed),
                                 np.random.default_rng([seed, 7]))


def _count(frames, sensor, degrade, seed) -> int:
    return len(_truth_events(frames, sensor, degrade, seed))


def make_recording(case: ProofCase, spec: SceneSpec, sensor: SensorConfig, rng: np.random.Generator,
                   oversample: int = 1, interpolate=None) -> tuple[Recording, dict]:
    """The concealed recording of ``case`` and the truth: ``{"degrade": {...},
    "threshold_scale": s, "base_count": n, "count": n, "uncompensated_count": n}``.

    ``oversample`` > 1: the true events come from frames rendered that many times denser
    than the recorded ones (the calibration must then also absorb its own interpolation
    error); 1: from the recorded frames upsampled exactly as the calibration will
    (``interpolate``), so the only difference is the concealed effect."""
    spec = dataclasses.replace(spec, motion=case.motion)
    frames, tex = render(spec, rng)
    if oversample > 1:
        fine, _ = render(spec, rng, fps_hz=spec.fps_hz * oversample, texture=tex)
    else:
        from rdnet.sim.interpolate import InterpolateConfig, upsample_all
        im, t = upsample_all(frames.images, frames.t_us, interpolate or InterpolateConfig(), sensor.log_eps)
        fine = Frames(im, t, np.zeros(len(t), np.int64))
    seed = int(rng.integers(1 << 30)) + 10_000_000          # never one of the calibration seeds
    base_deg = DegradeConfig(**case.base)
    n_base = _count(fine, sensor, base_deg, seed)
    values = dict(case.truth)
    values["threshold_scale"] = case.truth_threshold_scale

    def count_with(v: float | None) -> int:
        vals = dict(values)
        if v is not None:
            vals[case.compensate] = v
        s, d = apply(sensor, DegradeConfig(), vals)
        return _count(fine, s, d, seed)

    n_unc = count_with(None)
    if case.compensate is not None:
        key = case.compensate
        start = values[key]
        # count falls as thresholds rise and rises with the noise rate
        sign = -1.0 if key == "threshold_scale" else 1.0
        lo, hi = math.log(start) - 3.0, math.log(start) + 3.0
        if key != "threshold_scale":
            lo = math.log(1e-4)
        for _ in range(16):
            mid = 0.5 * (lo + hi)
            too_many = count_with(math.exp(mid)) > n_base
            if too_many == (sign > 0):
                hi = mid
            else:
                lo = mid
        values[key] = math.exp(0.5 * (lo + hi))
    s, d = apply(sensor, DegradeConfig(), values)
    events = _truth_events(fine, s, d, seed)
    rec = Recording(spec.width, spec.height, events=events, frames=frames, sensor="proof scene")
    truth = {"degrade": {k: float(getattr(d, k)) for k in d.active()},
             "threshold_scale": float(values["threshold_scale"]), "base_count": n_base,
             "count": len(events), "uncompensated_count": n_unc}
    return rec, truth


def case_metrics(case: ProofCase, report: dict, truth: dict) -> dict:
    """Named effects, rank and parameter error of the true effect, discrepancies."""
    named = [e["name"] for e in report["effects"] if e["missing"]]
    d = report["discrepancy"]
    out = {"case": case.name, "true_effect": case.effect, "named": named,
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


def run_proof(cases: Sequence[ProofCase] | None, out_dir: str | Path | None, rng: np.random.Generator, *,
              spec: SceneSpec = SceneSpec(), sensor: SensorConfig = SensorConfig(),
              cfg: CalibrateConfig = CalibrateConfig(), oversample: int = 1, interpolate=None,
              seed: int = 0) -> dict:
    """Run the calibration blind on every case; write each case's report under
    ``out_dir/<case>/`` (when given) and return ``{"cases": [...], "summary": {...}}``."""
    from rdnet.calib.report import write_json, write_report
    cases = CASES if cases is None else cases
    results = []
    for case in cases:
        with numba_threads(cfg.threads):
            rec, truth = make_recording(case, spec, sensor, rng, oversample, interpolate)
        log.info("proof case %s: truth %s", case.name, truth)
        cal = calibrate(rec, sensor, DegradeConfig(**case.base), cfg, seed=seed, interpolate=interpolate,
                        source=f"proof:{case.name}")
        if out_dir is not None:
            write_report(cal, Path(out_dir) / case.name)
        m = case_metrics(case, cal.report, truth)
        m["runtime_s"] = cal.runtime_s
        results.append(m)
        log.info("proof case %s: named %s (rank of truth %s), held-out %.3f -> %.3f", case.name,
                 m["named"], m["rank"], m["heldout_before"], m["heldout_after"])
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
    metrics = {"cases": results, "summary": summary}
    if out_dir is not None:
        write_json(Path(out_dir) / "proof.json", metrics)
    return metrics


def main(argv: list[str] | None = None) -> int:
    """``python -m rdnet.calib.proof OUT_DIR``: run the proof, write OUT_DIR/proof.json and
    one report per case, print the table."""
    import argparse

    from rdnet.sim.interpolate import InterpolateConfig
    ap = argparse.ArgumentParser(prog="python -m rdnet.calib.proof", description=main.__doc__)
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=2024, help="seed of the scenes and true events")
    ap.add_argument("--oversample", type=int, default=1, help="truth from frames this many times denser (1: same)")
    ap.add_argument("--cases", nargs="*", default=None, help="case names (default: all)")
    ap.add_argument("--max-upsample", type=int, default=16, help="interpolate.max_upsample of the scenes")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cases = [c for c in CASES if args.cases is None or c.name in args.cases]
    m = run_proof(cases, args.out, np.random.default_rng(args.seed), oversample=args.oversample,
                  interpolate=InterpolateConfig(max_upsample=args.max_upsample))
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


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
