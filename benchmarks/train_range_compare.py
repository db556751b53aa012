"""The whole study at two training degradation ranges, side by side (issue 11).

``benchmarks/restore_train_range.py`` showed that training stage 1 on a range bracketing the test
range (``randomize.train_scale: [[0.25, 0.9], [1.6, 3.0]]``) fixes the count restorer's shortfall
on the simulated test split. To see what that choice does everywhere else, ``dvc repro`` was run
once with that range (every network retrained, every metric recomputed); its outputs are kept in
``benchmarks/results/train_range_wide/`` (same relative paths as in the project, with the
``params.yaml`` of that run). This script puts them beside the study's current outputs
(``metrics/``, ``results/``: the default range [0.5, 0.9]) on three fronts: the simulated test split
(event-level restoration, deblurring rows), the real recordings (``restore_real``: counts and
where the events are) and the DAVIS346 closed loop.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/train_range_compare.py
        writes benchmarks/results/train_range_compare.md (reads only committed files)

The "default" side is the study as committed when the script runs: the committed
``train_range_compare.md`` sets the wide run beside the study of its own round, and a rerun
after the study has changed (identity pairs, the support rule, ... since) would set it beside
a different study. ``benchmarks/study_warp_compare.py`` reuses its tables.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WIDE = ROOT / "benchmarks" / "results" / "train_range_wide"
RESTORERS = ("restore_events", "restore_image", "rdnet", "degraded", "ednccn", "baf")
ROWS = ("undegraded_train", "degraded_train", "rdnet", "rdnet_signed", "rdnet_dual", "restored")


def _load(root: Path, rel: str) -> dict:
    return json.loads((root / rel).read_text())


def _train_scale(root: Path) -> str:
    import yaml
    return json.dumps(yaml.safe_load((root / "params.yaml").read_text())["randomize"]["train_scale"])


def restoration_table(runs: dict[str, Path]) -> list[str]:
    out = ["| method | " + " | ".join(f"{n}: F1 | {n}: count ratio | {n}: all-voxel L1" for n in runs) + " |",
           "|---|" + "---:|" * (3 * len(runs))]
    data = {n: _load(r, "metrics/restoration.json") for n, r in runs.items()}
    for m in RESTORERS:
        cells = []
        for n in runs:
            e = data[n][m]["events"]
            cells += [f"{e['f1']:.3f}", f"{e['count_ratio']:.2f}", f"{e['voxel_l1_all']:.3f}"]
        out.append(f"| {m} | " + " | ".join(cells) + " |")
    return out


def _mean_std(xs: list[float]) -> str:
    import numpy as np
    a = np.asarray(xs, float)
    return f"{a.mean():.2f} ± {a.std(ddof=1):.2f}" if a.size > 1 else f"{a.mean():.2f}"


def deblur_table(runs: dict[str, Path]) -> list[str]:
    out = ["| row | " + " | ".join(f"{n}: PSNR (dB) | {n}: per seed" for n in runs) + " |",
           "|---|" + "---:|---|" * len(runs)]
    seeds = {n: {row: _load(r, f"results/rows/{row}.json")["psnr_seeds"] for row in ROWS} for n, r in runs.items()}
    for row in ROWS:
        cells = []
        for n in runs:
            s = seeds[n][row]
            cells += [_mean_std(s), " / ".join(f"{x:.2f}" for x in s)]
        out.append(f"| `{row}` | " + " | ".join(cells) + " |")
    cells = []
    for n in runs:
        gap = [a - b for a, b in zip(seeds[n]["rdnet"], seeds[n]["degraded_train"])]
        cells += [_mean_std(gap), " / ".join(f"{x:+.2f}" for x in gap)]
    out.append("| RDNet - row 2 (paired) | " + " | ".join(cells) + " |")
    return out


def real_table(runs: dict[str, Path]) -> list[str]:
    out = ["| recording | method | " + " | ".join(f"{n}: events (of raw) | {n}: activity kept | {n}: background kept"
                                                 for n in runs) + " |",
           "|---|---|" + "---:|" * (3 * len(runs))]
    data = {n: _load(r, "results/restore_real/summary.json")["recordings"] for n, r in runs.items()}
    first = next(iter(data.values()))
    for rec in sorted(first):
        for meth in sorted(m for m in first[rec]["methods"] if m.startswith("rdnet")):
            cells = []
            for n in runs:
                m = data[n][rec]["methods"].get(meth)
                if m is None:
                    cells += ["-"] * 3
                    continue
                cells += [f"{m['events_out']:,} ({100 * m['kept_fraction']:.0f} %)",
                          f"{100 * m['regions']['activity']:.0f} %", f"{100 * m['regions']['background']:.0f} %"]
            out.append(f"| {rec} | {first[rec]['methods'][meth].get('name', meth)} | " + " | ".join(cells) + " |")
    cells = [f"{_load(r, 'results/deblur/davis346/consistency.json')['restored']:.3f}" for r in runs.values()]
    raw = _load(next(iter(runs.values())), "results/deblur/davis346/consistency.json")["raw"]
    out += ["", f"DAVIS346 event-frame consistency R^2 of the restored stream (`rdnet deblur`; raw {raw:.3f}): "
            + ", ".join(f"{n} {c}" for n, c in zip(runs, cells)) + "."]
    return out


def sections(runs: dict[str, Path]) -> list[str]:
    """The three comparison sections (restoration, deblurring, real recordings) of ``runs``."""
    return ["## Simulated test split: event-level restoration (`metrics/restoration.json`)", "",
            *restoration_table(runs), "",
            "## Simulated test split: deblurring, 3 seeds (`results/rows/*.json`)", "",
            *deblur_table(runs), "",
            "## Real recordings, no ground truth (`results/restore_real/summary.json`)", "",
            *real_table(runs), ""]


def write_lines(out: Path, lines: list[str]) -> None:
    """``lines`` to ``out`` (through a temporary file, renamed), and say where."""
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines))
    tmp.replace(out)
    print(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wide", type=Path, default=WIDE, help="outputs of the study run at the other range")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "train_range_compare.md")
    args = ap.parse_args(argv)
    runs = {"default": ROOT, "wide": args.wide}
    lines = ["# The study at two training ranges", "",
             "Generated by `benchmarks/train_range_compare.py` from committed outputs; "
             + ", ".join(f"**{n}**: `randomize.train_scale: {_train_scale(r)}`" for n, r in runs.items())
             + "; the test range ([1.0, 1.5]) and everything else identical.", "",
             *sections(runs)]
    write_lines(args.out, lines)


if __name__ == "__main__":
    main()
