"""The ``lag`` statistic on interleaved segments (issue 12; docs/calibration.md, "Why latency
is vetoed").

``rdnet.calib.stats.xcorr_lag_us`` sums, at each lag, the products of the rate-over-time bins
inside a mask. The calibration's fit and held-out masks interleave (3 runs each), so every lag
step loses pairs at the run ends, and a broad correlation peak is pulled towards 0. This script
measures that on the proof's oversample4 ``latency_with_jitter`` case (truth: 4 ms latency, 1 ms
jitter; "real" events from frames rendered 4x denser than the recorded ones), with the block's
own random draws, for the random-start and the stationary truths:

* the lag of the simulation without latency (declared config: 1 ms jitter) and with the true
  4 ms, against the recording, over the whole window, the fit and the held-out segments and
  each segment alone, with the committed sum and with :func:`xcorr_lag_pearson` (each lag
  normalised by its own pairs inside the mask);
* the recorded / simulated event count per segment;
* a test signal (a slow rate, period 100 bins, shifted by 2 and -3 bins) through a mask of 3
  runs of 83 bins.

:func:`xcorr_lag_pearson`, ``rdnet.calib.stats.pearson_lag_us`` (the Pearson lag of the
smoothed rates) and :func:`quantile_lag` are the variants that were tried in the full proof as
the ``lag`` term and not kept: ``--proof-with NAME OUT`` runs the ``calibration_proof`` stage with
``rdnet.calib.stats.xcorr_lag_us`` replaced by one of them (14-30 min;
``benchmarks/results/calibration_proof_lag_pearson.json``: ``pearson`` on the random-start
truths of the code before 2026-11-27, ``--truth-warmup-us 0 --truth-preroll-us 0`` with
``calibrate.warmup_us: 0`` today; ``calibration_proof_lag_pearson_smoothed.json``:
``pearson_smoothed`` on the stationary truths, the defaults; ``calibration_proof_lag_quantile.json``:
``quantile`` (:func:`quantile_lag`), the same). The variant that did better kept the ``lag``
term and used the smoothed Pearson lag only as latency's own statistic
(``calibration_proof_lag_signature.json``, measured with a patch before 2026-11-28): that is the
library's ``lag_smoothed`` statistic today (weight 0), so every ``--proof-with`` run now has it too.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_lag_segments.py    # ~1 min
    PYTHONPATH=$PWD .venv/bin/python benchmarks/calib_lag_segments.py --proof-with pearson_smoothed /tmp/proof
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

from rdnet.calib import stats as st
from rdnet.calib.calibrate import calibration_interpolation
from rdnet.calib.context import build_context
from rdnet.calib.fit import Objective
from rdnet.calib.proof import case_draws, cases_for, make_recording
from rdnet.calib.scene import SceneSpec
from rdnet.config import load_params, section
from rdnet.sim.settings import DegradeConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("calib_lag_segments")


def xcorr_lag_pearson(sim: np.ndarray, real: np.ndarray, mask: np.ndarray, bin_us: float,
                      max_lag_us: float) -> float:
    """:func:`rdnet.calib.stats.pearson_lag_us` without the smoothing (each lag's correlation
    the Pearson coefficient of the bin pairs both inside ``mask``)."""
    return st.pearson_lag_us(sim, real, mask, bin_us, max_lag_us, smooth_bins=1)


#: cumulative shares at which :func:`quantile_lag` compares the times
QUANTILES = np.linspace(0.1, 0.9, 9)


def quantile_lag(sim: np.ndarray, real: np.ndarray, mask: np.ndarray, bin_us: float,
                 max_lag_us: float) -> float:
    """Lag (us) as the median, over the mask's runs and the shares :data:`QUANTILES`, of
    the time at which the recording's cumulative rate reaches that share of its run's total
    minus the time the simulation's does. The cumulative sum integrates the frame-period
    ripple away, and each run is normalised by its own total, so a count ratio that differs
    between runs does not enter; ``max_lag_us`` is not used."""
    m = np.asarray(mask, bool)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], m.astype(np.int8), [0]])))
    diffs = []
    for a, b in zip(edges[::2], edges[1::2]):
        cs, cr = np.cumsum(sim[a:b]), np.cumsum(real[a:b])
        if cs[-1] <= 0 or cr[-1] <= 0:
            continue
        x = np.arange(b - a + 1, dtype=float)               # bin edges of the run
        ts = np.interp(QUANTILES, np.concatenate([[0.0], cs / cs[-1]]), x)
        tr = np.interp(QUANTILES, np.concatenate([[0.0], cr / cr[-1]]), x)
        diffs.append(tr - ts)
    return float(np.median(np.concatenate(diffs)) * bin_us) if diffs else 0.0


ESTIMATORS = {"sum (committed)": st.xcorr_lag_us, "pearson (tried)": xcorr_lag_pearson,
              "pearson smoothed (tried)": st.pearson_lag_us, "quantile times (tried)": quantile_lag}
VARIANTS = {"pearson": xcorr_lag_pearson, "pearson_smoothed": st.pearson_lag_us, "quantile": quantile_lag}


def run_proof_with(name: str, out: Path, extra: list[str]) -> None:
    """The ``calibration_proof`` stage with ``xcorr_lag_us`` (the ``lag`` term of the
    discrepancy and latency's first guess) replaced by ``VARIANTS[name]`` (every caller looks
    it up in ``rdnet.calib.stats`` at call time); outputs under ``out``."""
    import runpy
    import sys
    st.xcorr_lag_us = VARIANTS[name]
    sys.path.insert(0, str(ROOT / "stages"))
    sys.argv = ["calibration_proof.py", "--out", str(out / "proof"), "--metrics", str(out / "metrics.json"), *extra]
    runpy.run_path(str(ROOT / "stages" / "calibration_proof.py"), run_name="__main__")


def test_signal() -> dict:
    t = np.arange(500)
    rate = 1.0 + np.sin(2 * np.pi * t / 200.0) ** 2
    mask = (t // 83) % 2 == 1
    out = {}
    for shift in (2, -3):
        real = np.interp(t - shift, t, rate)
        out[str(shift)] = {name: f(rate, real, mask, 2000.0, 20000.0) / 2000.0 for name, f in ESTIMATORS.items()}
    return out


def case_lags(truth: str, cfg, seeds: list[int]) -> dict:
    gen = "rdnet"
    cases = cases_for(gen)[gen]
    rng = np.random.default_rng(2024)                 # the stage's seed: the block's own draws
    draws = {c.name: case_draws(c, SceneSpec(), rng) for c in cases}
    case = next(c for c in cases if c.name == "latency_with_jitter")
    kw = (dict(truth_warmup_us=0, truth_preroll_us=0) if truth == "random start"
          else dict(truth_warmup_us=5_000_000, truth_preroll_us=500_000))
    ip = calibration_interpolation(cfg)
    rec, _ = make_recording(case, SceneSpec(), SensorConfig(), None, oversample=4, interpolate=ip,
                            draws=draws[case.name], **kw)
    ctx = build_context(rec, cfg, SensorConfig().log_eps, interpolate=dataclasses.replace(ip, method="linear"))
    obj = Objective(ctx, SensorConfig(), DegradeConfig(**case.base), seeds)
    real = st.summarize(ctx.real, ctx)
    masks = {"whole": range(len(ctx.segments)), "fit": ctx.fit, "held-out": ctx.held}
    masks.update({f"segment {k}": (k,) for k in range(len(ctx.segments))})
    res = {"frames_simulated": int(len(ctx.sim_t)), "configs": {}}
    for label, values in (("declared (jitter 1 ms), no latency", {}), ("with the true latency 4 ms", {"latency_us": 4000.0})):
        rows = {}
        for mname, segs in masks.items():
            r = st.aggregate(real, ctx, segs)
            sims = [st.aggregate(obj.summary(values, s), ctx, segs) for s in seeds]   # once per seed
            row = {ename: [round(f(a["rate_time"], r["rate_time"], r["time_mask"], float(cfg.time_bin_us),
                                   float(cfg.max_lag_us))) for a in sims]
                   for ename, f in ESTIMATORS.items()}
            row["recorded / simulated events"] = float(r["count"]) / max(float(np.mean([a["count"] for a in sims])), 1.0)
            rows[mname] = row
        res["configs"][label] = rows
    return res


def markdown(out: dict) -> str:
    lines = ["# The `lag` statistic on interleaved segments", "",
             "Oversample4 `latency_with_jitter` of the proof (truth 4 ms latency, 1 ms jitter), the block's own "
             "draws, linear interpolation, simulation seeds " + ", ".join(map(str, out["seeds"])) + ". "
             "Lags in us (positive: the recording is later), one per seed; `sum` is "
             "`rdnet.calib.stats.xcorr_lag_us`; the variants tried: `pearson` (each lag normalised by its own "
             f"pairs inside the mask) and `pearson smoothed` (both rates first smoothed over "
             f"{st.LAG_SMOOTH_BINS} bins, one frame period; since 2026-11-28 latency's own statistic "
             "`lag_smoothed`, weight 0), and `quantile times` (the median shift of the times at which each run's "
             "cumulative rate reaches 10, 20, ..., 90 % of its total). docs/calibration.md, \"Why latency is vetoed\".", ""]
    for truth, res in out["cases"].items():
        lines += [f"## {truth} truth", ""]
        for label, rows in res["configs"].items():
            lines += [f"Simulation: {label}.", "",
                      "| bins | lag, sum (committed) | lag, pearson (tried) | lag, pearson smoothed (tried) | "
                      "lag, quantile times (tried) | recorded / simulated events |", "|---|---|---|---|---|---|"]
            for mname, row in rows.items():
                lines.append(f"| {mname} | {row['sum (committed)']} | {row['pearson (tried)']} | "
                             f"{row['pearson smoothed (tried)']} | {row['quantile times (tried)']} | "
                             f"{row['recorded / simulated events']:.3f} |")
            lines.append("")
    lines += ["## Test signal", "", "A slow rate (period 100 bins) shifted by `shift` bins, seen through 3 runs of 83 "
              "bins (as the held-out mask); lag read in bins:", "",
              "| shift | sum (committed) | pearson (tried) | pearson smoothed (tried) | quantile times (tried) |",
              "|---|---|---|---|---|"]
    for shift, row in out["test_signal"].items():
        lines.append(f"| {shift} | {row['sum (committed)']:.2f} | {row['pearson (tried)']:.2f} | "
                     f"{row['pearson smoothed (tried)']:.2f} | {row['quantile times (tried)']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "calib_lag_segments")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--proof-with", nargs=2, metavar=("VARIANT", "OUT"), default=None,
                    help=f"run the calibration_proof stage with another lag ({', '.join(VARIANTS)}) into OUT")
    args, extra = ap.parse_known_args(argv)
    if args.proof_with:
        run_proof_with(args.proof_with[0], Path(args.proof_with[1]), extra)
        return 0
    if extra:
        ap.error(f"unrecognized arguments: {' '.join(extra)}")
    logging.basicConfig(level=logging.WARNING)
    cfg = section(load_params(ROOT / "params.yaml"), "calibrate")
    out = {"seeds": args.seeds, "test_signal": test_signal(),
           "cases": {t: case_lags(t, cfg, args.seeds) for t in ("random start", "stationary")}}
    args.results.with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")
    args.results.with_suffix(".md").write_text(markdown(out))
    print(markdown(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
