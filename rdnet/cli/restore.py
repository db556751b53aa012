"""``rdnet restore RECORDING OUT.h5``: remove noise events from a recording.

Reads RECORDING (any format rdnet reads), restores its events in consecutive time
windows (``restore.window_us``; memory bounded) and writes OUT.h5 (restored events in
the project's HDF5 layout, frames copied when present) and OUT.json (event counts in
and out, method and model used, no-reference scores of the raw and restored streams:
ESR and, with frames, event-frame consistency). Methods: rdnet (the learned restorer:
image-guided when the recording has frames, events-only otherwise; --checkpoint or the
study's / packaged models), baf (background-activity filter), stcf, gef (needs frames).
Settings: the ``restore`` section of params.yaml. Nothing is written unless the whole
run succeeds.
"""
from __future__ import annotations

from pathlib import Path

from rdnet.config import add_params_args, load_cli_params, section
from rdnet.cli.info import add_progress_arg, add_sensor_size_args, sensor_size_of
from rdnet.restore.settings import METHODS



def register(subparsers) -> None:
    p = subparsers.add_parser("restore", help="remove noise events from a recording (learned or classical)",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("recording", type=Path, help="recording (.aedat4, .h5, .txt, .npz, ...)")
    p.add_argument("out", type=Path, help="output OUT.h5 (OUT.json is written beside it)")
    p.add_argument("--method", choices=METHODS, default=None,
                   help="restorer (default: restore.method of params.yaml, rdnet)")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="learned restorer checkpoint (method rdnet; default: the study's, else the packaged one; "
                        "method ednccn: default models/ednccn)")
    p.add_argument("--calibration", type=Path, default=None, metavar="REPORT",
                   help="an `rdnet calibrate` report.json of this camera: its fitted latency_us is "
                        "undone first (sets restore.latency_us), and the frame-pair restorer's guide counts "
                        "events at its fitted contrast threshold (sets restore.guide_threshold; with "
                        "restore.guide auto, the default, a recording with frames then gets that restorer)")
    add_sensor_size_args(p)
    add_params_args(p)
    add_progress_arg(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from rdnet.restore.run import json_path_for, restore_recording

    params = load_cli_params(args)
    if args.calibration is not None:
        from rdnet.restore.settings import calibrated_restore
        from rdnet.study.config import calibrated_configs
        # refuses a FIFO or a folder before reading (a FIFO would block), names a missing file
        sensor, degrade = calibrated_configs(args.calibration, "--calibration")
        params = {**params, "restore": {**(params.get("restore") or {}), **calibrated_restore(sensor, degrade)}}
        section(params, "restore", f"{args.calibration} (its fitted latency_us and thresholds, --calibration)")
    res = restore_recording(args.recording, args.out, params, method=args.method,
                            checkpoint=args.checkpoint, progress=args.progress,
                            sensor_size=sensor_size_of(args))
    kept = res["kept_fraction"]
    esr = res["scores"]["esr"]

    def fmt(v):
        return "n/a" if v is None else f"{v:.3f}"
    line = (f"{res['method']}: {res['events_in']} -> {res['events_out']} events "
            f"({'n/a' if kept is None else f'{100 * kept:.1f} %'} kept)")
    guide = (res.get("model") or {}).get("guide")
    if isinstance(guide, dict):          # a frame-pair restorer: which threshold its guide counts events at
        trained = guide["threshold_trained"]
        line += f"; guide threshold {guide['threshold']:.3g}" + (
            "" if guide["threshold"] == trained else f" (trained {trained:.3g})")
    if esr is not None:
        line += f"; ESR (higher = more structure) raw {fmt(esr['raw'])}, restored {fmt(esr['restored'])}"
    cons = res["scores"]["consistency"]
    if cons:
        line += (f"; event-frame consistency R^2 raw {fmt(cons['raw']['r2_fitted'])}, "
                 f"restored {fmt(cons['restored']['r2_fitted'])}")
    print(line)
    print(f"wrote {args.out} and {json_path_for(args.out)}")
    return 0
