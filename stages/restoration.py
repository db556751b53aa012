"""Stage `restoration`: restoration metrics against the undegraded events for the raw
degraded events, STCF, GEF and RDNet's stage 1 (metrics/restoration.json)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.study.rows import restoration_table
    res = restoration_table(section(params, "ablation"), args.pairs, args.events_dir, args.checkpoint,
                            seeds=section(params, "study").seeds)
    _common.write_json(args.out, res)


p = _common.parser(__doc__)
p.add_argument("--pairs", type=Path, default=Path("data/pairs/test.h5"))
p.add_argument("--events-dir", type=Path, default=Path("data/events/test"))
p.add_argument("--checkpoint", type=Path, default=Path("models/rdnet"),
               help="RDNet network directory (seed<k>/model.pt) or one .pt file")
p.add_argument("--out", type=Path, default=Path("metrics/restoration.json"))
_common.run(main, p)
