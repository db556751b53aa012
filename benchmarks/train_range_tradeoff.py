"""The training range's trade-off in one figure (issue 11): what a range buys on the simulated
test split (the count ratio goal, 0.85-1.15) against what it costs on the real recordings,
which none of the ranges was chosen on.

Reads two committed results of the same networks (nothing is run):
``benchmarks/results/restore_train_range_cutoff_scale.json`` (``restore_train_range.py``: the
test split's event metrics per variant, task and seed) and
``benchmarks/results/restore_train_range_cutoff_scale_real.json`` (``restore_seeds_real.py``:
the real recordings scored as ``restore_real`` scores them). One point per variant and seed:

- left: the image-guided restorer's test count ratio against its DAVIS346 event-frame
  consistency (raw's level dashed);
- right: the events-only restorer's test count ratio against the share of the DVXplorer
  take's person it keeps (marker) and of its background (open marker), with the goal's
  limits (person >= 75 %, background <= 15 %).

The goal band of the count ratio is shaded in both.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/train_range_tradeoff.py
        # writes benchmarks/results/restore_train_range_cutoff_scale.png
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
#: issue 11's goal band of the test count ratio, and its DVXplorer limits
RATIO_GOAL = (0.85, 1.15)
PERSON_MIN, BACKGROUND_MAX = 0.75, 0.15


def points(test: dict, real: dict, task: str, recording: str, key: str) -> dict[str, list[tuple[float, float]]]:
    """variant -> [(test count ratio, the real recording's ``key``)] over the seeds both hold."""
    methods = real["recordings"][recording]["methods"]
    out: dict[str, list[tuple[float, float]]] = {}
    for name, v in test["variants"].items():
        for run in v["runs"]:
            score = methods.get(f"{name}/{run['seed']}")
            if run["task"] == task and score is not None and score.get(key) is not None:
                out.setdefault(name, []).append((run["test"]["count_ratio"], score[key]))
    return out


def figure(test: dict, real: dict, out: Path) -> None:
    from rdnet.eval.report import _figure, _save_figure

    fig, (ax1, ax2) = _figure(1, 2, figsize=(11, 5.0))
    names = list(test["variants"])
    colors = {n: f"C{i % 10}" for i, n in enumerate(names)}
    davis = real["recordings"]["davis346_road"]["methods"]
    for name, pts in points(test, real, "restore", "davis346_road", "consistency_r2").items():
        ax1.plot(*zip(*pts), "o", color=colors[name], label=name)
    ax1.axhline(davis["raw"]["consistency_r2"], color="k", ls="--", lw=1)
    ax1.set(xlabel="simulated test split: count ratio (image-guided)", ylabel="DAVIS346 consistency R$^2$",
            title="image-guided restorer")
    person = points(test, real, "restore_events", "dvxplorer_person", "activity")
    background = points(test, real, "restore_events", "dvxplorer_person", "background")
    for name in names:
        if name in person:
            ax2.plot(*zip(*person[name]), "o", color=colors[name], label=name)
        if name in background:
            ax2.plot(*zip(*background[name]), "o", mfc="none", color=colors[name])
    ax2.axhline(PERSON_MIN, color="k", ls="--", lw=1)
    ax2.axhline(BACKGROUND_MAX, color="k", ls=":", lw=1)
    ax2.text(0.99, PERSON_MIN, "person goal >= 75 %", ha="right", va="bottom", fontsize=7, transform=ax2.get_yaxis_transform())
    ax2.text(0.99, BACKGROUND_MAX, "background goal <= 15 %", ha="right", va="bottom", fontsize=7,
             transform=ax2.get_yaxis_transform())
    ax2.set(xlabel="simulated test split: count ratio (events-only)",
            ylabel="DVXplorer kept: person (filled), background (open)",
            title="events-only restorer")
    for ax in (ax1, ax2):
        ax.axvspan(*RATIO_GOAL, color="g", alpha=0.08)
        ax.grid(alpha=0.3)
    ax1.text(0.01, davis["raw"]["consistency_r2"], "raw", ha="left", va="bottom", fontsize=7,
             transform=ax1.get_yaxis_transform())
    handles, labels = ax1.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=7, frameon=False)
    fig.suptitle("Training ranges: the simulated count ratio (goal band shaded) against the real recordings "
                 "(seeds 0 and 1)", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    _save_figure(fig, out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--test", type=Path, default=RESULTS / "restore_train_range_cutoff_scale.json")
    ap.add_argument("--real", type=Path, default=RESULTS / "restore_train_range_cutoff_scale_real.json")
    ap.add_argument("--out", type=Path, default=RESULTS / "restore_train_range_cutoff_scale.png")
    args = ap.parse_args()
    figure(json.loads(args.test.read_text()), json.loads(args.real.read_text()), args.out)


if __name__ == "__main__":
    main()
