"""Stage `simulate`: paired ideal/degraded events with randomized per-split degradation
(params: sensor, degrade, randomize, seed)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.study.data import simulate_sequences
    summary = simulate_sequences(params, args.scenes, args.interp, args.out)
    _common.write_json(args.out / "summary.json", summary)


p = _common.parser(__doc__)
p.add_argument("--scenes", type=Path, default=Path("data/scenes"))
p.add_argument("--interp", type=Path, default=Path("data/interp"))
p.add_argument("--out", type=Path, default=Path("data/events"))
_common.run(main, p)
