"""Stage `restore_real`: every restore method (raw, baf, stcf, gef where the recording has
frames, rdnet when the learned restorer is installed, ednccn when models/ednccn is trained,
rdnet_frames -- the frame-pair restorer of models/restore_frames -- where it has frames)
over the real recordings of data/real and those of --shared that rdnet can read (others
are skipped with a warning), scored without ground truth (params: restore, sensor).

Per recording and method: events kept, the share of the output that is not in the
recording (added or moved events; 0 for a filter), ESR (E-MLB), event-frame consistency (with
frames), and region fractions -- the share of the raw events kept inside the *activity
mask* (where the scene moves), outside it (background activity), and on the known hot
pixels (--facts, stages/real_recordings.yaml, from ../shared/real/README.md). The activity mask is derived
from each recording's raw events by one fixed rule, the same for every recording
(rdnet.eval.noref.activity_mask): the per-pixel event count, 3 x 3 median-filtered (lone hot
pixels vanish), Gaussian-smoothed with sigma 4 px, above 0.25 x its 99.9th percentile. Writes OUT/summary.json, OUT/summary.md
and OUT/<recording>.png (raw vs restored event images); the restored .h5/.json files go
to --data-out.
"""
from pathlib import Path

import _common
from rdnet.eval.noref import ACTIVITY_MASK as MASK  # after _common: it puts the repo on sys.path
from rdnet.restore.real import Run, read_facts, recordings, score_recording

METHODS = ("raw", "baf", "stcf", "gef", "rdnet", "ednccn")
#: Extra rows on the recordings with known hot pixels (--facts): the
#: learned restorer without the hot-pixel pass shows what the network removes by itself.
VARIANTS = (Run("rdnet_no_hot_pass", "rdnet", restore={"hot_pixel_factor": 0}, suffix=" (no hot-pixel pass)"),)
#: An extra row on every recording: the learned restorer that only deletes (each voxel capped at
#: its input events, restore.add_events: false), the same network and decision.
DELETIONS_ONLY = Run("rdnet_deletions_only", "rdnet", restore={"add_events": False}, suffix=" (deletions only)")
#: And its counterpart that only adds (each voxel raised to its input events, every recorded
#: event kept, restore.delete_events: false): the two rows split the learned restorer's effect.
ADDITIONS_ONLY = Run("rdnet_additions_only", "rdnet", restore={"delete_events": False}, suffix=" (additions only)")
#: On the recordings with frames: the restorer guided by the two frames that bracket each
#: window, as a user picks it (restore.guide: frame_pair: the study's models/restore_frames,
#: its lowest seed; windows from frame to frame).
FRAME_PAIRS = Run("rdnet_frames", "rdnet", restore={"guide": "frame_pair"}, needs_frames=True)


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
    lines = ["| recording | method | events out | kept | not in the recording | ESR | consistency R^2 | "
             "activity kept | background kept | hot pixels kept | hot pixels flagged |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]

    def f(v, pct=False):
        if v is None or v != v:
            return "-"
        return f"{100 * v:.1f} %" if pct else f"{v:.3f}"
    for name, e in summary["recordings"].items():
        for m, r in e["methods"].items():
            rg = r["regions"]
            lines.append(f"| {name} | {r['name']} | {r['events_out']:,} | {f(r['kept_fraction'], True)} | "
                         f"{f(r.get('not_recorded_fraction'), True)} | {f(r['esr'])} | {f(r['consistency_r2'])} | {f(rg.get('activity'), True)} | "
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
    facts = read_facts(args.facts)
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
        runs = ([Run(m, m) for m in METHODS] + [DELETIONS_ONLY, ADDITIONS_ONLY, FRAME_PAIRS]
                + (list(VARIANTS) if name in facts.hot_pixels else []))
        sc = score_recording(name, path, params, runs, args.data_out / name, facts=facts)
        summary["recordings"][name] = sc.entry
        figure(args.out / f"{name}.png", name, sc.raw, sc.outs, sc.activity)
    _common.write_json(args.out / "summary.json", summary)
    write_text_atomic(args.out / "summary.md", table(summary))


p = _common.parser(__doc__)
p.add_argument("--data", type=Path, default=Path("data/real"))
p.add_argument("--shared", type=Path, default=Path("../shared/real"),
               help="more real recordings when present (not shipped: copyleft)")
p.add_argument("--facts", type=Path, default=Path("stages/real_recordings.yaml"),
               help="known hot pixels and sensor sizes of the recordings (rdnet.restore.real.read_facts)")
p.add_argument("--out", type=Path, default=Path("results/restore_real"))
p.add_argument("--data-out", type=Path, default=Path("data/restore_real"))
p.add_argument("--only", nargs="*", default=None, help="restrict to these recording folder names")
_common.run(main, p)
