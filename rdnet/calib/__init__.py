"""Sim-to-real calibration (``rdnet calibrate``): statistics, mismatch localisation,
effect fits, report, and the proof on concealed effects.

- :mod:`~rdnet.calib.context`: the recording's window, segments, pixel sample, static mask.
- :mod:`~rdnet.calib.stats`: event statistics and the discrepancy metric.
- :mod:`~rdnet.calib.effects`: the vocabulary of effects and their ``degrade`` keys.
- :mod:`~rdnet.calib.engine`: simulations (pixel circuit cached, noise and timing composed).
- :mod:`~rdnet.calib.fit`: basic refit, screen, fits, forward selection with held-out scoring.
- :mod:`~rdnet.calib.calibrate`: :func:`calibrate` (the whole diagnosis -> report dict).
- :mod:`~rdnet.calib.report`: report.json / report.md / figures.
- :mod:`~rdnet.calib.consistency`: event-frame consistency.
- :mod:`~rdnet.calib.proof`, :mod:`~rdnet.calib.scene`: concealed-effect proof cases.

report.json schema::

    {"recording": str, "base_config": {"sensor": {...}, "degrade": {...}},
     "fitted_config": {"sensor": {...}, "degrade": {...}},
     "effects": [{"name", "missing", "parameters", "where", "evidence", "confidence", "rank",
                  "heldout_gain", "seed_std", "fitted", "screen_gain", "statistic", "signature",
                  "look_alikes", "caveats"}],
     "discrepancy": {"metric", "fit_before", "fit_after", "heldout_before", "heldout_after", ...},
     "basic_refit": {...}, "refit_caveats": [str], "frame_interpolation": {...},
     "latency_timing": {"recorded_lag_us", "recorded_ci95_us", "ideal_lag_us": {method: us},
                        "latency_range_us", "frame_interval_us", ...},
     "mismatch": {...}, "consistency": {...},
     "setup": {..., "simulations", "search": {"search_pixels", "search_stride", "kernel_runs", ...}}}
"""
import importlib

#: names the package re-exports -> the module that defines them, imported on first use:
#: reading params.yaml imports :mod:`rdnet.calib.settings` (the ``calibrate`` section),
#: which must not pull in the calibration engine and numba (about 0.8 s at every CLI
#: start). The function ``calibrate`` is not among them, since its name is also its module's:
#: ``from rdnet.calib.calibrate import calibrate``.
_LAZY = {"Calibration": "rdnet.calib.calibrate", "finding": "rdnet.calib.calibrate",
         "EFFECTS": "rdnet.calib.effects", "CalibrateConfig": "rdnet.calib.settings"}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
