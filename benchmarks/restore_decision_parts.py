"""What each half of the learned restorer's decision does: its deletions of recorded events
and its additions, apart (issue 11).

The count stage 1 decides, voxel by voxel and per polarity, how many events to keep
(``rdnet.nn.decision``). Against the window's input that is two kinds of edit: a voxel that
holds recorded events can lose some or all of them (a deletion), and a voxel can get more
events than it had (an addition). ``rdnet restore`` can apply either half alone:
``restore.add_events: false`` caps each voxel at its input (deletions only, a row of the
``restore_real`` stage), ``restore.delete_events: false`` raises it to its input (additions
only, also a row there), as :func:`rdnet.events.select.capped_entries` and
:func:`~rdnet.events.select.floored_entries` do on the event stream.

This script scores the same split on the simulated data, where the truth is known: for the
study's count restorers (``models/restore_image``, ``models/restore_events``; ``dvc repro``
first), each training seed, on the checkpoint's own validation rows (held-out training
sequences, where the decision was fitted), on the test split (degradations disjoint from
training) and on the same test sequences rendered by the independent circuit generator
(``rdnet.study.independent.circuit_pairs``, one draw, as the ``restoration_circuit`` stage
makes them: events rdnet's simulator did not make), the event metrics of the study (``rdnet.eval.events.match_metrics``: precision,
recall, F1 against the undegraded events; count ratio; the signed all-voxel L1) of

* ``raw``: the degraded input;
* ``decision``: the checkpoint's decision (threshold and support rule), as the study scores it;
* ``deletions only``: ``min(decision, input)`` per voxel;
* ``additions only``: ``max(decision, input)`` per voxel;
* ``keep every input voxel``: a second threshold for the voxels that hold input events, set to
  0 (each keeps ``round(mu)`` >= 1 events), the threshold of the other voxels refitted on the
  validation rows so that the count matches there again (``rdnet.nn.decision.fit_threshold``).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_decision_parts.py       # about 8 minutes

Writes ``benchmarks/results/restore_decision_parts.{json,md}``.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np
import torch

from rdnet.eval.events import match_metrics
from rdnet.nn.decision import decide_counts, fit_threshold, polarity_grid, support_applies
from rdnet.train.checkpoint import load_model, read_checkpoint
from rdnet.train.data import PairsDataset, read_pairs_info
from rdnet.train.loop import predict_counts

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from restore_train_range import write_results  # noqa: E402

log = logging.getLogger("restore_decision_parts")
VARIANTS = ("raw", "decision", "deletions only", "additions only", "keep every input voxel")
METRICS = ("precision", "recall", "f1", "count_ratio", "voxel_l1_all")


def heads(net, pairs: Path, rows: np.ndarray, image: bool):
    """``(mu, prob, target, support, input counts)`` of a loaded restorer on ``rows``."""
    data = PairsDataset(pairs, events="degraded", rows=rows)
    mu, prob, target, support = predict_counts(net, data, torch.device("cpu"), image=image, with_support=True)
    inputs = np.stack([data[i]["counts_degraded"].numpy() for i in range(len(data))])
    return mu, prob, target, support, np.rint(inputs).astype(np.int64)


def keep_inputs(mu, prob, sup, occupied, threshold_out: float) -> np.ndarray:
    """Every voxel with input events kept (``round(mu)`` events), the others where their
    probability reaches ``threshold_out`` (both with the support rule's mask)."""
    keep = occupied | (prob >= np.float32(threshold_out))
    return decide_counts(mu, keep.astype(np.float32), 0.5, sup)


def scores(counts: np.ndarray, target: np.ndarray) -> dict:
    m = match_metrics(polarity_grid(counts), polarity_grid(np.rint(target).astype(np.int64)))
    return {k: float(m[k]) for k in METRICS}


def measure(name: str, seed: int, circuit: Path | None) -> dict:
    """One checkpoint on its validation rows, the test split and (``circuit``: a pairs file)
    the test split rendered by the independent circuit generator."""
    path = ROOT / "models" / name / f"seed{seed}" / "model.pt"
    ck = read_checkpoint(path)
    net = load_model(path)
    dec = ck["extra"]["decision"]
    image = name == "restore_image"
    train, test = ROOT / "data" / "pairs" / "train.h5", ROOT / "data" / "pairs" / "test.h5"
    split = {"validation": (train, np.asarray(ck["extra"]["val_rows"], np.int64)),
             "test": (test, np.arange(read_pairs_info(test).n))}
    if circuit is not None:
        split["test, circuit"] = (circuit, np.arange(read_pairs_info(circuit).n))
    out = {"network": name, "seed": seed, "threshold": float(dec["threshold"])}
    threshold_out = None
    for which in split:                            # validation first: it fits the second threshold
        mu, prob, target, support, inp = heads(net, *split[which], image)
        sup = support if support_applies(dec) else None
        decided = decide_counts(mu, prob, float(dec["threshold"]), sup)
        occupied = inp > 0
        if threshold_out is None:
            kept = int(decide_counts(mu, occupied.astype(np.float32), 0.5, sup).sum())
            rest = int(np.rint(target).sum()) - kept
            other = np.where(occupied, 0.0, prob) * (1.0 if sup is None else np.broadcast_to(sup, prob.shape))
            threshold_out = float(fit_threshold(mu, other, rest)) if rest > 0 else float("inf")
            out["threshold_other_voxels"] = threshold_out
        variants = {"raw": inp, "decision": decided, "deletions only": np.minimum(decided, inp),
                    "additions only": np.maximum(decided, inp),
                    "keep every input voxel": keep_inputs(mu, prob, sup, occupied, threshold_out)}
        out[which] = {k: scores(v, target) for k, v in variants.items()}
        out.setdefault("splits", []).append(which)
        log.info("%s seed %d %s: %s", name, seed, which,
                 {k: round(v["f1"], 4) for k, v in out[which].items()})
    return out


def mean_table(runs: list[dict], which: str) -> list[str]:
    lines = [f"**{which}** (mean over seeds {sorted({r['seed'] for r in runs})}; image-guided / events-only)", "",
             "| variant | precision | recall | F1 | count ratio | all-voxel L1 |", "|---|---|---|---|---|---|"]
    nets = ("restore_image", "restore_events")
    for v in VARIANTS:
        cells = []
        for k in METRICS:
            vals = [np.mean([r[which][v][k] for r in runs if r["network"] == n]) for n in nets]
            fmt = "{:.4f}" if k == "voxel_l1_all" else "{:.3f}"
            cells.append(" / ".join(fmt.format(x) for x in vals))
        lines.append(f"| {v} | " + " | ".join(cells) + " |")
    return lines + [""]


def markdown(res: dict) -> str:
    runs = res["runs"]
    thr = "; ".join(f"{r['network']} seed {r['seed']}: {r['threshold']:.3f} -> {r['threshold_other_voxels']:.3f}"
                    for r in runs)
    return "\n".join([
        "The learned restorer's decision split into its deletions and its additions (`python "
        "benchmarks/restore_decision_parts.py`; the study's count restorers, simulated data (rdnet's simulator; "
        "`test, circuit`: the test sequences rendered by the independent circuit generator), truth = the "
        "undegraded events). `deletions only` = min(decision, input) per voxel (`restore.add_events: false`), "
        "`additions only` = max(decision, input) (`restore.delete_events: false`), `keep every input voxel` = "
        "the voxels with input events all kept, the other voxels' threshold refitted to the validation count.", "",
        *[line for which in runs[0]["splits"] for line in mean_table(runs, which)],
        f"Decision threshold -> threshold of the voxels without input events when every input voxel is kept: {thr}.",
        ""])


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "restore_decision_parts.json")
    ap.add_argument("--no-circuit", action="store_true",
                    help="skip the test split rendered by the independent circuit generator")
    args = ap.parse_args()
    torch.set_num_threads(1)
    import tempfile

    from rdnet.config import load_params
    from rdnet.study.data import sequences
    from rdnet.study.independent import circuit_pairs
    with tempfile.TemporaryDirectory() as tmp:
        circuit = None
        if not args.no_circuit:      # the test sequences rendered by the circuit generator, one draw
            circuit, _ = circuit_pairs(load_params(ROOT / "params.yaml"),
                                       sequences(ROOT / "data" / "events", "test"), Path(tmp), 0)
        runs = [measure(n, s, circuit) for n in ("restore_image", "restore_events") for s in args.seeds]
    write_results(args.out, {"benchmark": "restore_decision_parts", "runs": runs}, markdown)


if __name__ == "__main__":
    main()
