"""Do the study's three training seeds of a restorer, combined, restore better than each
alone? (issue 11: F1, count ratio and all-voxel L1 on the simulated test split; DAVIS346
consistency and the DVXplorer person / background shares on real recordings.)

The seeds of one restorer (``models/restore_image`` or ``models/restore_events``) differ
most on the real recordings (DVXplorer background 17-26 %, DAVIS346 4-13 % of the output
not recorded; ``benchmarks/results/restore_seeds_real.md``). Combining networks is the
standard way to cut that variance without new training. Two forms:

- **average** (:class:`SeedEnsemble`): the members' occupancy probabilities and count heads
  averaged voxel by voxel, and the voxel -> event decision fitted to the average as the
  training fits each member's (:func:`rdnet.train.loop.fit_decision`: the count-ratio-1
  threshold on the held-out training sequences, then the support rule). As a check of that
  path, each member's own decision is refitted the same way and must equal the one stored
  in its checkpoint.
- **vote** (:class:`SeedVote`): each member's stored decision; a voxel is kept where 2 of the
  3 keep it, with the median of their counts.

Scores, for every member (its stored decision), both combinations and, as a control, each
member alone at the vote's count ratio (its threshold fitted on the test split itself, so
favouring the member: what a higher threshold alone gives):

- the study's test split (``data/pairs/test.h5``): precision, recall, F1, count ratio and
  the signed-voxel L1 over all voxels and over event voxels
  (``restore_learned_eval.pair_metrics``);
- the same test sequences rendered by the independent circuit generator (one draw,
  :func:`rdnet.study.independent.circuit_pairs`, as stage ``restoration_circuit`` renders
  them; ``--no-circuit`` leaves it out), with the same metrics;
- real recordings, as ``restore_real`` scores them (``restore_training_scenes.score_real``):
  the image-guided restorer on the DAVIS346, the events-only one on the others.

Each combination costs 3x one restorer's inference (the members run one after another, dense).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_seed_ensemble.py      # about 7 min
        writes benchmarks/results/restore_seed_ensemble.{json,md}
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from restore_learned_eval import pair_metrics  # noqa: E402
from restore_training_scenes import METRICS, restorers_from, score_real  # noqa: E402

log = logging.getLogger("restore_seed_ensemble")

#: restorer -> (models folder, image-guided, the real recordings it restores)
RESTORERS = {"restore_image": ("models/restore_image", True, ("davis346_road",)),
             "restore_events": ("models/restore_events", False,
                                ("dvxplorer_person", "ecd_shapes_subset", "prophesee_evk4_night"))}


class SeedEnsemble(nn.Module):
    """Count-output RestoreNets averaged voxel by voxel: the mean of the members'
    occupancy probabilities (returned as its logit) and of their count heads. Offers the
    interface the decision and inference paths call (``output``, ``image_channels``,
    ``bins``, ``forward(..., return_heads=True)``, ``sparse_heads``); a sparse input is made
    dense first, so every member computes its dense heads."""

    def __init__(self, members):
        super().__init__()
        self.members = nn.ModuleList(members)
        first = members[0]
        if any(m.output != "counts" for m in members):
            raise ValueError("SeedEnsemble averages count-output restorers only")
        self.output, self.image_channels, self.bins = first.output, first.image_channels, first.bins

    def _dense(self, counts):
        from rdnet.nn.sparse import SparseVoxels
        if isinstance(counts, SparseVoxels):
            return counts.dense(next(self.parameters()).device)
        return counts

    def heads(self, image, counts):
        counts = self._dense(counts)
        mus, probs = [], []
        for m in self.members:
            mu, logit = m(image, counts, return_heads=True)
            mus.append(mu.float())
            probs.append(torch.sigmoid(logit.float()))
        p = torch.stack(probs).mean(0).clamp(1e-7, 1 - 1e-7)
        return torch.stack(mus).mean(0), torch.log(p) - torch.log1p(-p)

    def forward(self, image, voxel, return_heads: bool = False):
        mu, logit = self.heads(image, voxel)
        return (mu, logit) if return_heads else torch.sigmoid(logit) * mu

    def sparse_heads(self, image, counts, logit_min: float, pixels=None):
        mu, logit = self.heads(image, counts)
        keep = logit >= logit_min
        if pixels is not None:          # the kept voxels at those pixels, as index arrays
            at = torch.zeros_like(keep)
            y, x = (torch.as_tensor(np.asarray(a, np.int64)) for a in pixels)
            at[0, :, y, x] = True
            keep = tuple(np.nonzero((keep & at).cpu().numpy()))

        def mu_at(b, c, y, x):
            return mu[tuple(torch.as_tensor(np.asarray(a, np.int64), device=mu.device) for a in (b, c, y, x))]
        return keep, mu_at


class SeedVote(SeedEnsemble):
    """The members' own decisions, voted: a voxel is kept where at least ``quorum`` members
    keep it (each with its stored threshold; its support rule, the same for every member,
    is the decision's), with the median of the members' decided counts (0 for a member
    that drops it). Its heads encode that: ``mu`` the median count, the logit +-10 for
    kept / dropped, so any decision threshold in (0, 1) applies the vote."""

    def __init__(self, members, thresholds, quorum: int = 2):
        super().__init__(members)
        from rdnet.nn.decision import logit_threshold
        self.cuts = [logit_threshold(float(t)) for t in thresholds]
        self.quorum = int(quorum)

    def heads(self, image, counts):
        counts = self._dense(counts)
        decided = []
        for m, cut in zip(self.members, self.cuts):
            mu, logit = m(image, counts, return_heads=True)
            decided.append(torch.where(logit >= cut, torch.clamp(mu.float(), min=1.0).round(), 0.0))
        decided = torch.stack(decided)
        keep = (decided > 0).sum(0) >= self.quorum
        return decided.median(0).values, torch.where(keep, 10.0, -10.0)


def members(folder: Path, seeds) -> list[tuple[Path, dict, nn.Module]]:
    from rdnet.train import checkpoint as ckpt_mod
    out = []
    for s in seeds:
        path = folder / f"seed{s}" / "model.pt"
        ck = ckpt_mod.read_checkpoint(path)
        out.append((path, ck, ckpt_mod.model_from_checkpoint(path, ck).eval()))
    return out


def fitted(net, train: Path, val_rows, image: bool) -> dict:
    from rdnet.train.loop import fit_decision
    return fit_decision(net, train, val_rows, torch.device("cpu"), image=image, support_rule=True)


class TestSplit:
    """A test pairs file read once: its undegraded (target) and degraded counts, the raw
    stream's scores, and every network's heads predicted once (:meth:`scorer`)."""

    def __init__(self, pairs: Path):
        from rdnet.train.data import PairsDataset
        self.pairs = pairs
        data = PairsDataset(pairs, crop=None, augment=False)
        try:
            rows = [data[i] for i in range(len(data))]
        finally:
            data.close()
        self.target = np.stack([r["counts_undegraded"].numpy() for r in rows])
        self.degraded = np.stack([r["counts_degraded"].numpy() for r in rows])
        self.raw = pair_metrics(self.degraded, self.target, self.degraded)

    def scorer(self, net):
        """``score(decision, match_ratio=None)``: the event metrics of ``net``'s heads (predicted
        here, once) under ``decision``; with ``match_ratio``, under the threshold at which the
        count ratio on this split comes closest to that value instead (fitted on the split
        itself: a control, not a usable decision)."""
        from rdnet.nn.decision import decide_counts, decision_gain, support_applies
        from rdnet.train.data import PairsDataset
        from rdnet.train.loop import predict_counts
        data = PairsDataset(self.pairs, crop=None, augment=False)
        try:
            out, prob, _, support = predict_counts(net, data, torch.device("cpu"), image=net.image_channels > 0,
                                                   with_support=True)
        finally:
            data.close()

        def score(decision: dict, match_ratio: float | None = None) -> dict:
            sup = support if support_applies(decision) else None

            def at(threshold: float) -> dict:
                restored = decide_counts(out, prob, threshold, sup, decision_gain(decision))
                return {**pair_metrics(restored, self.target, self.degraded), "threshold": threshold}
            if match_ratio is None:
                return at(float(decision["threshold"]))
            lo, hi = 0.0, 1.0                     # the count ratio falls as the threshold rises
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if at(mid)["count_ratio"] > match_ratio else (lo, mid)
            return min((at(lo), at(hi)), key=lambda m: abs(m["count_ratio"] - match_ratio))
        return score


def real_scores(rec: str, params: dict, runs: dict, work: Path) -> dict:
    """``runs``: label -> LearnedRestorer, scored by ``restore_training_scenes.score_real``
    (raw and BAF beside them) with ``load_restorer`` answering each label."""
    from rdnet.restore.real import recordings
    found = dict(recordings([ROOT / "data" / "real", ROOT.parent / "shared" / "real"]))
    if rec not in found:
        log.warning("%s not found: skipped", rec)
        return {}
    spec = {"raw": ("raw", None), "baf": ("baf", None), **{k: ("rdnet", Path(k)) for k in runs}}
    with restorers_from(lambda _: lambda checkpoint, **kw: runs[Path(checkpoint).name]):
        return {"path": str(found[rec].relative_to(ROOT.parent)), **score_real(found[rec], rec, params, spec, work)}


def main() -> None:
    import dataclasses

    from rdnet.config import load_params
    from rdnet.eval.report import write_text_atomic
    from rdnet.restore.learned import prepare_for_inference, restorer_from_checkpoint
    from rdnet.train.data import split_rows

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--train", type=Path, default=ROOT / "data/pairs/train.h5")
    ap.add_argument("--test", type=Path, default=ROOT / "data/pairs/test.h5")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--restorers", nargs="+", default=list(RESTORERS), choices=list(RESTORERS))
    ap.add_argument("--skip-recordings", nargs="*", default=["prophesee_evk4_night"],
                    help="real recordings left out (the 10 s night file takes long with 3 dense members)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/restore_seed_ensemble")
    ap.add_argument("--no-circuit", dest="circuit", action="store_false",
                    help="leave out the test split rendered by the independent circuit generator")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(1)       # as the training (train.threads), so refitted decisions match bit for bit
    params = load_params(args.params)
    _, val_rows = split_rows(args.train, int(params["train"]["val_sequences"]))
    splits = {"test": TestSplit(args.test)}
    circuit_dir = tempfile.TemporaryDirectory()
    if args.circuit:            # the same test sequences rendered by the independent generator
        from rdnet.study.data import sequences
        from rdnet.study.independent import circuit_pairs
        pairs, _ = circuit_pairs(params, sequences(ROOT / "data/events", "test"), Path(circuit_dir.name), seed=0)
        splits["circuit"] = TestSplit(pairs)
    res = {"seeds": args.seeds, "val_rows": int(len(val_rows)), "raw": {k: sp.raw for k, sp in splits.items()},
           "restorers": {}}

    scorers = {}                # id(net) -> its scorer per split: each network predicted once

    def scores(net, decision, match=None):
        per_split = scorers.setdefault(id(net), {k: sp.scorer(net) for k, sp in splits.items()})
        return {k: f(decision, None if match is None else match[k]) for k, f in per_split.items()}
    for name in args.restorers:
        folder, image, recs = RESTORERS[name]
        mem = members(ROOT / folder, args.seeds)
        entry = {"members": {}, "ensemble": {}}
        for (path, ck, net), s in zip(mem, args.seeds):
            stored = ck["extra"]["decision"]
            refit = fitted(net, args.train, val_rows, image)
            same = (refit["threshold"] == stored["threshold"]
                    and (refit.get("support") or {}) == (stored.get("support") or {}))
            if not same:
                raise SystemExit(f"{path}: the refitted decision {refit} differs from the stored {stored}")
            entry["members"][f"seed{s}"] = {"threshold": stored["threshold"], **scores(net, stored)}
            log.info("%s seed %d: %s", name, s, entry["members"][f"seed{s}"]["test"])
        ens = SeedEnsemble([net for _, _, net in mem]).eval()
        decision = fitted(ens, args.train, val_rows, image)
        entry["ensemble"] = {"threshold": decision["threshold"], "decision": decision,
                             **scores(ens, decision)}
        log.info("%s ensemble: %s", name, entry["ensemble"]["test"])
        supports = [ck["extra"]["decision"].get("support") for _, ck, _ in mem]
        if not all(sp and sp.get("drop") for sp in supports):
            raise SystemExit(f"{name}: the vote needs every member to drop unsupported voxels")
        vote = SeedVote([net for _, _, net in mem], [ck["extra"]["decision"]["threshold"] for _, ck, _ in mem]).eval()
        vote_decision = {**mem[0][1]["extra"]["decision"], "threshold": 0.5, "fitted_on": "vote of the members"}
        entry["vote"] = {"threshold": 0.5, **scores(vote, vote_decision)}
        log.info("%s vote: %s", name, entry["vote"]["test"])
        # control: each member alone at the vote's count ratio (its threshold fitted on the test split)
        ratios = {k: entry["vote"][k]["count_ratio"] for k in splits}
        entry["members_at_vote_ratio"] = {f"seed{s}": scores(net, ck["extra"]["decision"], ratios)
                                          for (_, ck, net), s in zip(mem, args.seeds)}
        # real recordings: every member with its own decision, and the ensemble
        runs = {}
        for (path, _, _), s in zip(mem, args.seeds):
            runs[f"seed{s}"] = restorer_from_checkpoint(path, has_frames=image, params=params)
        base = runs[f"seed{args.seeds[0]}"]
        prepare_for_inference(ens, "cpu")
        runs["ensemble"] = dataclasses.replace(base, net=ens, decision=decision, source="seed ensemble")
        prepare_for_inference(vote, "cpu")
        runs["vote"] = dataclasses.replace(base, net=vote, decision=vote_decision, source="seed vote")
        entry["real"] = {}
        with tempfile.TemporaryDirectory() as tmp:
            for rec in recs:
                if rec in args.skip_recordings:
                    continue
                entry["real"][rec] = real_scores(rec, params, runs, Path(tmp))
        res["restorers"][name] = entry
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.out.with_suffix(".json"), json.dumps(res, indent=2, default=float) + "\n")
    write_text_atomic(args.out.with_suffix(".md"), table(res))
    circuit_dir.cleanup()
    print(table(res))


def table(res: dict) -> str:
    lines = [f"# Seed ensemble of the study's restorers (seeds {res['seeds']})", "",
             "Members: each training seed with the decision stored in its checkpoint. Ensemble: the "
             "members' occupancy probabilities and count heads averaged per voxel, its decision fitted "
             f"as training fits each member's ({res['val_rows']} held-out training rows). Vote: the "
             "members' own decisions, a voxel kept where 2 of 3 keep it, with the median of their counts.", ""]
    titles = {"test": "Simulated test split (rdnet's simulator)",
              "circuit": "The same test sequences rendered by the independent circuit generator (one draw)"}
    for name, e in res["restorers"].items():
        lines += [f"## `{name}`"]
        for split, raw in res["raw"].items():
            lines += ["", f"{titles.get(split, split)}:", "",
                      "| run | threshold | " + " | ".join(METRICS) + " |", "|---|---:|" + "---:|" * len(METRICS)]
            rows = {"raw degraded events": {"threshold": float("nan"), split: raw},
                    **e["members"], "mean of the members": None, "ensemble": e["ensemble"], "vote (2 of 3)": e["vote"]}
            rows.update({f"{k} at the vote's count ratio (threshold fitted on this split)": m
                         for k, m in e.get("members_at_vote_ratio", {}).items()})
            for label, r in rows.items():
                if r is None:
                    vals = [np.mean([m[split][k] for m in e["members"].values()]) for k in METRICS]
                    lines.append(f"| {label} | - | " + " | ".join(f"{v:.4f}" for v in vals) + " |")
                    continue
                thr = r[split].get("threshold", r.get("threshold"))
                lines.append(f"| {label} | {thr:.3f} | " + " | ".join(f"{r[split][k]:.4f}" for k in METRICS) + " |")
        for rec, r in e.get("real", {}).items():
            if not r:
                continue
            lines += ["", f"Real recording `{rec}` ({r['events']:,} events):", "",
                      "| run | events out | kept | activity kept | background kept | not recorded | ESR | consistency R^2 |",
                      "|---|---:|---:|---:|---:|---:|---:|---:|"]
            for label, m in r["methods"].items():
                c = "-" if m["consistency_r2"] is None else f"{m['consistency_r2']:.3f}"
                lines.append(f"| {label} | {m['events_out']:,} | {100 * m['kept_fraction']:.1f} % | "
                             f"{100 * m['activity']:.1f} % | {100 * m['background']:.1f} % | "
                             f"{100 * m['not_recorded_fraction']:.1f} % | {m['esr']:.3f} | {c} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
