"""Where on DAVIS346 does the learned restorer delete events, and which of its deletions cost
the event-frame consistency? (issue 11, goal "DAVIS346 consistency at least raw")

The restorer keeps 97 % of the recording's events and scores 0.325 against raw's 0.348; its
deletions alone score 0.332, and BAF, deleting as many, 0.339 (``restore_operating_curves``).
This script splits the deletions by the brightness of the scene where they happen: each
recorded event gets the intensity of its pixel in the nearest APS frame (``frames.grey()``,
linear, 0-1), and the events are cut into quintiles of that intensity. Per quintile it reports
the share of the events deleted by

- the restorer as ``rdnet restore`` runs it (the guiding image: the nearest frame),
- the same restorer reading a flat image (the nearest frame's mean everywhere; as in
  ``restore_window_image``), which says how much of the pattern the image drives,
- BAF (10 ms, ``restore.baf_dt_us``),

and the event-frame consistency (``rdnet.deblur.consistency``, each stream scored against the
raw one as ``rdnet restore`` scores it) of the restored stream with its deletions in the dark
part (the darkest ``--dark-quantile`` of the events) undone, and with its other deletions
undone. A deletion is a recorded event missing from the output (the restorer keeps the
recorded timestamps, ``restore.event_times: input``).

``--checkpoints`` restores with the given image-guided checkpoints (one row each; ``default``,
the default: the restorer ``rdnet restore`` finds, the study's seed 0 or the packaged one).
``--variants NAME=JSON ...`` also trains the image-guided stage 1 (seed 0, study settings) on
training pairs simulated with those ``degrade`` overrides (``restore_training_scenes``'s
pipeline; ``study={}`` reproduces the study's seed 0 bit for bit) and adds a row for each, to
test whether a brightness-dependent part of the training degradation (shot noise 4x denser in
the dark, ``degrade.shot_noise_bright_factor``; the bandwidth limit, slower in the dark) taught
the dark deletions; ``--work DIR`` keeps and reuses their pairs and networks. For each variant
it also reports what its training pairs teach about dark events: the share of the degraded
events lying in voxels that hold no undegraded event, by grey level; and the same for the
study's test pairs and for the same test sequences rendered by the independent circuit
generator (``--no-independent`` skips it), so that the statistic is not rdnet's model alone.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_dark_deletions.py        # about 1 min
        writes benchmarks/results/restore_dark_deletions.{json,md}
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from restore_training_scenes import restorers_from  # noqa: E402
from restore_window_image import WindowImages, restorer_with  # noqa: E402

log = logging.getLogger("restore_dark_deletions")
QUINTILES = 5


def frame_intensity(rec) -> np.ndarray:
    """Per recorded event: the linear grey level of its pixel in the frame nearest in time."""
    e, ft = rec.events.array, np.asarray(rec.frames.t_us, np.int64)
    i = np.clip(np.searchsorted(ft, e["t"]), 0, len(ft) - 1)
    prev = np.clip(i - 1, 0, len(ft) - 1)
    near = np.where(np.abs(ft[prev] - e["t"]) < np.abs(ft[i] - e["t"]), prev, i)
    return rec.frames.grey()[near, e["y"], e["x"]].astype(np.float64)


def quintiles(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(edges, band)``: the quintile edges of ``values`` and each value's quintile (0-4)."""
    edges = np.quantile(values, np.linspace(0, 1, QUINTILES + 1))
    return edges, np.clip(np.searchsorted(edges, values, side="right") - 1, 0, QUINTILES - 1)


def restore(rec_path: Path, rec, params: dict, checkpoint: Path | None, image: str | None, out: Path):
    """``rdnet restore``'s learned restoration of ``rec_path`` (loaded: ``rec``) into ``out``:
    ``(restored Events, deleted)``, ``deleted`` the recorded events missing from the output.
    ``image`` ``flat`` hands the network a flat image instead of the nearest frame."""
    from rdnet.events.io import load
    from rdnet.events.select import event_keys
    from rdnet.restore.run import restore_recording
    if image is None:
        restore_recording(rec_path, out, params, method="rdnet", checkpoint=checkpoint, progress=False)
    else:
        images = WindowImages(rec.frames.grey(), rec.frames.t_us, image)
        with restorers_from(lambda ld: lambda ck, **kw: restorer_with(ld(ck, **kw), images)):
            restore_recording(rec_path, out, params, method="rdnet", checkpoint=checkpoint, progress=False)
    restored = load(out).events
    return restored, ~np.isin(event_keys(rec.events), event_keys(restored))


