"""Stage `interpolate`: adaptive flow upsampling of every scene (params: interpolate)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.study.data import interpolate_scenes
    summary = interpolate_scenes(params, args.scenes, args.out)
    _common.write_json(args.out / "summary.json", summary)


p = _common.parser(__doc__)
p.add_argument("--scenes", type=Path, default=Path("data/scenes"))
p.add_argument("--out", type=Path, default=Path("data/interp"))
_common.run(main, p)
