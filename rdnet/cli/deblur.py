"""``rdnet deblur RECORDING OUT``: restore and deblur a real recording with RDNet.

For every frame of RECORDING (AEDAT 4, HDF5 or another readable format with frames and
events) the events of its exposure window go through stage 1 (restoration) and stage 2
(deblurring) of the RDNet checkpoint (default: the study's, models/rdnet). Writes
OUT/consistency.json (event-frame consistency of the raw and the restored events:
how well the signed events between consecutive frames explain the change of log
intensity; higher is better), OUT/montage.png, and restored.h5 (restored events and
deblurred frames) plus deblurred/*.png into --data-out (default OUT). Settings: the
``deblur`` section (window, batch_size, device, max_frames ...), ``voxel`` and ``model``
(must match the checkpoint) and ``sensor`` (nominal thresholds, log_eps). Nothing is
written unless the whole run succeeds.
"""
from __future__ import annotations

from pathlib import Path

from rdnet.cli.info import add_progress_arg
from rdnet.config import add_params_args, load_cli_params


def register(subparsers) -> None:
    p = subparsers.add_parser("deblur", help="restore and deblur a real recording with RDNet",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("recording", type=Path, help="recording with frames and events (.aedat4, .h5, ...)")
    p.add_argument("out", type=Path, help="output folder: consistency.json, montage.png")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="RDNet checkpoint file or folder (default: models/rdnet, as trained by dvc repro)")
    p.add_argument("--data-out", type=Path, default=None,
                   help="folder for the large outputs (restored.h5, deblurred/*.png); default OUT")
    add_params_args(p)
    add_progress_arg(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from rdnet.deblur.run import deblur_recording

    params = load_cli_params(args)
    res = deblur_recording(args.recording, args.out, params, checkpoint=args.checkpoint,
                           data_out=args.data_out, progress=args.progress)

    def fmt(v):
        return "n/a" if v is None else f"{v:.4f}"
    print(f"event-frame consistency (R^2, higher is better) over {res['frame_pairs']} frame pairs: "
          f"raw {fmt(res['raw'])}, restored {fmt(res['restored'])}")
    print(f"wrote {args.out / 'consistency.json'} and {(args.data_out or args.out) / 'restored.h5'} "
          f"({res['run']['frames']} frames, deblur windows: {res['windows']['deblur']})")
    return 0