def unsupported_by_intensity(pairs: Path) -> dict:
    """What the training pairs teach about dark events: the share of the degraded events that
    lie in a voxel (bin, pixel, polarity) holding no undegraded event, overall and per quintile
    of the blurry image's grey level at their pixel (noise, and events moved to another bin)."""
    import h5py
    with h5py.File(pairs, "r") as f:
        img = f["blurry"][:, 0]
        deg = np.stack([f["voxel_degraded_on"][:], f["voxel_degraded_off"][:]], 1)      # N, 2, B, H, W
        und = np.stack([f["voxel_undegraded_on"][:], f["voxel_undegraded_off"][:]], 1)
    sel = deg > 0
    n = deg[sel].astype(np.int64)
    grey = np.repeat(np.broadcast_to(img[:, None, None], deg.shape)[sel], n)
    unsupported = np.repeat((und == 0)[sel], n)
    edges, band = quintiles(grey)
    return {"degraded_events": int(n.sum()), "unsupported": float(unsupported.mean()),
            "grey_quintile_edges": [float(x) for x in edges],
            "unsupported_by_quintile": [float(unsupported[band == b].mean()) for b in range(QUINTILES)]}


def independent_check(params: dict) -> dict:
    """:func:`unsupported_by_intensity` of the study's test pairs (rdnet's simulator) and of the
    same test sequences rendered by the independent circuit generator (``rdnet.circuit``, one
    draw, as ``restoration_circuit``'s first): whether the dark prior is rdnet's alone."""
    from rdnet.study.data import sequences
    from rdnet.study.independent import circuit_pairs
    out = {"rdnet simulator (data/pairs/test.h5)": unsupported_by_intensity(ROOT / "data" / "pairs" / "test.h5")}
    with tempfile.TemporaryDirectory() as tmp:
        pairs, _ = circuit_pairs(params, sequences(ROOT / "data" / "events", "test"), Path(tmp), 0)
        out["circuit generator (the same test sequences)"] = unsupported_by_intensity(pairs)
    return out


def train_variant(params: dict, degrade_overrides: dict, work: Path) -> Path:
    """The image-guided stage 1, seed 0, trained on the training split simulated with
    ``degrade_overrides`` (``degrade`` keys, or a section name with a dict of its keys, such as
    ``{"sensor": {"log_eps": 0.001}}``; reused when ``work`` already holds it)."""
    import copy
    from restore_train_range import train
    from restore_training_scenes import training_pairs
    ck = work / "seed0" / "model.pt"
    if ck.is_file():
        log.info("reusing %s", ck)
        return ck
    p = copy.deepcopy(params)
    for key, value in degrade_overrides.items():      # a dict value: overrides of that section
        if isinstance(value, dict):
            p[key] = {**p[key], **value}
        else:
            p["degrade"][key] = value
    pairs = work / "pairs" / "train.h5"
    if not pairs.is_file():
        pairs = training_pairs(p, {}, work)
    return train("restore", pairs, work / "seed0", 0, int(params["train"]["iterations"]))[0]


def main() -> None:
    from rdnet.baselines.baf import baf_mask
    from rdnet.config import load_params, section
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    from rdnet.eval.report import write_text_atomic
    from rdnet.events.core import Events
    from rdnet.events.io import load

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--recording", type=Path, default=ROOT / "data/real/davis346_road/davis346.aedat4")
    ap.add_argument("--checkpoints", nargs="*", default=["default"],
                    help="image-guided checkpoints; 'default': the restorer rdnet restore finds")
    ap.add_argument("--variants", nargs="*", default=[], metavar="NAME=JSON",
                    help='degrade overrides to train seed 0 with, e.g. bright1=\'{"shot_noise_bright_factor": 1.0}\'')
    ap.add_argument("--work", type=Path, default=None, help="keep the variants' pairs and networks here")
    ap.add_argument("--dark-quantile", type=float, default=0.4)
    ap.add_argument("--no-independent", dest="independent", action="store_false",
                    help="skip the training-pairs statistic on the test split and its circuit rendering")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/restore_dark_deletions")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    params = load_params(args.params)
    rec = load(args.recording)
    e, w, h = rec.events.array, rec.events.width, rec.events.height
    inten = frame_intensity(rec)
    edges, band = quintiles(inten)
    dark = inten < np.quantile(inten, args.dark_quantile)
    baf = baf_mask(rec.events, int(params["restore"]["baf_dt_us"]))
    sensor = section(params, "sensor")
    frames = LogFrames.of(rec.frames, rec.events, sensor.log_eps)

    def consistency(arr: np.ndarray) -> float:
        ev = Events(np.sort(arr, order="t", kind="stable"), w, h)
        return compare_consistency(frames, {"raw": rec.events, "v": ev}, sensor.threshold_on,
                                   sensor.threshold_off)["v"]["r2_fitted"]

    def by_band(deleted: np.ndarray) -> list[float]:
        return [float(deleted[band == b].mean()) for b in range(QUINTILES)]

    res = {"recording": str(args.recording.relative_to(ROOT)), "events": int(len(e)),
           "intensity_quintile_edges": [float(x) for x in edges], "dark_quantile": args.dark_quantile,
           "dark_events": int(dark.sum()), "raw_consistency": consistency(e),
           "baf": {"deleted": int((~baf).sum()), "deleted_by_quintile": by_band(~baf),
                   "consistency": consistency(e[baf]),
                   "consistency_dark_deletions_only": consistency(e[baf | ~dark])},
           "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        runs = [(None if c == "default" else Path(c), "rdnet restore default" if c == "default" else c)
                for c in args.checkpoints]
        for item in args.variants:
            name, spec = item.split("=", 1)
            overrides = json.loads(spec)
            work = (args.work or Path(tmp)) / name
            runs.append((train_variant(params, overrides, work), f"variant {name} {json.dumps(overrides)}"))
            res.setdefault("variants", {})[name] = {"overrides": overrides,
                                                   "training_pairs": unsupported_by_intensity(work / "pairs" / "train.h5")}
        for k, (ck, name) in enumerate(runs):
            for image in (None, "flat"):
                label = f"{name}{' / flat image' if image else ''}"
                restored, deleted = restore(args.recording, rec, params, ck, image, Path(tmp) / f"r{k}_{image}.h5")
                kept_out = restored.array
                run = {"deleted": int(deleted.sum()), "events_out": int(len(kept_out)),
                       "deleted_by_quintile": by_band(deleted),
                       "deleted_dark_share": float((deleted & dark).sum() / max(1, deleted.sum())),
                       "deleted_baf_supported": float((deleted & baf).sum() / max(1, deleted.sum())),
                       "consistency": consistency(kept_out)}
                if image is None:
                    run.update({
                        "consistency_dark_deletions_undone": consistency(np.concatenate([kept_out, e[deleted & dark]])),
                        "consistency_other_deletions_undone": consistency(np.concatenate([kept_out, e[deleted & ~dark]])),
                        "consistency_raw_minus_dark_deletions": consistency(e[~(deleted & dark)]),
                        "consistency_raw_minus_other_deletions": consistency(e[~(deleted & ~dark)])})
                res["runs"][label] = run
                log.info("%s: %s", label, run)
    if args.independent:
        res["independent"] = independent_check(params)
    write_text_atomic(args.out.with_suffix(".json"), json.dumps(res, indent=2) + "\n")
    write_text_atomic(args.out.with_suffix(".md"), table(res))
    print(table(res))


