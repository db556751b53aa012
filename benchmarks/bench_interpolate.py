"""Frame-interpolation quality and speed: flow (DIS, Farneback) vs linear blending, and
the log-step bound of the adaptive upsampling.

Ground truth: sequences rendered at a high frame rate by :mod:`rdnet.sim.scenes` (camera
pan/rotation/zoom/shake + independently moving objects) and a pure sub-pixel pan across
a natural image. Every ``factor``-th frame is kept, the frames in between are interpolated
back with :func:`rdnet.sim.interpolate.interpolate_pair`, and PSNR (linear intensity in
[0, 1], all held-out frames) is reported per method and factor, with the time per
interpolated frame.

The bound (``max_log_step`` on ``|delta log(Y + eps)|`` between consecutive output frames):

* ``adaptive``: what :func:`upsample` achieves (pairs over the bound, largest criterion,
  largest step of any pixel, fraction of pixel-steps over the bound, frames per input
  frame) on the embedded study scenes (``scenes`` and ``interpolate`` of params.yaml, test
  split) at several ``max_upsample``, with and without the ``fill_log`` guarantee, and on
  the 960 Hz sequences subsampled 8x;
* ``causes``: where the steps over the bound come from: the interpolated sequence against
  the true 960 Hz frames *at the same rate* (share of the interpolated over-bound
  pixel-steps that are over in the truth too, share at dark pixels, share in occlusion
  regions), for the occlusion weighting in use (expected visibility, uniform occlusion
  time) and for the hard masks it replaced.

    .venv/bin/python benchmarks/bench_interpolate.py            # writes benchmarks/results/interpolate.json
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from rdnet.config import load_params, section
from rdnet.sim.interpolate import (InterpolateConfig, PairInterpolator, UpsampleStats, _remap,
                                   _warp_map, interpolate_pair, step_sizes, upsample_all)
from rdnet.sim.scenes import ScenesConfig, make_specs, render_sequence, render_split

BOUND, EPS, DARK = 0.1, 0.01, 0.05

METHODS = {
    "flow_dis": InterpolateConfig(method="flow", flow="dis"),          # medium preset (the default)
    "flow_dis_fast": InterpolateConfig(method="flow", flow="dis", dis_preset="fast"),
    "flow_dis_ultrafast": InterpolateConfig(method="flow", flow="dis", dis_preset="ultrafast"),
    "flow_dis_scale2": InterpolateConfig(method="flow", flow="dis", dis_finest_scale=2),   # medium, coarser grid
    "flow_farneback": InterpolateConfig(method="flow", flow="farneback"),
    "linear": InterpolateConfig(method="linear"),
}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def sequences(size: int, n_frames: int, n_scenes: int, seed: int) -> dict[str, np.ndarray]:
    """name -> (N, H, W) float32 linear frames at the high rate."""
    out = {}
    cfg = ScenesConfig(n_train=0, n_test=n_scenes, height=size, width=size, n_frames=n_frames,
                       fps_hz=960.0, speed_px=0.5, rotation_deg=0.05, zoom=0.001, shake_px=0.1,
                       n_objects=2, object_speed_px=0.6, texture_fraction=0.0, seed=seed)
    for spec in make_specs(cfg, "test"):
        out[f"scene_{spec.index}_{spec.background}"] = render_sequence(spec).images
    # a pure pan over a natural image (0.5 px / frame, sub-pixel), no objects
    pan = dataclasses.replace(cfg, n_test=1, rotation_deg=0.0, zoom=0.0, shake_px=0.0, n_objects=0)
    spec = make_specs(pan, "test", np.random.default_rng(seed + 100))[0]
    cam = dict(spec.camera)
    for k in ("x", "y", "angle", "log_scale"):
        cam[k] = dict(cam[k], a=[0.0] * len(cam[k]["a"]))
    spec = dataclasses.replace(spec, camera=cam, background="camera")
    out["pan_camera"] = render_sequence(spec).images
    return out


def bench(seqs: dict, factors: list[int]) -> list[dict]:
    rows = []
    for name, ims in seqs.items():
        for f in factors:
            keep = np.arange(0, ims.shape[0], f)
            keep = keep[: (ims.shape[0] - 1) // f + 1]
            for mname, cfg in METHODS.items():
                t = time.perf_counter()
                pred, truth = [], []
                for a, b in zip(keep[:-1], keep[1:]):
                    pred.append(interpolate_pair(ims[a], ims[b], f - 1, cfg))
                    truth.append(ims[a + 1:b])
                dt = time.perf_counter() - t
                pred, truth = np.concatenate(pred), np.concatenate(truth)
                rows.append({"sequence": name, "factor": f, "method": mname,
                             "psnr_db": round(psnr(pred, truth), 3),
                             "ms_per_frame": round(1e3 * dt / len(pred), 3),
                             "frames": int(len(pred))})
    return rows


def _row(name: str, ims: np.ndarray, t_us: np.ndarray, label: str, cfg: InterpolateConfig) -> dict:
    st = UpsampleStats()
    t = time.perf_counter()
    up, tu = upsample_all(ims, t_us, cfg, log_eps=EPS, stats=st)
    sec = time.perf_counter() - t
    steps = step_sizes(up, EPS, color=up.ndim == 4)        # the whole sequence: checks the per-pair stats
    assert st.pixel_steps_over == int((steps > cfg.max_log_step).sum())
    return {"sequence": name, "config": label, "max_upsample": cfg.max_upsample,
            "pixel_quantile": cfg.pixel_quantile, "fill_log": cfg.fill_log, "pairs": st.pairs,
            "frames_per_input_frame": round(len(tu) / len(ims), 2),
            "filled_per_pair": round(st.filled / st.pairs, 2),
            "pairs_over_bound": st.violations, "criterion_max": round(st.max_log_step, 4),
            "log_step_max": round(st.strict_max_log_step, 4),
            "log_step_p99_9": round(float(np.quantile(steps, 0.999)), 4),
            "frac_pixel_steps_over_bound": float(f"{st.over_bound_fraction:.3g}"),
            "seconds": round(sec, 2)}


def study_scenes(params_path: Path) -> tuple[dict, InterpolateConfig, dict]:
    """The embedded study's test scenes (params.yaml ``scenes``) and its ``interpolate``."""
    params = load_params(params_path)
    scfg = section(params, "scenes")
    icfg = section(params, "interpolate")
    seqs = {f"study_{spec.index}_{spec.background}": (fr.images, fr.t_us)
            for spec, fr in render_split(scfg, "test")}
    return seqs, icfg, {"height": scfg.height, "width": scfg.width, "fps_hz": scfg.fps_hz,
                        "n_frames": scfg.n_frames, "speed_px": scfg.speed_px,
                        "object_speed_px": scfg.object_speed_px}


