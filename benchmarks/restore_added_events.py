"""Where the learned restorers add events on the real recordings: the output events of
``restore_real``'s ``rdnet`` runs that are not recorded events (time, pixel and polarity;
the ``events_not_recorded`` of ``rdnet restore``), by region (inside the activity mask of
:func:`rdnet.eval.noref.activity_mask`, the mask ``restore_real`` scores with), by whether
their pixel recorded any event, and by polarity against the recording's ON share.

Reads ``data/restore_real/<recording>/{raw,rdnet}.h5`` (``dvc repro restore_real``); writes
``benchmarks/results/restore_added_events.{json,md}``. A few seconds.

    .venv/bin/python benchmarks/restore_added_events.py
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rdnet.events.io import load
from rdnet.events.select import event_keys
from rdnet.eval.noref import activity_mask

ROOT = Path(__file__).resolve().parents[1]


def added_events(folder: Path) -> dict:
    raw, out = load(folder / "raw.h5").events, load(folder / "rdnet.h5").events
    act = activity_mask(raw)
    new = ~np.isin(event_keys(out), event_keys(raw))
    a = out.array[new]
    recorded = np.zeros((raw.height, raw.width), bool)
    recorded[raw.y, raw.x] = True
    share = (lambda m: float(m.mean()) if m.size else None)  # noqa: E731
    return {"events_out": len(out), "added": int(new.sum()), "added_share": share(new),
            "mask_pixel_share": float(act.mean()), "added_in_mask": share(act[a["y"], a["x"]]),
            "added_at_silent_pixels": share(~recorded[a["y"], a["x"]]),
            "added_on_share": share(a["p"].astype(bool)), "raw_on_share": float(raw.p.mean())}


def main() -> int:
    root = ROOT / "data" / "restore_real"
    res = {d.name: added_events(d) for d in sorted(root.iterdir()) if (d / "rdnet.h5").exists()}
    out = ROOT / "benchmarks" / "results" / "restore_added_events.json"
    out.write_text(json.dumps(res, indent=1) + "\n")
    pct = (lambda v: "-" if v is None else f"{100 * v:.1f} %")  # noqa: E731
    lines = ["# Where the learned restorers add events (`restore_real`'s rdnet runs)", "",
             "`benchmarks/restore_added_events.py`: output events that are not recorded events, by region "
             "(the activity mask `restore_real` scores with), by whether their pixel recorded anything, and "
             "by polarity.", "",
             "| recording | events out | added | added inside the activity mask | mask's share of the pixels "
             "| added at pixels that recorded nothing | ON share: added / recorded |",
             "|---|---|---|---|---|---|---|"]
    for name, r in res.items():
        lines.append(f"| {name} | {r['events_out']:,} | {r['added']:,} ({pct(r['added_share'])}) | "
                     f"{pct(r['added_in_mask'])} | {pct(r['mask_pixel_share'])} | {pct(r['added_at_silent_pixels'])} | "
                     f"{pct(r['added_on_share'])} / {pct(r['raw_on_share'])} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
