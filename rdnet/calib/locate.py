"""Locating a sim-to-real mismatch: residuals of the statistics over space, log
intensity, time, polarity and static/moving pixels, in words and numbers."""
from __future__ import annotations

import numpy as np

from rdnet.calib.context import CalibContext
from rdnet.calib.stats import IEI_EDGES


def _ratio(a: float, b: float) -> float:
    return float(a) / float(b) if b > 0 else float("inf") if a > 0 else 1.0


def residuals(sim: dict, real: dict, ctx: CalibContext) -> dict:
    """Where ``sim`` (whole-window statistics) departs from ``real``: a plain dict."""
    floor = 0.05 * max(float(real["rate"]), 1e-6)
    lr = np.log((sim["rate_map"] + floor) / (real["rate_map"] + floor))
    g = ctx.cfg.grid_px * ctx.stride
    worst = np.argsort(-np.abs(lr).ravel())[:3]
    cells = [{"x": int(i % lr.shape[1]) * g, "y": int(i // lr.shape[1]) * g, "size": g,
              "log_ratio_sim_real": float(lr.ravel()[i])} for i in worst]
    e = ctx.intensity_edges
    ir = np.log((sim["rate_vs_intensity"] + floor) / (real["rate_vs_intensity"] + floor))
    bins = [{"log_intensity": [float(e[i]), float(e[i + 1])], "rate_real_hz": float(real["rate_vs_intensity"][i]),
             "rate_sim_hz": float(sim["rate_vs_intensity"][i]), "on_real": float(real["on_vs_intensity"][i]),
             "on_sim": float(sim["on_vs_intensity"][i])} for i in range(len(ir))]
    short = IEI_EDGES <= 3.0                       # intervals below 1 ms (first bins)
    iei_short_real = float(real["iei"][: short.sum()].sum())
    iei_short_sim = float(sim["iei"][: short.sum()].sum())
    from rdnet.calib.stats import xcorr_lag_us
    lag = xcorr_lag_us(sim["rate_time"], real["rate_time"], real["time_mask"],
                       float(ctx.cfg.time_bin_us), float(ctx.cfg.max_lag_us))
    rt_r, rt_s = real["rate_time"], sim["rate_time"]
    k = int(np.argmax(np.abs(rt_s - rt_r)))
    return {
        "rate_real_hz_per_pixel": float(real["rate"]),
        "rate_sim_hz_per_pixel": float(sim["rate"]),
        "worst_cells": cells,
        "intensity_bins": bins,
        "worst_intensity_bin": int(np.argmax(np.abs(ir))),
        "moving_on_fraction": {"real": float(real["on_fraction"]), "sim": float(sim["on_fraction"])},
        "static_pixels": int(ctx.static.sum()),
        "static_rate_hz": {"real": float(real["static_rate"]), "sim": float(sim["static_rate"])},
        "static_on_fraction": {"real": float(real["static_on_fraction"]), "sim": float(sim["static_on_fraction"])},
        "iei_below_1ms": {"real": iei_short_real, "sim": iei_short_sim},
        "net_rate_tail_hz": {"real": [float(v) for v in real["pixel_tail"]], "sim": [float(v) for v in sim["pixel_tail"]]},
        "isolated_rate_tail_hz": {"real": [float(v) for v in real["pixel_isolated"]],
                                  "sim": [float(v) for v in sim["pixel_isolated"]]},
        "lag_us": float(lag),
        "worst_time_us": int(ctx.time_edges[k]),
    }


def where(effect: str, res: dict, ctx: CalibContext, values: dict) -> str:
    """One phrase saying where in the data ``effect`` shows (from :func:`residuals` of
    the simulation *without* the effect against the recording)."""
    if effect in ("shot_noise", "leak_events"):
        s = res["static_rate_hz"]; o = res["static_on_fraction"]
        return (f"static pixels ({res['static_pixels']} of {ctx.n_pixels} sampled): rate {s['real']:.3g} Hz "
                f"real vs {s['sim']:.3g} Hz sim, ON fraction {o['real']:.2f} vs {o['sim']:.2f}")
    if effect == "hot_pixels":
        t, i = res["net_rate_tail_hz"], res["isolated_rate_tail_hz"]
        return (f"pixels that fire alone: the rate above the busiest neighbour (top 0.2 %: {i['real'][-1]:.3g} Hz "
                f"real vs {i['sim'][-1]:.3g} Hz sim) and the net rate |ON - OFF| ({t['real'][-1]:.3g} vs "
                f"{t['sim'][-1]:.3g} Hz), about {values.get('hot_pixel_fraction', 0) * 100:.2g} % of the pixels")
    if effect == "bandwidth":
        b = res["intensity_bins"][res["worst_intensity_bin"]]
        lo, hi = b["log_intensity"]
        return (f"pixels with log intensity in [{lo:.2f}, {hi:.2f}]: rate {b['rate_real_hz']:.3g} Hz real vs "
                f"{b['rate_sim_hz']:.3g} Hz sim (the darkest bins)" if res["worst_intensity_bin"] <= 1 else
                f"log-intensity bin [{lo:.2f}, {hi:.2f}]: rate {b['rate_real_hz']:.3g} Hz real vs {b['rate_sim_hz']:.3g} Hz sim")
    if effect in ("refractory_period", "readout_saturation", "timestamp_jitter"):
        s = res["iei_below_1ms"]
        return (f"short inter-event intervals of a pixel: {s['real'] * 100:.1f} % below 1 ms real vs "
                f"{s['sim'] * 100:.1f} % sim")
    if effect == "latency":
        return f"timing of the whole sensor: real events lag the simulation by {res['lag_us'] / 1000:.2f} ms"
    if effect == "onoff_asymmetry":
        o = res["moving_on_fraction"]
        return f"polarity in moving pixels: ON fraction {o['real']:.3f} real vs {o['sim']:.3f} sim"
    if effect == "threshold_mismatch":
        return "spread of the per-pixel event rates among moving pixels"
    return "whole sensor"
