"""Stages `train_baseline@*`, `train_restore`, `train_deblur`: train one network
(params: model, train). Resumes from OUT/last.pt when present."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.train.loop import train
    ck = train(args.task, section(params, "train"), section(params, "model"), args.train, args.out,
               events=args.events, init_checkpoint=args.init, resume=True, progress=True)
    print(f"wrote {ck}")


p = _common.parser(__doc__)
p.add_argument("--task", required=True)
p.add_argument("--events", choices=["degraded", "undegraded"], default="degraded")
p.add_argument("--train", type=Path, default=Path("data/pairs/train.h5"))
p.add_argument("--init", type=Path, default=None, help="stage-1 checkpoint (task rdnet)")
p.add_argument("--out", type=Path, required=True)
_common.run(main, p)
