"""Stage `closed_loop`: camera-specific restoration (rdnet.study.closed_loop). Simulates the
study's sequences with the sensor + degradation that `rdnet calibrate` fitted to the DAVIS346
recording (--report; every fitted effect at --scale x its value), trains the image-guided count
restorer on them as `train_restore` does (lowest seed of study.seeds) into --models, and
compares it with the generic restorer (--generic) on the recording: events out, count ratio,
ESR, event-frame consistency R^2 (raw; generic; camera; the study's frame-pair restorer (--frames),
also with its guide at the fitted threshold; and each of them again with the fitted latency
subtracted from the timestamps first, as `rdnet restore --calibration`), plus the event-level
metrics of the generic and camera restorers on the calibrated held-out sequences (in-domain check). Writes OUT/summary.json,
OUT/summary.md and OUT/summary.png; simulated data and restored streams go to --work
(params: seed, randomize, blur, voxel, scenes.color, model, train, study.seeds, restore,
sensor thresholds and log_eps, ablation.batch_size/device)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.eval.report import write_text_atomic
    from rdnet.study import closed_loop as cl
    sim = cl.simulate_calibrated(params, args.report, args.scenes, args.interp, args.work, scale=args.scale)
    train = cl.train_camera_restorer(params, args.work / "pairs" / "train.h5", args.models, timing=args.timing,
                                     progress=not args.no_progress)
    from rdnet.restore.settings import calibrated_restore
    from rdnet.study.config import calibrated_configs
    restorers = {"generic": args.generic, "camera": args.models}
    fitted = calibrated_restore(*calibrated_configs(args.report))
    summary = {"simulation": sim,
               "training": {k: train[k] for k in ("task", "seeds", "parameters", "runs")},
               "recording": cl.compare_on_recording(params, args.recording, {**restorers, "frames": args.frames},
                                                    args.work / "restored", latency_us=fitted["latency_us"],
                                                    guide_threshold=fitted["guide_threshold"]),
               "in_domain": cl.in_domain(params, args.work / "pairs" / "test.h5", args.work / "events" / "test",
                                         restorers)}
    for run in summary["training"]["runs"]:      # wall time goes to --timing only (reproducible summary)
        run.pop("wall_s", None)
    _common.write_json(args.out / "summary.json", summary)
    write_text_atomic(args.out / "summary.md", cl.summary_markdown(summary))
    cl.summary_figure(summary, args.out / "summary.png")
    print(f"closed loop: training {train['wall_s_total']:.0f} s; " + ", ".join(
        f"{k} consistency {r['consistency_r2']:.3f} count {r['count_ratio']:.2f}x"
        for k, r in summary["recording"]["rows"].items()))


p = _common.parser(__doc__)
p.add_argument("--report", type=Path, default=Path("results/calibration/davis346/report.json"))
p.add_argument("--scenes", type=Path, default=Path("data/scenes"))
p.add_argument("--interp", type=Path, default=Path("data/interp"))
p.add_argument("--recording", type=Path, default=Path("data/real/davis346_road/davis346.aedat4"))
p.add_argument("--generic", type=Path, default=Path("models/restore_image"))
p.add_argument("--frames", type=Path, default=Path("models/restore_frames"),
               help="the frame-pair restorer (restore_frames), run on the recording only")
p.add_argument("--scale", type=float, default=1.0, help="every fitted effect at this multiple of its value")
p.add_argument("--work", type=Path, default=Path("data/closed_loop"))
p.add_argument("--models", type=Path, default=Path("data/closed_loop/restore_davis346"))
p.add_argument("--timing", type=Path, default=Path("metrics/train/restore_davis346.json"))
p.add_argument("--out", type=Path, default=Path("results/closed_loop"))
p.add_argument("--no-progress", action="store_true")
if __name__ == "__main__":      # guarded: training workers (spawn) may import this module
    _common.run(main, p)
