"""Stage `calibration_proof`: run `calibrate` blind on recordings in which one effect is
present but concealed (plus null cases), and score what it names (params: calibrate). The
"real" events come from two generators: rdnet's own simulator (top-level metrics, and again
with the true events simulated from 4x denser frames: block `oversample4`) and the
independent circuit model of rdnet.circuit (block `circuit`)."""
from pathlib import Path

import _common


def main(args, params):
    import numpy as np

    from rdnet.calib.proof import cases_for, format_table, run_proof
    from rdnet.config import section
    from rdnet.sim.interpolate import InterpolateConfig
    cfg = section(params, "calibrate")
    interp = InterpolateConfig(max_upsample=cfg.max_upsample)
    lists = cases_for(args.generator, args.quick)
    compact = {}
    if "rdnet" in lists:
        m = run_proof(lists["rdnet"], args.out, np.random.default_rng(args.seed), cfg=cfg, interpolate=interp)
        (args.out / "proof.md").write_text(format_table(m) + "\n")
        compact = _compact(m)
        if args.oversample > 1:
            # the truth from frames rendered denser: the calibration's own interpolation is imperfect
            key = f"oversample{args.oversample}"
            mo = run_proof(lists["rdnet"], args.out / key, np.random.default_rng(args.seed), cfg=cfg,
                           interpolate=interp, oversample=args.oversample)
            (args.out / key / "proof.md").write_text(format_table(mo) + "\n")
            compact[key] = _compact(mo)
    if "circuit" in lists:
        # an independent sensor model (rdnet.circuit) makes the true events
        mc = run_proof(lists["circuit"], args.out / "circuit", np.random.default_rng(args.seed), cfg=cfg,
                       interpolate=interp, circuit_oversample=args.circuit_oversample)
        (args.out / "circuit" / "proof.md").write_text(format_table(mc) + "\n")
        compact["circuit"] = _compact(mc)
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
               help="also run the rdnet proof with the truth from frames this many times denser (1: skip)")
p.add_argument("--circuit-oversample", type=int, default=4,
               help="circuit truth from frames this many times denser than the recorded ones")
p.add_argument("--generator", choices=("rdnet", "circuit", "both"), default="both",
               help="model of the true events")
p.add_argument("--quick", action="store_true", help="only a small subset (rdnet.calib.proof.QUICK)")
p.add_argument("--out", type=Path, default=Path("results/calibration/proof"))
p.add_argument("--metrics", type=Path, default=Path("metrics/calibration_proof.json"))
_common.run(main, p)
