"""Stage `evaluate@<row>`: score one ablation row on the test pairs (params: ablation.rows.<row>).
Writes the compact metrics (psnr, ssim, ...) for `dvc metrics show` and the details
(per-level and per-degradation breakdowns, per-sample values) beside them."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.study.rows import evaluate_ablation_row
    cfg = section(params, "ablation")
    res = evaluate_ablation_row(cfg, args.row, args.pairs, args.events_dir)
    compact = {k: res[k] for k in ("psnr", "ssim", "n", "paper_psnr") if res.get(k) is not None}
    _common.write_json(args.out, compact)
    _common.write_json(args.details, res)


p = _common.parser(__doc__)
p.add_argument("--row", required=True)
p.add_argument("--pairs", type=Path, default=Path("data/pairs/test.h5"))
p.add_argument("--events-dir", type=Path, default=Path("data/events/test"))
p.add_argument("--out", type=Path, required=True)
p.add_argument("--details", type=Path, required=True)
_common.run(main, p)