def adaptive(seqs960: dict, factor: int, study: dict, base: InterpolateConfig) -> list[dict]:
    rows = []
    caps = sorted({base.max_upsample, 64, 256})
    configs = [(f"params, max_upsample {c}", dataclasses.replace(base, max_upsample=c)) for c in caps]
    configs.append(("params + fill_log", dataclasses.replace(base, fill_log=True)))
    configs.append(("params, pixel_quantile 1", dataclasses.replace(base, pixel_quantile=1.0)))
    for name, (ims, t_us) in study.items():
        for label, cfg in configs:
            rows.append(_row(name, ims, t_us, label, cfg))
    for name, ims in seqs960.items():
        sub = ims[::factor]
        t_us = np.rint(np.arange(len(sub)) * factor * 1e6 / 960.0).astype(np.int64)
        for label, cfg in (("max_upsample 64", dataclasses.replace(base, max_upsample=64, pixel_quantile=0.99)),
                           ("max_upsample 64 + fill_log", dataclasses.replace(base, max_upsample=64, fill_log=True))):
            rows.append(_row(f"{name} (8x subsampled)", sub, t_us, label, cfg))
    return rows


class HardMaskInterpolator(PairInterpolator):
    """The occlusion weighting used before (hard masks, V = 1 - O): for comparison only."""

    def frame(self, t: float) -> np.ndarray:
        t = np.float32(t)
        f01, f10, o0, o1, grid = self._prepare()
        m0 = _warp_map(grid, -(1 - t) * t * f01 + t * t * f10)
        m1 = _warp_map(grid, (1 - t) * (1 - t) * f01 - t * (1 - t) * f10)
        g0, g1 = _remap(self.f0, m0), _remap(self.f1, m1)
        w1 = t * (1 - _remap(o0, m0)) + 1e-4 * t
        w0 = (1 - t) * (1 - _remap(o1, m1)) + 1e-4 * (1 - t)
        return np.maximum((w0 * g0 + w1 * g1) / (w0 + w1), 0).astype(np.float32)


