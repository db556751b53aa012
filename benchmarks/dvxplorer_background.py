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
  pixels sit);
* per band, its pixels and events per pixel and second, and the events *in excess of the far
  field's rate* (the band >= 40 px from the mask, taken as the noise floor of a pixel that
  sees no motion): ``events - floor_rate x pixels x seconds``. Background-activity noise
  does not know where the person is, so that excess is an estimate of the signal the mask
  leaves out, which a restorer that keeps signal keeps too; its share of the background is
  the lowest background share such a restorer can reach (an estimate: the floor is assumed
  uniform over the sensor);
* per band, the share of the events ``rdnet restore`` (``--method rdnet``: the study's
  events-only restorer, as ``restore_real`` runs it) writes out, by pixel location (a
  restorer may move or add events, so this is output over input per band).

Writes ``benchmarks/results/dvxplorer_background.{json,md,png}``.

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


def take_without_hot_pixels(recording: Path, cfg):
    """The take as ``restore_real`` scores it: ``(events, hot, act, dist_px, span)`` -- its
    events without the hot pixels the ``restore`` section's hot-pixel pass flags (``cfg``: a
    RestoreConfig), that (H, W) hot-pixel mask, the activity mask of the remaining events
    (:func:`rdnet.eval.noref.activity_mask`), every pixel's distance to it (0 inside) and the
    first and last timestamps of the take as recorded (hot pixels included)."""
    from scipy.ndimage import distance_transform_edt

    from rdnet.eval.noref import ACTIVITY_MASK, activity_mask
    from rdnet.events.core import Events
    from rdnet.events.io.dispatch import load
    from rdnet.restore.hotpixels import hot_pixels, pixel_counts

    ev = load(recording).events
    span = int(ev.t[0]), int(ev.t[-1])
    counts, dur = pixel_counts([ev], ev.width, ev.height)
    hot = hot_pixels(counts, dur, cfg.hot_pixel_factor, cfg.hot_pixel_min_hz)
    ev = Events(ev.array[~hot[ev.y, ev.x]], ev.width, ev.height)
    act = activity_mask(ev, **ACTIVITY_MASK)
    return ev, hot, act, distance_transform_edt(~act), span


