"""A per-pixel persistence statistic for threshold mismatch (issue 12: "per-pixel count
dispersion beyond the Poisson expectation (threshold mismatch) vs a global threshold change").

Threshold mismatch gives each pixel its own threshold for the whole recording, so a pixel that
fires more than the simulation expects in one part of the recording does so in every other
part too. Scene content and sampling noise do not persist that way once the simulation's
expectation is divided out. The statistic, on the calibration's own context:

    r_p(A) = log((n_p(A) + 1) / (m_p(A) + 1)),     persistence = cov_p(r_p(fit), r_p(held))

over the moving pixels with m_p >= 3 in both sets (the 2 % most extreme left out), where n_p(A)
counts pixel p's events in the fit (or held-out) segments and m_p(A) is the mean count of 4
simulations of the basic refit (the configured parameters re-fitted, no mismatch; seeds
100-103): the library's statistic (``rdnet.calib.stats._persistence``) with the fit and
held-out segments as the two halves and the basic refit as the reference, where the library
references the declared config and splits each segment set into alternate halves. It is compared for the
recording ("real") and for simulations of the basic refit with ``threshold_sigma`` set to 0,
0.05, 0.1 and 0.2 (seeds 0-2); ``sigma_hat`` reads the recording's value off that curve
(linear interpolation in sigma^2, since the statistic grows as the variance of the log gain).

It runs on proof cases (the recording and truth exactly as the ``calibration_proof`` stage
makes them, ``benchmarks/calib_case_profile.case_recording``) and on the DAVIS346 recording
(as ``calibrate_real``: ideal base), for the ``flow`` and ``selected`` interpolations; the
interpolation the committed calibration kept is marked.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_persistence.py      # about 20 minutes

Writes ``benchmarks/results/calib_persistence.{json,md}``.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

from rdnet.calib import stats as st
from rdnet.calib.calibrate import _objectives, calibration_interpolation, interpolation_configs
from rdnet.calib.context import build_context
from rdnet.calib.fit import fit_basic
from rdnet.config import load_params, section
from rdnet.events.io import load as load_recording
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from calib_case_profile import case_recording  # noqa: E402
from calib_stability import stage_sets  # noqa: E402
from restore_train_range import write_results  # noqa: E402

log = logging.getLogger("calib_persistence")
SIGMAS = (0.0, 0.05, 0.1, 0.2)
REFERENCE_SEEDS = (100, 101, 102, 103)
SEEDS = (0, 1, 2)
#: (case, generator, oversample): the threshold-mismatch cases of the two independent blocks,
#: one of rdnet's own, the nulls of both, and effects that also change per-pixel counts
#: (ON/OFF asymmetry: a threshold change whose per-pixel effect depends on the local texture)
CASES = (
    ("threshold_mismatch_s1A", "rdnet", 4), ("threshold_mismatch_s2A", "rdnet", 4),
    ("threshold_mismatch_s2B", "rdnet", 4),
    ("circuit_threshold_mismatch_s1A", "circuit", 1), ("circuit_threshold_mismatch_s2A", "circuit", 1),
    ("circuit_threshold_mismatch_s2B", "circuit", 1),
    ("threshold_mismatch_s2A", "rdnet", 1),
    ("null_declared_right", "rdnet", 4), ("null_thresholds", "rdnet", 4), ("null_frame_rate_60", "rdnet", 4),
    ("circuit_null_declared_right", "circuit", 1), ("circuit_null_thresholds", "circuit", 1),
    ("circuit_null_frame_rate_60", "circuit", 1),
    ("circuit_bandwidth_in_the_dark_s2A", "circuit", 1), ("circuit_hot_pixels_in_noise_s2A", "circuit", 1),
    ("circuit_refractory_vs_lower_thresholds_s2A", "circuit", 1), ("hot_pixels_in_noise_s2A", "rdnet", 4),
    ("circuit_asymmetry_back_and_forth_s1B", "circuit", 1), ("circuit_asymmetry_back_and_forth_s2B", "circuit", 1),
    ("asymmetry_back_and_forth_s2A", "rdnet", 4),
)


def sigma_hat(real: float, curve: dict) -> float:
    """The threshold_sigma whose simulated persistence (mean over seeds) equals ``real``,
    interpolated linearly in sigma^2 (0 below the sigma = 0 point, extrapolated above 0.2)."""
    s2 = np.array([s * s for s in SIGMAS])
    y = np.array([np.mean(curve[f"{s:g}"]) for s in SIGMAS])
    if real <= y[0]:
        return 0.0
    if real >= y[-1]:
        v = s2[-2] + (real - y[-2]) * (s2[-1] - s2[-2]) / max(y[-1] - y[-2], 1e-12)
    else:
        v = float(np.interp(real, y, s2))
    return float(np.sqrt(max(v, 0.0)))


def measure(rec, base: DegradeConfig, sensor: SensorConfig, cfg, interp, name: str, kept: str | None) -> dict:
    out = {"recording": name, "kept_interpolation": kept, "interpolations": {}}
    for icfg in interpolation_configs(cfg, interp):
        if icfg.method not in ("flow", "selected"):
            continue
        ctx = build_context(rec, cfg, sensor.log_eps, interpolate=icfg, source=name)
        obj, fine, search = _objectives(ctx, sensor, base, list(SEEDS), None)
        values, _ = fit_basic(search, fine)
        moving = ~ctx.static.ravel()
        ref = np.mean([obj.summary(values, s).pix for s in REFERENCE_SEEDS], 0)      # (S, P)

        def persistence(pix: np.ndarray) -> float:
            return st._persistence(pix, ref, ctx.fit, ctx.held, moving)
        real = persistence(st.summarize(ctx.real, ctx).pix)
        curve = {}
        for sig in SIGMAS:
            v = dict(values)
            if sig:
                v["threshold_sigma"] = sig
            curve[f"{sig:g}"] = [persistence(obj.summary(v, s).pix) for s in SEEDS]
        out["interpolations"][icfg.method] = {"real": real, "sim": curve,
                                              "sigma_hat": sigma_hat(real, curve),
                                              "basic_refit": {k: float(x) for k, x in values.items()}}
        log.info("%s %s: real %.4f, sim %s, sigma_hat %.3f", name, icfg.method, real,
                 {k: round(float(np.mean(x)), 4) for k, x in curve.items()}, out["interpolations"][icfg.method]["sigma_hat"])
    return out


def kept_interpolation(case: str, generator: str, oversample: int) -> str | None:
    sub = {"circuit": "circuit/", "rdnet": "oversample4/" if oversample > 1 else ""}[generator]
    path = ROOT / "results" / "calibration" / "proof" / f"{sub}{case}" / "report.json"
    return json.loads(path.read_text())["frame_interpolation"]["chosen"] if path.is_file() else None


def markdown(res: dict) -> str:
    lines = ["Persistence of each pixel's excess over the basic refit between the fit and the held-out "
             "segments (`python benchmarks/calib_persistence.py`; definition in the script's docstring): "
             "the recording's value, the simulations' (mean over 3 seeds, their spread in brackets) at "
             "threshold_sigma 0 / 0.05 / 0.1 / 0.2, and the sigma that reads the recording's value off that curve. "
             "**bold**: the interpolation the committed calibration kept.", "",
             "| recording | true threshold_sigma | interpolation | real | sim 0 | sim 0.05 | sim 0.1 | sim 0.2 | sigma_hat |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for r in res["recordings"]:
        for method, d in r["interpolations"].items():
            sims = " | ".join(f"{np.mean(d['sim'][f'{s:g}']):.4f} ({np.std(d['sim'][f'{s:g}'], ddof=1):.4f})"
                              for s in SIGMAS)
            m = f"**{method}**" if method == r["kept_interpolation"] else method
            truth = r.get("true_threshold_sigma")
            lines.append(f"| {r['recording']} | {'-' if truth is None else f'{truth:g}'} | {m} | {d['real']:.4f} | "
                         f"{sims} | {d['sigma_hat']:.3f} |")
    return "\n".join(lines) + "\n"


def calibrate_settings(params: Path):
    """The ``calibrate`` section of ``params`` and the proof's interpolation (its
    ``max_upsample``), with the library's per-step logging quietened."""
    for name in ("rdnet.calib", "rdnet.sim"):
        logging.getLogger(name).setLevel(logging.WARNING)
    cfg = section(load_params(params), "calibrate")
    return cfg, calibration_interpolation(cfg)


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=None, help="CASE:GENERATOR:OVERSAMPLE (default: the list above)")
    ap.add_argument("--real", type=Path, default=ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4")
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "calib_persistence.json")
    args = ap.parse_args()
    cfg, interp = calibrate_settings(args.params)
    cases = CASES if args.cases is None else [(c.split(":")[0], c.split(":")[1], int(c.split(":")[2]))
                                              for c in args.cases]
    rows = []
    for case_name, generator, oversample in cases:
        case, rec, truth = case_recording(case_name, generator, oversample, cfg, interp, 2024)
        label = f"{case_name} ({generator}{', oversample 4' if oversample > 1 else ''})"
        r = measure(rec, DegradeConfig(**case.base), SensorConfig(), cfg, interp, label,
                    kept_interpolation(case_name, generator, oversample))
        r["true_threshold_sigma"] = truth["degrade"].get("threshold_sigma") if case.effect == "threshold_mismatch" else None
        rows.append(r)
    if args.real.is_file():
        p = load_params(args.params, stage_sets(ROOT / "dvc.yaml"))
        report = ROOT / "results" / "calibration" / "davis346" / "report.json"
        kept = json.loads(report.read_text())["frame_interpolation"]["chosen"] if report.is_file() else None
        r = measure(load_recording(args.real), section(p, "degrade"), section(p, "sensor"), section(p, "calibrate"),
                    section(p, "interpolate"), "DAVIS346 road (ideal base)", kept)
        r["true_threshold_sigma"] = None
        rows.append(r)
    write_results(args.out, {"benchmark": "calib_persistence", "sigmas": list(SIGMAS), "recordings": rows}, markdown)


if __name__ == "__main__":
    main()
