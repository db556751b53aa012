"""Which polarity do real hot pixels fire? (issue 12: the hot-pixel models of rdnet and of
the independent circuit generator disagree, and the calibration reports the difference as a
second effect, ON/OFF asymmetry, in the circuit's hot-pixel case ``s1A``.)

rdnet's hot pixels (:mod:`rdnet.sim.effects`) fired Poisson events of one fixed polarity each
(ON or OFF with probability 1/2; now the default of its two polarity keys); the circuit's (:mod:`rdnet.circuit.pixel`) fire periodic ON
events only. This script flags the hot pixels of every real recording with events that
rdnet reads (the hot-pixel pass of ``rdnet restore``: :func:`rdnet.restore.hotpixels.hot_pixels`
with the ``restore`` section's factor and minimum rate) and reports, per recording, the ON
fraction of the hot pixels' events against the other pixels', and per hot pixel its own ON
fraction (how many fire both polarities: an ON fraction between 0.1 and 0.9), and the two
polarity keys of rdnet's hot-pixel model fitted to them (``degrade.hot_pixel_on_fraction`` m,
``degrade.hot_pixel_polarity_concentration`` k: pixel i fires ON with probability
q_i ~ Beta(k m, k (1 - m)); :func:`rdnet.restore.hotpixels.polarity_model`, method of moments,
with 2+ hot pixels; the same numbers ``rdnet restore`` writes to OUT.json's
``hot_pixels.polarity``). Recordings of ../shared/real that are absent are skipped with a note.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/hot_pixel_polarity.py
    # -> benchmarks/results/hot_pixel_polarity.{json,md}
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "real"
RECORDINGS = {"davis346_road": ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4",
              "dvxplorer_person": SHARED / "dvxplorer_person" / "dvxplorer.aedat4",
              "prophesee_evk4_night": SHARED / "prophesee_evk4_night" / "night.raw",
              "prophesee_gen3_sparklers": SHARED / "prophesee_gen3_sparklers" / "sparklers.raw"}


def polarity(path: Path, factor: float, min_hz: float) -> dict:
    from rdnet.events.io.stream import open_events
    from rdnet.restore.hotpixels import hot_pixels, polarity_counts, polarity_model
    with open_events(path) as src:           # the pass of rdnet restore: all and ON counts per pixel
        counts, on_counts, dur = polarity_counts(src.chunks(1_000_000), src.width, src.height)
    hot = hot_pixels(counts, dur, factor, min_hz)
    model = polarity_model(counts, on_counts, hot)
    n, on = counts[hot].astype(np.float64), on_counts[hot].astype(np.float64)
    rest_n, rest_on = counts[~hot].sum(), on_counts[~hot].sum()
    per_pixel = on / np.maximum(n, 1)
    return {"path": str(path.relative_to(ROOT.parent)), "hot_pixels": int(hot.sum()),
            "hot_events": int(n.sum()), "on_fraction_hot": model["on_fraction"],
            "on_fraction_others": float(rest_on / rest_n),
            "per_hot_pixel_on_fraction": sorted(round(float(x), 3) for x in per_pixel),
            "hot_pixels_firing_both": int(((per_pixel > 0.1) & (per_pixel < 0.9)).sum()),
            "model_fit": {k: model[k] for k in ("hot_pixel_on_fraction", "hot_pixel_polarity_concentration")}}


def per_recording(measure) -> tuple:
    """``(restore config, {name: measure(name, path, cfg)}, notes)`` over :data:`RECORDINGS`,
    the absent ones skipped with a note (``cfg``: the ``restore`` section of params.yaml,
    whose hot-pixel factor and minimum rate the restore pass uses)."""
    from rdnet.config import load_params, section
    cfg = section(load_params(ROOT / "params.yaml"), "restore")
    rows, notes = {}, []
    for name, path in RECORDINGS.items():
        if not path.exists():
            notes.append(f"{name}: {path} absent, skipped")
            continue
        rows[name] = measure(name, path, cfg)
        print(name, json.dumps(rows[name]), flush=True)
    return cfg, rows, notes


def main() -> int:
    cfg, rows, notes = per_recording(lambda name, path, c: polarity(path, c.hot_pixel_factor, c.hot_pixel_min_hz))
    out = ROOT / "benchmarks" / "results" / "hot_pixel_polarity"
    out.with_suffix(".json").write_text(json.dumps({
        "benchmark": "hot_pixel_polarity", "hot_pixel_factor": cfg.hot_pixel_factor,
        "hot_pixel_min_hz": cfg.hot_pixel_min_hz, "recordings": rows, "notes": notes}, indent=2) + "\n")
    lines = ["| recording | hot pixels | their events | ON fraction, hot pixels | ON fraction, other pixels "
             "| hot pixels firing both polarities (ON fraction 0.1-0.9) | median per-pixel ON fraction "
             "| fitted on fraction m | fitted concentration k |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, r in rows.items():
        fr = r["per_hot_pixel_on_fraction"]
        hot_on = "-" if r["on_fraction_hot"] is None else f"{r['on_fraction_hot']:.3f}"
        med = f"{np.median(fr):.2f}" if fr else "-"
        m, k = r["model_fit"]["hot_pixel_on_fraction"], r["model_fit"]["hot_pixel_polarity_concentration"]
        fit = "| - | - |" if m is None else f"| {m:.2f} | {k if isinstance(k, str) else f'{k:.2f}'} |"
        lines.append(f"| {name} | {r['hot_pixels']} | {r['hot_events']} | {hot_on} | "
                     f"{r['on_fraction_others']:.3f} | {r['hot_pixels_firing_both']} of {r['hot_pixels']} | {med} {fit}")
    lines += [""] + [f"- {n}" for n in notes]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
