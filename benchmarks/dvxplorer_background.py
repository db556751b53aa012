"""What the "background" of the DVXplorer recording is made of (issue 11: background kept
<= 15 % of raw, better than BAF).

``restore_real`` scores a restorer on the DVXplorer take (../shared/real, static camera, a
person moving) by the share of raw events it keeps inside the *activity mask*
(:func:`rdnet.eval.noref.activity_mask`, derived from the raw events) and outside it (the
background). This script asks how much of that background a filter based on space-time
support (BAF, as in jAER and v2e) can remove at all:

* the background's events, after the hot-pixel pass (:mod:`rdnet.restore.hotpixels`, the
  ``restore`` section's settings), binned by their distance to the activity mask;
* per band, the share BAF (``restore.baf_dt_us``) keeps, on the recording as it is, and with
  the background events' timestamps drawn uniformly over the recording (the same pixels and
  counts, no temporal structure: what BAF keeps from noise alone, given where the noisy
  pixels sit).

Writes ``benchmarks/results/dvxplorer_background.{json,md}``.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/dvxplorer_background.py
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RECORDING = ROOT.parent / "shared" / "real" / "dvxplorer_person" / "dvxplorer.aedat4"
BANDS_PX = ((0, 5), (5, 15), (15, 40), (40, None))


def main(argv=None) -> int:
    from scipy.ndimage import distance_transform_edt

    from rdnet.baselines.baf import baf_mask
    from rdnet.config import load_params, section
    from rdnet.eval.noref import ACTIVITY_MASK as MASK
    from rdnet.eval.noref import activity_mask
    from rdnet.events.core import Events
    from rdnet.events.io.dispatch import load
    from rdnet.restore.hotpixels import hot_pixels, pixel_counts

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recording", type=Path, default=RECORDING)
    ap.add_argument("--seed", type=int, default=0, help="seed of the shuffled timestamps")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "dvxplorer_background.json")
    args = ap.parse_args(argv)
    cfg = section(load_params(ROOT / "params.yaml"), "restore")

    ev = load(args.recording).events
    W, H = ev.width, ev.height
    t0, t1 = int(ev.t[0]), int(ev.t[-1])
    counts, dur = pixel_counts([ev], W, H)
    hot = hot_pixels(counts, dur, cfg.hot_pixel_factor, cfg.hot_pixel_min_hz)
    ev = Events(ev.array[~hot[ev.y, ev.x]], W, H)
    act = activity_mask(ev, **MASK)
    bg = ~act[ev.y, ev.x]
    dist = distance_transform_edt(~act)[ev.y, ev.x]
    kept = baf_mask(ev, cfg.baf_dt_us)
    # the control: background timestamps uniform over the recording, activity events as they are
    arr = ev.array.copy()
    rng = np.random.default_rng(args.seed)
    arr["t"][bg] = rng.integers(t0, t1 + 1, int(bg.sum()))
    order = np.argsort(arr["t"], kind="stable")
    kept_shuffled = np.empty(len(arr), bool)
    kept_shuffled[order] = baf_mask(Events(arr[order], W, H), cfg.baf_dt_us)

    seconds = (t1 - t0) * 1e-6
    rows = []
    for lo, hi in BANDS_PX + ((0, None),):
        m = bg & (dist >= lo) & ((dist < hi) if hi is not None else True)
        rows.append({"band_px": [lo, hi], "events": int(m.sum()), "share_of_background": float(m.sum() / bg.sum()),
                     "baf_kept": float(kept[m].mean()), "baf_kept_shuffled_times": float(kept_shuffled[m].mean())})
    busy = counts[~act & ~hot]
    result = {"recording": str(args.recording.relative_to(ROOT.parent)), "hot_pixels_removed": int(hot.sum()),
              "activity_mask": MASK, "baf_dt_us": cfg.baf_dt_us, "seconds": seconds,
              "activity_kept_by_baf": float(kept[~bg].mean()),
              "background_pixels": int((~act).sum()), "background_pixels_with_events": int((busy > 0).sum()),
              "background_rate_hz_per_pixel": float(bg.sum() / seconds / max((~act).sum(), 1)),
              "bands": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    lines = ["# DVXplorer background: what BAF can remove", "",
             f"`{result['recording']}`, {seconds:.2f} s; {result['hot_pixels_removed']} hot pixels removed first; "
             f"BAF dt {cfg.baf_dt_us} us keeps {100 * result['activity_kept_by_baf']:.1f} % of the activity-mask events. "
             f"Background: {result['background_pixels_with_events']} of {result['background_pixels']} pixels have events, "
             f"{result['background_rate_hz_per_pixel']:.2f} Hz per pixel on average.", "",
             "| distance to the activity mask (px) | events | share of background | BAF keeps | "
             "BAF keeps, background times shuffled |", "|---|---|---|---|---|"]
    for r in rows:
        lo, hi = r["band_px"]
        band = "all" if (lo, hi) == (0, None) else (f">= {lo}" if hi is None else f"{lo}-{hi}")
        lines.append(f"| {band} | {r['events']:,} | {100 * r['share_of_background']:.1f} % | "
                     f"{100 * r['baf_kept']:.1f} % | {100 * r['baf_kept_shuffled_times']:.1f} % |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
