"""Stages `train_baseline@<network>`, `train_restore`, `train_deblur`: train one network
once per seed of `study.seeds` into OUT/seed<k>/ (params: model, train, study and the
network's entry of `networks`). Each seed resumes from its last.pt when present.
Run by `study.launcher`: `python`, or `torchrun --nproc_per_node=N` for data parallelism."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.study.config import NetworkConfig, network
    from rdnet.study.training import train_seeds
    from rdnet.train.distributed import cleanup, init_from_env
    train_cfg = section(params, "train")
    if args.restore_output:                               # e.g. the paper's signed stage 1 beside the counts one
        import dataclasses
        train_cfg = dataclasses.replace(train_cfg, restore_output=args.restore_output)
    if args.stage2_input:                                 # e.g. RDNet whose stage 2 also reads the raw events
        import dataclasses
        train_cfg = dataclasses.replace(train_cfg, stage2_input=args.stage2_input)
    init_from_env(train_cfg.device)                       # under torchrun (study.launcher): join the group
    if args.network and args.events is not None:
        from rdnet.errors import ConfigError
        raise ConfigError("--events", f"goes with --task; network {args.network!r} reads the events of "
                          f"networks.{args.network}.events in params.yaml")
    net = (network(params, args.network) if args.network
           else NetworkConfig(task=args.task, events=args.events or "degraded"))
    study = section(params, "study")
    init_deblur = None
    if net.task == "rdnet" and study.rdnet_stage2_init:
        network(params, study.rdnet_stage2_init)          # must name a network of the study
        init_deblur = args.models / study.rdnet_stage2_init
    from rdnet.train.run import frame_pair_guide
    summary = train_seeds(net, study, train_cfg, section(params, "model"),
                          args.train, args.out, init=args.init, init_deblur=init_deblur, progress=True,
                          timing=args.timing, guide=frame_pair_guide(net.task, params))
    cleanup()
    print(f"trained {args.out} for seeds {summary['seeds']} in {summary['wall_s_total']:.0f} s "
          f"({summary['parameters']:,} parameters)")


def _parser():
    p = _common.parser(__doc__)
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--network", help="an entry of the `networks` section of params.yaml")
    g.add_argument("--task", help="a training task (restore, restore_events, restore_frames, rdnet, deblur, ...)")
    p.add_argument("--events", choices=["degraded", "undegraded"], default=None,
                   help="with --task deblur or deblurnet_matched: the input events (default degraded)")
    p.add_argument("--restore-output", choices=["signed_masked", "counts"], default=None,
                   help="overrides train.restore_output (stage-1 output of restore/rdnet tasks)")
    p.add_argument("--stage2-input", choices=["restored", "dual"], default=None,
                   help="overrides train.stage2_input (task rdnet: what stage 2 reads)")
    p.add_argument("--train", type=Path, default=Path("data/pairs/train.h5"))
    p.add_argument("--init", type=Path, default=None,
                   help="starting weights: a network directory (seed by seed) or a .pt file")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--timing", type=Path, default=None,
                   help="wall-time record (default OUT.timing.json); kept out of OUT, so OUT's bytes "
                        "depend only on the settings and the data")
    p.add_argument("--models", type=Path, default=Path("models"),
                   help="where the study's networks are (study.rdnet_stage2_init)")
    return p


if __name__ == "__main__":      # guarded: the seed workers (spawn) import this module
    _common.run(main, _parser())
