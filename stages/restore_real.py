"""Stage `restore_real`: every restore method (raw, baf, stcf, gef where the recording has
frames, rdnet when the learned restorer is installed, ednccn when models/ednccn is trained)
over the real recordings of data/real and those of --shared that rdnet can read (others
are skipped with a warning), scored without ground truth (params: restore, sensor).

Per recording and method: events kept, ESR (E-MLB), event-frame consistency (with
frames), and region fractions -- the share of the raw events kept inside the *activity
mask* (where the scene moves), outside it (background activity), and on the known hot
pixels (HOT_PIXELS below, from ../shared/real/README.md). The activity mask is derived
from each recording's raw events by one fixed rule, the same for every recording
(rdnet.eval.noref.activity_mask): the per-pixel event count, 3 x 3 median-filtered (lone hot
pixels vanish), Gaussian-smoothed with sigma 4 px, above 0.25 x its 99.9th percentile. Writes OUT/summary.json, OUT/summary.md
and OUT/<recording>.png (raw vs restored event images); the restored .h5/.json files go
to --data-out.
"""
from pathlib import Path

import _common
from rdnet.eval.noref import ACTIVITY_MASK as MASK  # after _common: it puts the repo on sys.path

#: (x, y) hot pixels listed in ../shared/real/README.md, per recording folder name.
HOT_PIXELS = {"dvxplorer_person": [(187, 105), (204, 157), (241, 196), (307, 97)]}
#: (width, height) of recordings whose format does not store it (README: DAVIS240C).
SENSOR_SIZE = {"ecd_shapes_subset": (240, 180)}
SKIP = {".md", ".png", ".jpg", ".json", ".yaml", ".dvc"}
METHODS = ("raw", "baf", "stcf", "gef", "rdnet", "ednccn")
#: Extra rows on the recordings with known hot pixels (HOT_PIXELS): (key, method, restore
#: overrides, label suffix). The learned restorer without the hot-pixel pass shows what the
#: network removes by itself.
VARIANTS = (("rdnet_no_hot_pass", "rdnet", {"hot_pixel_factor": 0}, " (no hot-pixel pass)"),)


def recordings(roots):
    """(name, path) of candidate recordings: one per folder name, first root first."""
    seen, out = set(), []
    for root in roots:
        if root is None or not root.is_dir():
            continue
        for d in sorted(p for p in root.iterdir() if p.is_dir()):
            files = sorted(f for f in d.iterdir() if f.is_file() and f.suffix.lower() not in SKIP)
            if files and d.name not in seen:
                seen.add(d.name)
                out.append((d.name, files[0]))
    return out


def score_recording(name, path, params, data_out, log):
    import json

    from rdnet.errors import ModelNotFoundError
    from rdnet.eval.noref import activity_mask, mask_fractions, pixel_mask
    from rdnet.events.io import load
    from rdnet.restore.run import restore_recording

    size = SENSOR_SIZE.get(name)
    rec = load(path, sensor_size=size)
    raw = rec.require_events(str(path))
    masks = {}
    act = activity_mask(raw, **MASK)
    masks["activity"], masks["background"] = act, ~act
    hot = HOT_PIXELS.get(name)
    if hot:
        masks["hot_pixels"] = pixel_mask(rec.width, rec.height, hot)
    entry = {"path": str(path), "width": rec.width, "height": rec.height,
             "has_frames": rec.frames is not None and len(rec.frames) > 0, "events": len(raw),
             "duration_us": int(raw.t[-1] - raw.t[0]), "activity_mask_pixels": int(act.sum()),
             "activity_mask": dict(MASK), "hot_pixels": hot or [], "methods": {}}
    outs = {}
    runs = [(m, m, {}, "") for m in METHODS] + (list(VARIANTS) if hot else [])
    for key, method, overrides, suffix in runs:
        if method == "gef" and not entry["has_frames"]:
            continue
        out = data_out / name / f"{key}.h5"
        out.parent.mkdir(parents=True, exist_ok=True)
        run_params = {**params, "restore": {**params.get("restore", {}), **overrides}}
        try:
            res = restore_recording(path, out, run_params, method=method, progress=False, sensor_size=size)
        except ModelNotFoundError as e:               # a broken model fails the stage; an absent one
            log.warning("%s: method %s skipped: %s", name, key, e)   # only loses its row
            continue
        restored = load(out).events
        outs[key] = restored
        cons = res["scores"]["consistency"] or {}
        entry["methods"][key] = {
            "name": res["method"] + suffix, "events_out": res["events_out"], "kept_fraction": res["kept_fraction"],
            "hot_pixels_flagged": (res["hot_pixels"] or {}).get("count", 0),
            "esr": res["scores"]["esr"]["restored"],
            "consistency_r2": (cons.get("restored") or {}).get("r2_fitted"),
            "regions": {k: v["fraction"] for k, v in mask_fractions(raw, restored, masks).items()}}
        # (speed is not recorded here, so the committed summary is reproducible: bench_restore.py)
        (data_out / name / f"{key}.summary.json").write_text(json.dumps(res, indent=2) + "\n")
    return entry, rec, raw, outs, act


