"""Stage `blur`: GOPRO-style blurry/sharp pairs with undegraded and degraded voxel grids
(params: blur, voxel)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.study.data import make_pairs
    summary = make_pairs(params, args.events, args.out)
    _common.write_json(args.out / "summary.json", summary)


p = _common.parser(__doc__)
p.add_argument("--events", type=Path, default=Path("data/events"))
p.add_argument("--out", type=Path, default=Path("data/pairs"))
_common.run(main, p)