def causes(seqs960: dict, factor: int) -> list[dict]:
    """Interpolated (every ``factor``-th frame kept, ``factor`` - 1 inserted) against the
    true 960 Hz frames, at the same rate."""
    rows = []
    cfg = InterpolateConfig(method="flow")
    for name, ims in seqs960.items():
        keep = np.arange(0, ims.shape[0], factor)
        keep = keep[: (ims.shape[0] - 1) // factor + 1]
        truth = ims[: keep[-1] + 1]
        d_true = np.abs(np.diff(np.log(truth + np.float32(EPS)), axis=0))
        over_true = d_true > BOUND
        for variant, cls in (("expected visibility (in use)", PairInterpolator), ("hard masks (before)", HardMaskInterpolator)):
            pred, occ = [ims[0]], []
            for a, b in zip(keep[:-1], keep[1:]):
                pi = cls(ims[a], ims[b], cfg)
                pred += list(pi.frames(factor - 1)) + [ims[b]]
                _, _, o0, o1, _ = pi._prepare()
                m = cv2.dilate(((o0 > 0) | (o1 > 0)).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
                occ += [m] * factor
            pred = np.asarray(pred)
            d = np.abs(np.diff(np.log(pred + np.float32(EPS)), axis=0))
            over = d > BOUND
            lo = np.minimum(pred[1:], pred[:-1])
            n_over = max(int(over.sum()), 1)
            rows.append({"sequence": name, "factor": factor, "occlusion_weights": variant,
                         "truth_frac_over_bound": float(f"{over_true.mean():.3g}"),
                         "truth_log_step_max": round(float(d_true.max()), 3),
                         "interp_frac_over_bound": float(f"{over.mean():.3g}"),
                         "interp_log_step_max": round(float(d.max()), 3),
                         "share_also_over_in_truth": round(float((over & over_true).sum()) / n_over, 3),
                         "share_dark_pixels": round(float((over & (lo < DARK)).sum()) / n_over, 3),
                         "share_occlusion_regions": round(float((over & np.asarray(occ)).sum()) / n_over, 3)})
    return rows


def summarize(rows: list[dict]) -> dict:
    out = {}
    for r in rows:
        out.setdefault(r["method"], {}).setdefault(str(r["factor"]), []).append(r)
    return {m: {f: {"psnr_db_mean": round(float(np.mean([r["psnr_db"] for r in v])), 3),
                    "ms_per_frame_mean": round(float(np.mean([r["ms_per_frame"] for r in v])), 3)}
                for f, v in d.items()} for m, d in out.items()}


def plot(summary: dict, factors: list[int], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(4, 3), dpi=100)
    for m, d in summary.items():
        ax.plot(factors, [d[str(f)]["psnr_db_mean"] for f in factors], "o-", label=m)
    ax.set_xscale("log", base=2)
    ax.set_xticks(factors, [str(f) for f in factors])
    ax.set_xlabel("subsampling factor")
    ax.set_ylabel("PSNR of interpolated frames (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp)
    os.replace(tmp, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--frames", type=int, default=129)
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--factors", type=int, nargs="+", default=[4, 8, 16])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--params", type=Path, default=Path(__file__).parent.parent / "params.yaml")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "interpolate.json")
    ap.add_argument("--png", type=Path, default=Path(__file__).parent / "results" / "interpolate.png")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    seqs = sequences(args.size, args.frames, args.scenes, args.seed)
    study, icfg, study_info = study_scenes(args.params)
    rows = bench(seqs, args.factors)
    summary = summarize(rows)
    result = {
        "benchmark": "interpolate",
        "command": "python benchmarks/bench_interpolate.py " + " ".join(
            f"--{k} {' '.join(map(str, v)) if isinstance(v, list) else v}" for k, v in
            (("size", args.size), ("frames", args.frames), ("scenes", args.scenes),
             ("factors", args.factors), ("seed", args.seed))),
        "setup": {"truth_fps_hz": 960.0, "size": args.size, "frames": args.frames,
                  "camera_speed_px_per_frame": 0.5, "object_speed_px_per_frame": 0.6,
                  "psnr": "linear intensity [0,1], all held-out frames, no border crop",
                  "opencv_threads": 1},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version(),
                    "opencv": cv2.__version__, "numpy": np.__version__,
                    "load_average_1min_at_start": round(load0, 2), "load_average_1min_at_end": None},
        "notes": ("bound 0.1 on |delta log(Y + 0.01)| between consecutive output frames. adaptive: the "
                  "study's test scenes with its interpolate config at several max_upsample (criterion = "
                  "pixel_quantile), with fill_log (log-linear frames where the cap leaves steps over the "
                  "bound: every pixel meets it), and the 960 Hz sequences subsampled 8x. causes: "
                  "interpolated vs true 960 Hz frames at the same rate; dark = the lower of the two "
                  "intensities < 0.05; occlusion = forward-backward masks of the pair, dilated 1 px"),
        "study_scenes": study_info,
        "study_interpolate": {k: getattr(icfg, k) for k in ("method", "flow", "dis_preset", "max_log_step",
                                                             "max_upsample", "pixel_quantile", "occlusion",
                                                             "verify", "fill_log")},
        "summary": summary,
        "rows": rows,
        "adaptive": adaptive(seqs, 8, study, icfg),
        "causes": causes(seqs, 8),
        "total_seconds": None,
    }
    result["total_seconds"] = round(time.perf_counter() - t0, 1)
    result["machine"]["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    os.replace(tmp, args.out)
    if args.png:
        plot(summary, args.factors, args.png)
    for m, d in summary.items():
        print(m, {f: (v["psnr_db_mean"], v["ms_per_frame_mean"]) for f, v in d.items()})
    for r in result["adaptive"] + result["causes"]:
        print(r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