def table(res: dict) -> str:
    e = res["intensity_quintile_edges"]
    bands = [f"{e[b]:.2f}-{e[b + 1]:.2f}" for b in range(QUINTILES)]
    lines = [f"# Where the restorer deletes events on `{res['recording']}`", "",
             f"{res['events']:,} recorded events, cut into quintiles of their pixel's grey level in the "
             f"nearest frame; raw consistency R^2 {res['raw_consistency']:.4f}; \"dark\": the darkest "
             f"{res['dark_quantile']:.0%} of the events ({res['dark_events']:,}).", "",
             "Share of each quintile's events deleted:", "",
             "| method | deleted | " + " | ".join(bands) + " | dark share of its deletions | BAF-supported share of its deletions | consistency R^2 |",
             "|---|---:|" + "---:|" * QUINTILES + "---:|---:|---:|"]
    b = res["baf"]
    lines.append(f"| BAF | {b['deleted']:,} | " + " | ".join(f"{x:.3f}" for x in b["deleted_by_quintile"])
                 + f" | | | {b['consistency']:.4f} |")
    for label, r in res["runs"].items():
        lines.append(f"| {label} | {r['deleted']:,} | " + " | ".join(f"{x:.3f}" for x in r["deleted_by_quintile"])
                     + f" | {r['deleted_dark_share']:.3f} | {r['deleted_baf_supported']:.3f} | {r['consistency']:.4f} |")
    lines += ["", "Consistency R^2 with part of the deletions undone (each stream scored against raw):", "",
              "| restorer | restored | dark deletions undone | other deletions undone | raw minus its dark deletions | raw minus its other deletions |",
              "|---|---:|---:|---:|---:|---:|"]
    for label, r in res["runs"].items():
        if "consistency_dark_deletions_undone" in r:
            lines.append(f"| {label} | {r['consistency']:.4f} | {r['consistency_dark_deletions_undone']:.4f} | "
                         f"{r['consistency_other_deletions_undone']:.4f} | {r['consistency_raw_minus_dark_deletions']:.4f} | "
                         f"{r['consistency_raw_minus_other_deletions']:.4f} |")
    lines += ["", f"BAF with its dark deletions only: {b['consistency_dark_deletions_only']:.4f}.", ""]
    pairs = {f"{name} (training pairs)": v["training_pairs"] for name, v in res.get("variants", {}).items()}
    pairs.update({f"test split, {name}": t for name, t in res.get("independent", {}).items()})
    if pairs:
        lines += ["What the simulated pairs teach: the share of the degraded events in voxels with no "
                  "undegraded event, by quintile of the blurry image's grey level at their pixel:", "",
                  "| pairs | degraded events | unsupported | " + " | ".join(f"quintile {b + 1}" for b in range(QUINTILES)) + " |",
                  "|---|---:|---:|" + "---:|" * QUINTILES]
        for name, t in pairs.items():
            lines.append(f"| {name} | {t['degraded_events']:,} | {t['unsupported']:.3f} | "
                         + " | ".join(f"{x:.3f}" for x in t["unsupported_by_quintile"]) + " |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
