"""Stage `evaluate@<row>`: score one ablation row on the test pairs (params: ablation.rows.<row>,
study.seeds): trained rows once per training seed, reported as mean and spread.
Writes the compact metrics (psnr, ssim, ...) for `dvc metrics show` and the details
(per-level and per-degradation breakdowns, per-sample values) beside them."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.study.rows import evaluate_ablation_row
    cfg = section(params, "ablation")
    seeds = section(params, "study").seeds
    res = evaluate_ablation_row(cfg, args.row, args.pairs, args.events_dir, seeds=seeds)
    compact = {k: res[k] for k in ("psnr", "psnr_std", "ssim", "ssim_std", "n", "n_images", "still_excluded",
                                   "paper_psnr")
               if res.get(k) is not None}
    compact["n_seeds"] = len(res["seeds"])
    _common.write_json(args.out, compact)
    _common.write_json(args.details, res)


p = _common.parser(__doc__)
p.add_argument("--row", required=True)
p.add_argument("--pairs", type=Path, default=Path("data/pairs/test.h5"))
p.add_argument("--events-dir", type=Path, default=Path("data/events/test"))
p.add_argument("--out", type=Path, required=True)
p.add_argument("--details", type=Path, required=True)
_common.run(main, p)
