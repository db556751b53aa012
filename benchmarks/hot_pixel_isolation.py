"""Does a pixel's count above its busiest neighbour find real hot pixels, whatever their
polarity? (issue 12: the check on recordings rdnet did not generate behind hot pixels' own
statistic ``pixel_isolated`` and the calibration's hot-pixel mask, both built on
:func:`rdnet.calib.stats.isolated_counts`.)

The calibration ranks pixels by that excess; before session 33 it ranked them by the net
count |ON - OFF|. On every real recording with events that rdnet reads, per pixel grid (every
pixel, and every 2nd row and column as the calibration samples DAVIS346), this ranks the
pixels by three statistics (isolated count, net count, total count) and scores each against
two references:

* the hot pixels the recording's own README names (DVXplorer: (187,105), (204,157),
  (241,196), (307,97); written by whoever packaged the data, not by rdnet): their rank;
* the pixels the hot-pixel pass of ``rdnet restore`` flags
  (:func:`rdnet.restore.hotpixels.hot_pixels`, count > ``factor`` x the neighbours' median,
  the ``restore`` section's factor and minimum rate): recall among the top K, K = the number
  flagged on that grid. This reference also compares a pixel with its neighbours, so it is
  not independent of the isolated count; it is independent of polarity.

and reports the median share of a flagged pixel's count that each statistic keeps (the net
count keeps |2 q - 1| of a pixel firing ON with probability q).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/hot_pixel_isolation.py
    # -> benchmarks/results/hot_pixel_isolation.{json,md}
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from hot_pixel_polarity import per_recording  # noqa: E402

#: hot pixels named by ../shared/real/README.md, (x, y)
README_HOT = {"dvxplorer_person": ((187, 105), (204, 157), (241, 196), (307, 97))}
STRIDES = (1, 2)


def _ranks(score: np.ndarray, pixels) -> list[int]:
    """1-based rank of each (x, y) of ``pixels`` among all pixels by ``score`` (descending;
    ties share the best rank)."""
    flat = np.sort(score.ravel())[::-1]
    return [int(np.searchsorted(-flat, -score[y, x], side="left")) + 1 for x, y in pixels]


def measure(path: Path, name: str, factor: float, min_hz: float) -> dict:
    from rdnet.calib.stats import isolated_counts
    from rdnet.events.io.stream import open_events
    from rdnet.restore.hotpixels import hot_pixels, polarity_counts
    with open_events(path) as src:
        counts, on_counts, dur = polarity_counts(src.chunks(1_000_000), src.width, src.height)
    flagged = hot_pixels(counts, dur, factor, min_hz)
    out = {"path": str(path.relative_to(ROOT.parent)), "flagged": int(flagged.sum()), "grids": {}}
    for s in STRIDES:
        n, on, hot = counts[::s, ::s], on_counts[::s, ::s], flagged[::s, ::s]
        stats = {"isolated": isolated_counts(n), "net": np.abs(2 * on - n), "total": n}
        k = int(hot.sum())
        row = {"pixels": int(n.size), "flagged_on_grid": k, "by": {}}
        for label, score in stats.items():
            top = np.zeros(n.size, bool)
            if k:
                top[np.argsort(-score.ravel(), kind="stable")[:k]] = True
            r = {"recall_of_flagged_in_top_k": float((top & hot.ravel()).sum() / k) if k else None,
                 "median_share_of_flagged_count_kept": (float(np.median(score[hot] / np.maximum(n[hot], 1)))
                                                        if k else None)}
            named = [(x // s, y // s) for x, y in README_HOT.get(name, ()) if x % s == 0 and y % s == 0]
            if named:
                r["readme_hot_pixels_on_grid"] = named
                r["their_ranks"] = _ranks(score, named)
            row["by"][label] = r
        out["grids"][f"stride {s}"] = row
    return out


def main() -> int:
    from rdnet.calib.report import write_json
    from rdnet.eval.report import write_text_atomic
    cfg, rows, notes = per_recording(lambda name, path, c: measure(path, name, c.hot_pixel_factor,
                                                                   c.hot_pixel_min_hz))
    out = ROOT / "benchmarks" / "results" / "hot_pixel_isolation"
    write_json(out.with_suffix(".json"), {"benchmark": "hot_pixel_isolation", "hot_pixel_factor": cfg.hot_pixel_factor,
                                          "hot_pixel_min_hz": cfg.hot_pixel_min_hz, "recordings": rows, "notes": notes})
    lines = ["Real hot pixels ranked by three per-pixel statistics (`benchmarks/hot_pixel_isolation.py`; "
             "definitions in its docstring): recall of the pixels the restore pass flags among the top K "
             "(K = flagged on the grid), the median share of a flagged pixel's count the statistic keeps, "
             "and the ranks of the hot pixels the recording's README names.", "",
             "| recording | grid | flagged | statistic | recall in top K | share of count kept | README hot pixels: ranks |",
             "|---|---|---:|---|---:|---:|---|"]
    for name, r in rows.items():
        for grid, g in r["grids"].items():
            for label, b in g["by"].items():
                rec = "-" if b["recall_of_flagged_in_top_k"] is None else f"{b['recall_of_flagged_in_top_k']:.2f}"
                share = ("-" if b["median_share_of_flagged_count_kept"] is None
                         else f"{b['median_share_of_flagged_count_kept']:.2f}")
                ranks = ", ".join(str(x) for x in b.get("their_ranks", [])) or "-"
                lines.append(f"| {name} | {grid} ({g['pixels']} px) | {g['flagged_on_grid']} | {label} | {rec} | "
                             f"{share} | {ranks} |")
    lines += [""] + [f"- {n}" for n in notes]
    write_text_atomic(out.with_suffix(".md"), "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
