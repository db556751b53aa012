"""Stage `calibration_proof`: run `calibrate` blind on recordings in which one effect is
present but concealed (plus null cases), and score what it names (params: calibrate)."""
from pathlib import Path

import _common


def main(args, params):
    import numpy as np

    from rdnet.calib.proof import format_table, run_proof
    from rdnet.config import section
    from rdnet.sim.interpolate import InterpolateConfig
    cfg = section(params, "calibrate")
    m = run_proof(None, args.out, np.random.default_rng(args.seed), cfg=cfg,
                  interpolate=InterpolateConfig(max_upsample=cfg.max_upsample))
    (args.out / "proof.md").write_text(format_table(m) + "\n")
    compact = {"summary": m["summary"],
               "cases": {r["case"]: {"named_right": r["outcome"] == "right" if r["true_effect"] else not r["named"],
                                     "rank": r["rank"], "param_max_rel_error": r.get("param_max_rel_error"),
                                     "heldout_before": r["heldout_before"], "heldout_after": r["heldout_after"]}
                         for r in m["cases"]}}
    _common.write_json(args.metrics, compact)


p = _common.parser(__doc__)
p.add_argument("--seed", type=int, default=2024)
p.add_argument("--out", type=Path, default=Path("results/calibration/proof"))
p.add_argument("--metrics", type=Path, default=Path("metrics/calibration_proof.json"))
_common.run(main, p)
