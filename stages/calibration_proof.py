"""Stage `calibration_proof`: run `calibrate` blind on recordings in which one effect is
present but concealed (plus null cases), and score what it names (params: calibrate); then
again with the true events simulated from 4x denser frames (metrics block `oversample4`)."""
from pathlib import Path

import _common


def main(args, params):
    import numpy as np

    from rdnet.calib.proof import format_table, run_proof
    from rdnet.config import section
    from rdnet.sim.interpolate import InterpolateConfig
    cfg = section(params, "calibrate")
    interp = InterpolateConfig(max_upsample=cfg.max_upsample)
    m = run_proof(None, args.out, np.random.default_rng(args.seed), cfg=cfg, interpolate=interp)
    (args.out / "proof.md").write_text(format_table(m) + "\n")
    compact = _compact(m)
    if args.oversample > 1:
        # the truth from frames rendered denser: the calibration's own interpolation is imperfect
        key = f"oversample{args.oversample}"
        mo = run_proof(None, args.out / key, np.random.default_rng(args.seed), cfg=cfg, interpolate=interp,
                       oversample=args.oversample)
        (args.out / key / "proof.md").write_text(format_table(mo) + "\n")
        compact[key] = _compact(mo)
    _common.write_json(args.metrics, compact)


def _compact(m):
    return {"summary": m["summary"],
            "cases": {r["case"]: {"named_right": r["outcome"] == "right" if r["true_effect"] else not r["named"],
                                  "named": r["named"], "rank": r["rank"],
                                  "param_max_rel_error": r.get("param_max_rel_error"),
                                  "heldout_before": r["heldout_before"], "heldout_after": r["heldout_after"]}
                      for r in m["cases"]}}


p = _common.parser(__doc__)
p.add_argument("--seed", type=int, default=2024)
p.add_argument("--oversample", type=int, default=4,
               help="also run the proof with the truth from frames this many times denser (1: skip)")
p.add_argument("--out", type=Path, default=Path("results/calibration/proof"))
p.add_argument("--metrics", type=Path, default=Path("metrics/calibration_proof.json"))
_common.run(main, p)
