"""Where the learned restorers' count ratio is lost (issue 11: test count ratio 0.85-1.15).

For the study's count-output restorers (``models/restore_image`` and ``models/restore_events``,
seed 0; ``dvc repro`` first) on the simulated test split (``data/pairs/test.h5``, degradations
disjoint from training), on the same test sequences rendered by the independent circuit
generator (``rdnet.study.independent.circuit_pairs``, one draw, as the ``restoration_circuit``
stage makes them) and on every 4th row of the training split, it compares

* the occupancy head with the truth: the sum of the occupancy probabilities over the voxels
  against the number of voxels the undegraded events occupy (1 = calibrated);
* the count head with the truth: the mean count ``mu`` on the occupied voxels against the mean
  undegraded count there (the head is trained with an L1 loss, whose optimum is the median);
* the decided events (the checkpoint's fitted threshold and support rule) and the expected count
  ``sum(p * mu)`` against the undegraded count;
* a per-window *expected-count* decision: keep the most probable voxels, in order, until the
  decided count reaches that window's ``sum(p * mu)`` (a rule that needs no fitted threshold),
  its count ratio and F1 (rdnet.eval.events.match_metrics) beside the stored decision's.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_count_head.py     # about 1 minute

Writes ``benchmarks/results/restore_count_head.{json,md}``.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import torch

from rdnet.eval.events import match_metrics
from rdnet.nn.decision import decide_counts, polarity_grid, support_applies
from rdnet.train.checkpoint import load_model, read_checkpoint
from rdnet.train.data import PairsDataset, read_pairs_info
from rdnet.train.loop import predict_counts
from restore_train_range import write_results

ROOT = Path(__file__).resolve().parents[1]


def expected_count_decision(mu: np.ndarray, prob: np.ndarray, support) -> np.ndarray:
    """Per window: the voxels in order of falling probability, each with round(max(mu, 1))
    events (0 where unsupported), kept until the running count reaches sum(p * mu) there."""
    out = np.zeros(mu.shape, np.int64)
    for i in range(mu.shape[0]):
        sup = 1.0 if support is None else np.broadcast_to(support[i], mu[i].shape)
        target = float((prob[i] * mu[i] * sup).sum())
        order = np.argsort(-prob[i].ravel(), kind="stable")
        c = (np.rint(np.maximum(mu[i], 1.0)) * sup).ravel()[order]
        k = int(np.searchsorted(np.cumsum(c), target))
        flat = np.zeros(c.size, np.int64)
        flat[order[:k]] = c[:k].astype(np.int64)
        out[i] = flat.reshape(mu[i].shape)
    return out


def measure(name: str, split: str, pairs: Path, every: int) -> dict:
    path = ROOT / "models" / name / "seed0" / "model.pt"
    dec = read_checkpoint(path)["extra"]["decision"]
    net = load_model(path)
    data = PairsDataset(pairs, events="degraded", rows=np.arange(0, read_pairs_info(pairs).n, every))
    mu, prob, target, support = predict_counts(net, data, torch.device("cpu"), image=name == "restore_image",
                                               with_support=True)
    sup = support if support_applies(dec) else None
    ref = polarity_grid(np.rint(target).astype(np.int64))
    stored = decide_counts(mu, prob, dec["threshold"], sup)
    expected = expected_count_decision(mu, prob, sup)
    occ = target > 0
    total = float(target.sum())
    return {"network": name, "split": split, "rows": int(len(data)), "threshold": float(dec["threshold"]),
            "occupied_voxels": int(occ.sum()), "sum_p_over_occupied": float(prob.sum() / occ.sum()),
            "mean_true_count_occupied": float(target[occ].mean()), "mean_mu_occupied": float(mu[occ].mean()),
            "input_count_ratio": float(sum(data[i]["counts_degraded"].numpy().sum() for i in range(len(data))) / total),
            "expected_count_ratio": float((prob * mu).sum() / total),
            "stored": {"count_ratio": float(stored.sum() / total), "f1": match_metrics(polarity_grid(stored), ref)["f1"]},
            "expected_count_rule": {"count_ratio": float(expected.sum() / total),
                                    "f1": match_metrics(polarity_grid(expected), ref)["f1"]}}


def markdown(rows: list[dict]) -> str:
    lines = ["# Where the restorers' count ratio is lost", "",
             "Seed 0 of the study's count-output restorers; `test`: the simulated test split (all rows), `test, "
             "circuit`: the same sequences rendered by the independent circuit generator (one draw), `train`: "
             "every 4th row of the training split. Occupancy: sum of the occupancy probabilities / voxels the "
             "undegraded events occupy. Count head: mean `mu` / mean undegraded count on those voxels. Ratios: "
             "events / undegraded events. `benchmarks/restore_count_head.py`.", "",
             "| network | split | rows | occupancy sum p / occupied | mean mu / true count (occupied) | input ratio | "
             "sum(p mu) ratio | stored decision: ratio, F1 | expected-count rule: ratio, F1 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['network']} | {r['split']} | {r['rows']} | {r['sum_p_over_occupied']:.3f} | "
                     f"{r['mean_mu_occupied']:.2f} / {r['mean_true_count_occupied']:.2f} | {r['input_count_ratio']:.3f} | "
                     f"{r['expected_count_ratio']:.3f} | {r['stored']['count_ratio']:.3f}, {r['stored']['f1']:.4f} | "
                     f"{r['expected_count_rule']['count_ratio']:.3f}, {r['expected_count_rule']['f1']:.4f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "restore_count_head")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    import tempfile

    from rdnet.config import load_params
    from rdnet.study.data import sequences
    from rdnet.study.independent import circuit_pairs
    params = load_params(ROOT / "params.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        circuit, _ = circuit_pairs(params, sequences(ROOT / "data" / "events", "test"), Path(tmp), 0)
        splits = (("test", ROOT / "data" / "pairs" / "test.h5", 1), ("test, circuit", circuit, 1),
                  ("train", ROOT / "data" / "pairs" / "train.h5", 4))
        rows = [measure(name, split, pairs, every)
                for name in ("restore_image", "restore_events") for split, pairs, every in splits]
    write_results(args.results.with_suffix(".json"), {"rows": rows}, lambda r: markdown(r["rows"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