def main(argv=None) -> int:
    from rdnet.baselines.baf import baf_mask
    from rdnet.config import load_params, section
    from rdnet.eval.noref import ACTIVITY_MASK as MASK
    from rdnet.events.core import Events
    from rdnet.restore.hotpixels import pixel_counts

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recording", type=Path, default=RECORDING)
    ap.add_argument("--seed", type=int, default=0, help="seed of the shuffled timestamps")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "dvxplorer_background.json")
    ap.add_argument("--no-restorer", action="store_true", help="skip the learned restorer's column")
    args = ap.parse_args(argv)
    cfg = section(load_params(ROOT / "params.yaml"), "restore")

    ev, hot, act, dist_px, (t0, t1) = take_without_hot_pixels(args.recording, cfg)
    W, H = ev.width, ev.height
    bg = ~act[ev.y, ev.x]
    dist = dist_px[ev.y, ev.x]
    kept = baf_mask(ev, cfg.baf_dt_us)
    # the control: background timestamps uniform over the recording, activity events as they are
    arr = ev.array.copy()
    rng = np.random.default_rng(args.seed)
    arr["t"][bg] = rng.integers(t0, t1 + 1, int(bg.sum()))
    order = np.argsort(arr["t"], kind="stable")
    kept_shuffled = np.empty(len(arr), bool)
    kept_shuffled[order] = baf_mask(Events(arr[order], W, H), cfg.baf_dt_us)

    seconds = (t1 - t0) * 1e-6
    out_dist = None
    if not args.no_restorer:
        out_dist = _restored_distances(args.recording, dist_px, hot)
    far_lo = BANDS_PX[-1][0]
    far_pixels = int(((dist_px >= far_lo) & ~act & ~hot).sum())
    floor_hz = float((bg & (dist >= far_lo)).sum() / seconds / max(far_pixels, 1))
    rows = []
    for lo, hi in BANDS_PX + ((0, None),):
        m = bg & (dist >= lo) & ((dist < hi) if hi is not None else True)
        pm = ~act & ~hot & (dist_px >= lo) & ((dist_px < hi) if hi is not None else True)
        pixels = int(pm.sum())
        excess = max(0.0, float(m.sum()) - floor_hz * pixels * seconds)
        row = {"band_px": [lo, hi], "events": int(m.sum()), "share_of_background": float(m.sum() / bg.sum()),
               "pixels": pixels, "rate_hz_per_pixel": float(m.sum() / seconds / max(pixels, 1)),
               "excess_over_floor": excess, "excess_share_of_background": excess / float(bg.sum()),
               "baf_kept": float(kept[m].mean()), "baf_kept_shuffled_times": float(kept_shuffled[m].mean())}
        if out_dist is not None:
            om = (out_dist >= lo) & ((out_dist < hi) if hi is not None else True)
            row["restorer_out_over_in"] = float(om.sum() / max(int(m.sum()), 1))
        rows.append(row)
    busy = pixel_counts([ev], W, H)[0][~act & ~hot]
    result = {"recording": str(args.recording.relative_to(ROOT.parent)), "hot_pixels_removed": int(hot.sum()),
              "activity_mask": MASK, "baf_dt_us": cfg.baf_dt_us, "seconds": seconds,
              "activity_kept_by_baf": float(kept[~bg].mean()),
              "background_pixels": int((~act).sum()), "background_pixels_with_events": int((busy > 0).sum()),
              "background_rate_hz_per_pixel": float(bg.sum() / seconds / max((~act).sum(), 1)),
              "noise_floor_hz_per_pixel": floor_hz, "bands": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    lines = ["# DVXplorer background: what BAF can remove", "",
             f"`{result['recording']}`, {seconds:.2f} s; {result['hot_pixels_removed']} hot pixels removed first; "
             f"BAF dt {cfg.baf_dt_us} us keeps {100 * result['activity_kept_by_baf']:.1f} % of the activity-mask events. "
             f"Background: {result['background_pixels_with_events']} of {result['background_pixels']} pixels have events, "
             f"{result['background_rate_hz_per_pixel']:.2f} Hz per pixel on average.", "",
             f"Noise floor (the band >= {far_lo} px): {floor_hz:.2f} Hz per pixel. Excess = events above that "
             "floor (an estimate of signal outside the mask); restorer = `rdnet restore --method rdnet` "
             "(events-only), its output events over the input events of the band, by pixel.", "",
             "| distance to the activity mask (px) | pixels | events | Hz per pixel | share of background | "
             "excess over the floor (share of background) | BAF keeps | BAF keeps, background times shuffled | "
             "restorer out / in |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lo, hi = r["band_px"]
        band = "all" if (lo, hi) == (0, None) else (f">= {lo}" if hi is None else f"{lo}-{hi}")
        rest = "-" if "restorer_out_over_in" not in r else f"{100 * r['restorer_out_over_in']:.1f} %"
        lines.append(f"| {band} | {r['pixels']:,} | {r['events']:,} | {r['rate_hz_per_pixel']:.2f} | "
                     f"{100 * r['share_of_background']:.1f} % | {r['excess_over_floor']:,.0f} "
                     f"({100 * r['excess_share_of_background']:.1f} %) | "
                     f"{100 * r['baf_kept']:.1f} % | {100 * r['baf_kept_shuffled_times']:.1f} % | {rest} |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    figure(result, args.out.with_suffix(".png"))
    print("\n".join(lines))
    return 0


def figure(result: dict, path: Path) -> Path:
    """Per distance band: the events per pixel and second with the far-field noise floor (left),
    and the share of the band's events BAF, BAF on shuffled times and the restorer keep (right)."""
    from rdnet.eval.report import _figure, _save_figure
    bands = [r for r in result["bands"] if r["band_px"] != [0, None]]
    labels = [f">= {r['band_px'][0]} px" if r["band_px"][1] is None else f"{r['band_px'][0]}-{r['band_px'][1]} px"
              for r in bands]
    x = np.arange(len(bands))
    fig, axes = _figure(1, 2, figsize=(10.0, 3.4))
    ax = axes[0]
    ax.bar(x, [r["rate_hz_per_pixel"] for r in bands], 0.6, color="C0", label="background events")
    ax.axhline(result["noise_floor_hz_per_pixel"], color="k", lw=0.8, ls="--",
               label=f"far-field floor {result['noise_floor_hz_per_pixel']:.2f} Hz")
    ax.set_ylabel("events per pixel and second", fontsize=8)
    ax.set_title("rate by distance to the activity mask", fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1]
    series = [("BAF", "baf_kept", "C1"), ("BAF, times shuffled", "baf_kept_shuffled_times", "C7"),
              ("rdnet restore (learned)", "restorer_out_over_in", "C2")]
    series = [s for s in series if all(s[1] in r for r in bands)]
    w = 0.8 / len(series)
    for i, (name, key, color) in enumerate(series):
        ax.bar(x + (i - len(series) / 2 + 0.5) * w, [100 * r[key] for r in bands], w, label=name, color=color)
    ax.set_ylabel("% of the band's events kept", fontsize=8)
    ax.set_title("what each method keeps (hot pixels removed first)", fontsize=9)
    ax.legend(fontsize=7)
    for a in axes:
        a.set_xticks(x)
        a.set_xticklabels(labels, fontsize=8)
    fig.suptitle("DVXplorer take: the background outside the activity mask", fontsize=9)
    return _save_figure(fig, path)


def _restored_distances(recording: Path, dist_px: np.ndarray, hot: np.ndarray) -> np.ndarray:
    """Distance to the activity mask of every event ``rdnet restore --method rdnet`` writes
    for ``recording`` (in a temporary folder), the hot pixels' events left out as the input's
    are."""
    import subprocess
    import sys
    import tempfile

    from rdnet.events.io.dispatch import load
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "restored.h5"
        subprocess.run([sys.executable, "-m", "rdnet.cli", "restore", str(recording), str(out),
                        "--method", "rdnet"], check=True, cwd=ROOT)
        ev = load(out).events
    keep = ~hot[ev.y, ev.x]
    d = dist_px[ev.y[keep], ev.x[keep]]
    return np.where(d > 0, d, -1.0)          # events inside the mask fall in no band


if __name__ == "__main__":
    raise SystemExit(main())
