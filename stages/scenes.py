"""Stage `scenes`: render the embedded GOPRO-like sequences (params: scenes)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.study.data import render_scenes
    render_scenes(params, args.out)


p = _common.parser(__doc__)
p.add_argument("--out", type=Path, default=Path("data/scenes"))
_common.run(main, p)
