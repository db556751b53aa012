"""Which image should guide the image-guided restorer on a real recording? (issue 11, the
DAVIS346 goal: event-frame consistency of the restored stream at least that of the raw one.)

The image-guided restorer (``models/restore_image``) is trained on the study's pairs, whose
image is the *blurry* frame: the mean of the sharp frames over the very window its events
fill (``blur`` stage, GOPRO style). ``rdnet restore`` hands it the recorded APS frame nearest
to the middle of each 50 ms window (``rdnet.restore.run.nearest_frame``). The DAVIS346 frames
are exposed for 500 us, so that image is sharp and shows the scene at one instant of the
window, not its average: a domain gap between training and use. This script restores the
DAVIS346 recording with each training seed, the window's image made three ways:

- ``nearest``: the recorded frame nearest the window's middle (what ``rdnet restore`` does);
- ``linear``: the mean over the window of the frames blended linearly in time between the
  recorded ones (16 samples per window): a ghosted double image rather than motion blur;
- ``flow``: the mean of the frames upsampled by rdnet's optical-flow interpolation
  (``rdnet.sim.interpolate.upsample_all``, method flow, max_upsample 16, as the study's
  ``interpolate`` stage makes its training frames) that fall inside the window: motion
  blur synthesised as the training's blurry images are made;
- ``flat``: no picture at all, the nearest frame's mean everywhere (a control: how much the
  network reads the image on this recording).

Every other step is ``restore_real``'s (``restore_training_scenes.score_real``): the restorer,
its decision, the window loop, the scores against the recorded frames. Only the image the
network reads changes, through a restorer whose ``restore`` swaps the frame it is given.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/restore_window_image.py      # about 2 min
        writes benchmarks/results/restore_window_image.{json,md}
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from restore_training_scenes import restorers_from, score_real  # noqa: E402

log = logging.getLogger("restore_window_image")
IMAGES = ("nearest", "linear", "flow", "flat")


class WindowImages:
    """The guiding image of a window ``[t0, t1)`` of a recording's grey linear frames."""

    def __init__(self, grey: np.ndarray, t_us: np.ndarray, kind: str, samples: int = 16):
        self.grey, self.t = grey, np.asarray(t_us, np.int64)
        self.kind, self.samples = kind, samples
        if kind == "flow":
            from rdnet.sim.interpolate import InterpolateConfig, upsample_all
            self.up, self.up_t = upsample_all(grey, self.t, InterpolateConfig(method="flow", max_upsample=16),
                                              warn=False)

    def __call__(self, t0: int, t1: int) -> np.ndarray:
        if self.kind in ("nearest", "flat"):
            im = self.grey[int(np.argmin(np.abs(self.t - (t0 + t1) // 2)))]
            return im if self.kind == "nearest" else np.full_like(im, im.mean())
        if self.kind == "linear":
            ts = t0 + (np.arange(self.samples) + 0.5) / self.samples * (t1 - t0)
            i = np.clip(np.searchsorted(self.t, ts, side="right") - 1, 0, len(self.t) - 2)
            w = np.clip((ts - self.t[i]) / (self.t[i + 1] - self.t[i]), 0.0, 1.0).astype(np.float32)
            out = np.zeros_like(self.grey[0])
            for k in range(self.samples):
                out += (1 - w[k]) * self.grey[i[k]] + w[k] * self.grey[i[k] + 1]
            return out / np.float32(self.samples)
        inside = (self.up_t >= t0) & (self.up_t < t1)
        if not inside.any():                      # beyond the frames: the nearest upsampled one
            return self.up[int(np.argmin(np.abs(self.up_t - (t0 + t1) // 2)))]
        return self.up[inside].mean(axis=0, dtype=np.float64).astype(np.float32)


def restorer_with(restorer, images: WindowImages):
    """``restorer`` (a :class:`rdnet.restore.learned.LearnedRestorer`) reading ``images(t0, t1)``
    instead of the frame it is handed."""
    base = type(restorer)

    class Swapped(base):
        def restore(self, events, t0_us, t1_us, frame):
            return base.restore(self, events, t0_us, t1_us, images(int(t0_us), int(t1_us)))
    return Swapped(**{f.name: getattr(restorer, f.name) for f in dataclasses.fields(restorer)})


def main() -> None:
    from rdnet.config import load_params
    from rdnet.eval.report import write_text_atomic
    from rdnet.events.io import load

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--recording", type=Path, default=ROOT / "data/real/davis346_road/davis346.aedat4")
    ap.add_argument("--models", type=Path, default=ROOT / "models/restore_image")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--images", nargs="+", default=list(IMAGES), choices=IMAGES)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/restore_window_image")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    params = load_params(args.params)
    rec = load(args.recording)
    grey = rec.frames.grey()
    res = {"recording": str(args.recording.relative_to(ROOT)), "window_us": int(params["restore"]["window_us"]),
           "seeds": args.seeds, "runs": {}}
    for kind in args.images:
        images = WindowImages(grey, rec.frames.t_us, kind)
        runs = {f"{kind}/seed{s}": ("rdnet", args.models / f"seed{s}" / "model.pt") for s in args.seeds}
        if kind == args.images[0]:
            runs = {"raw": ("raw", None), "baf": ("baf", None), **runs}
        with restorers_from(lambda load: lambda checkpoint, **kw: restorer_with(load(checkpoint, **kw), images)), \
                tempfile.TemporaryDirectory() as tmp:
            scored = score_real(args.recording, "davis346_road", params, runs, Path(tmp))
        res["events"] = scored["events"]
        res["runs"].update(scored["methods"])
    write_text_atomic(args.out.with_suffix(".json"), json.dumps(res, indent=2) + "\n")
    write_text_atomic(args.out.with_suffix(".md"), table(res))
    print(table(res))


def table(res: dict) -> str:
    lines = [f"# The image that guides the image-guided restorer on `{res['recording']}`", "",
             f"{res['events']:,} recorded events; windows of {res['window_us'] // 1000} ms; "
             "`restore_image`, seeds " + ", ".join(map(str, res["seeds"])) + ".", "",
             "| image | run | events out | kept | not recorded | ESR | consistency R^2 |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for label, m in res["runs"].items():
        kind, _, run = label.partition("/")
        lines.append(f"| {kind if run else '-'} | {run or kind} | {m['events_out']:,} | {100 * m['kept_fraction']:.1f} % | "
                     f"{100 * m['not_recorded_fraction']:.1f} % | {m['esr']:.3f} | {m['consistency_r2']:.3f} |")
    lines += ["", "Means over the seeds:", "", "| image | kept | not recorded | consistency R^2 |", "|---|---:|---:|---:|"]
    kinds = dict.fromkeys(k.partition("/")[0] for k in res["runs"] if "/" in k)
    for kind in kinds:
        ms = [m for k, m in res["runs"].items() if k.startswith(kind + "/")]
        lines.append(f"| {kind} | {100 * np.mean([m['kept_fraction'] for m in ms]):.1f} % | "
                     f"{100 * np.mean([m['not_recorded_fraction'] for m in ms]):.1f} % | "
                     f"{np.mean([m['consistency_r2'] for m in ms]):.3f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
