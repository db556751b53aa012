"""Entry point of a training run: ``python -m rdnet.train.run`` (also ``rdnet train``
once registered as a CLI command; :func:`register` / :func:`run` follow the CLI's
subcommand protocol).

    python -m rdnet.train.run --task restore --params params.yaml \\
        --train data/pairs/train.h5 --out models/restore_image
    torchrun --nproc_per_node=2 -m rdnet.train.run --task deblur --events degraded ...

Reads the ``train`` and ``model`` sections of params.yaml (``--set train.iterations=10``
overrides a key). Works plainly and under ``torchrun`` (data parallel, see
:mod:`rdnet.train.distributed`).
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from rdnet.errors import RdnetError

log = logging.getLogger(__name__)

SECTION_CLASSES = {"train": "rdnet.train.config:TrainConfig", "model": "rdnet.train.config:ModelConfig"}


def ensure_sections() -> None:
    """Register the ``train`` and ``model`` sections with :mod:`rdnet.config` (no-op when
    the lead has already wired them into ``SECTIONS``)."""
    from rdnet.config import SECTIONS, register_section
    for name, target in SECTION_CLASSES.items():
        if name not in SECTIONS:
            register_section(name, target)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from rdnet.config import add_params_args

    # no ``choices`` from rdnet.train.loop.TASKS: that module imports torch, and this runs
    # whenever the ``rdnet`` CLI builds its parser; train() rejects an unknown task
    p.add_argument("--task", required=True,
                   help="what to train: restore, restore_events, restore_frames, deblur, deblurnet_matched, ... "
                        "(rdnet.train.loop.TASKS)")
    p.add_argument("--train", dest="train_path", type=Path, required=True, help="pairs file (HDF5)")
    p.add_argument("--out", type=Path, required=True, help="output folder (model.pt, last.pt, dvclive/)")
    p.add_argument("--events", choices=["degraded", "undegraded"], default="degraded",
                   help="input events of deblur/deblurnet_matched (default: degraded)")
    p.add_argument("--init", dest="init_checkpoint", type=Path, default=None,
                   help="starting weights (rdnet: the stage-1 restore checkpoint)")
    p.add_argument("--no-resume", dest="resume", action="store_false",
                   help="ignore OUT/last.pt and start over")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    add_params_args(p)


def register(subparsers) -> None:
    p = subparsers.add_parser("train", help="train a network on a pairs file (also under torchrun)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    p.set_defaults(func=run)


def frame_pair_guide(task: str, params):
    """The frame-pair guide of task ``restore_frames`` (:mod:`rdnet.nn.guide`): the log
    offset and ON threshold of ``params``' ``sensor`` section, the simulator's that made
    the pairs; None for every other task."""
    if task != "restore_frames":
        return None
    from rdnet.config import section
    from rdnet.nn.guide import FramePairGuide
    sensor = section(params, "sensor")
    return FramePairGuide(float(sensor.log_eps), float(sensor.threshold_on))


def run(args) -> int:
    from rdnet.config import load_cli_params, section
    from rdnet.events.io._common import check_output_folder
    from rdnet.train import distributed
    from rdnet.train.loop import train

    ensure_sections()
    params = load_cli_params(args)
    cfg = section(params, "train")
    model_cfg = section(params, "model")
    check_output_folder(args.out, ("model.pt", "last.pt"))    # before the training, not after it
    info = distributed.init_from_env(cfg.device)
    try:
        path = train(args.task, cfg, model_cfg, args.train_path, args.out, events=args.events,
                     init_checkpoint=args.init_checkpoint, resume=args.resume, progress=args.progress,
                     guide=frame_pair_guide(args.task, params))
    finally:
        distributed.cleanup()
    if info.rank == 0:
        log.info("wrote %s", path)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m rdnet.train.run", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return run(args)
    except RdnetError as e:
        print(f"rdnet train: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