def figure(path, name, raw, outs, act):
    from rdnet.eval.report import _figure, _save_figure, event_image
    from rdnet.eval.events import polarity_counts
    t_mid = int(raw.t[len(raw) // 2])
    t0, dur = t_mid - 16_500, 33_000
    cols = list(outs)
    fig, axes = _figure(1, len(cols) + 1, figsize=(3.2 * (len(cols) + 1), 3.0))
    for ax, m in zip(axes, cols):
        c = polarity_counts(outs[m], 1, t0, dur)
        ax.imshow(event_image(c[1] - c[0], scale=2.0))
        ax.set_title(f"{m}: {len(outs[m].slice_time(t0, t0 + dur))} ev", fontsize=8)
    axes[-1].imshow(act, cmap="gray")
    axes[-1].set_title("activity mask (from raw)", fontsize=8)
    for ax in axes:
        ax.set_xticks([]); ax.set_yticks([])
    fig.suptitle(f"{name}: 33 ms around t = {(t_mid - int(raw.t[0])) / 1e6:.3f} s from the first event "
                 "(red ON, blue OFF)", fontsize=9)
    return _save_figure(fig, path)


def table(summary):
    lines = ["| recording | method | events out | kept | ESR | consistency R^2 | activity kept | "
             "background kept | hot pixels kept | hot pixels flagged |", "|---|---|---|---|---|---|---|---|---|---|"]

    def f(v, pct=False):
        if v is None or v != v:
            return "-"
        return f"{100 * v:.1f} %" if pct else f"{v:.3f}"
    for name, e in summary["recordings"].items():
        for m, r in e["methods"].items():
            rg = r["regions"]
            lines.append(f"| {name} | {r['name']} | {r['events_out']:,} | {f(r['kept_fraction'], True)} | "
                         f"{f(r['esr'])} | {f(r['consistency_r2'])} | {f(rg.get('activity'), True)} | "
                         f"{f(rg.get('background'), True)} | {f(rg.get('hot_pixels'), True)} | "
                         f"{r.get('hot_pixels_flagged', 0)} |")
    return "\n".join(lines) + "\n"


def main(args, params):
    import logging

    from rdnet.errors import FormatError
    from rdnet.eval.report import write_text_atomic
    from rdnet.events.io import format_of
    log = logging.getLogger("restore_real")
    summary = {"recordings": {}, "skipped": {}, "activity_mask": dict(MASK),
               "note": "fractions are of the raw events inside each mask; activity mask derived from raw events"}
    for name, path in recordings([args.data, args.shared]):
        try:
            format_of(path)
        except FormatError as e:
            log.warning("skipping %s: %s", path, e)
            summary["skipped"][name] = str(e)
            continue
        if args.only and name not in args.only:
            continue
        log.info("restoring %s (%s)", name, path)
        entry, rec, raw, outs, act = score_recording(name, path, params, args.data_out, log)
        summary["recordings"][name] = entry
        figure(args.out / f"{name}.png", name, raw, outs, act)
    _common.write_json(args.out / "summary.json", summary)
    write_text_atomic(args.out / "summary.md", table(summary))


p = _common.parser(__doc__)
p.add_argument("--data", type=Path, default=Path("data/real"))
p.add_argument("--shared", type=Path, default=Path("../shared/real"),
               help="more real recordings when present (not shipped: copyleft)")
p.add_argument("--out", type=Path, default=Path("results/restore_real"))
p.add_argument("--data-out", type=Path, default=Path("data/restore_real"))
p.add_argument("--only", nargs="*", default=None, help="restrict to these recording folder names")
_common.run(main, p)
