"""Stage `calibration_proof`: run `calibrate` blind on recordings in which one effect is
present but concealed (plus null cases), and score what it names (params: calibrate). The
"real" events come from two generators: rdnet's own simulator (top-level metrics, and again
with the true events simulated from 4x denser frames: block `oversample4`) and the
independent circuit model of rdnet.circuit (block `circuit`). Over all blocks, the
reliability of the confidences (rdnet.calib.reliability: binned confidence, count, fraction
right, ECE) goes to the metrics (`reliability`) and to `reliability.md`."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.calib import reliability as rel
    from rdnet.calib.calibrate import calibration_interpolation
    from rdnet.calib.proof import Block, format_table, generator_blocks, run_blocks
    from rdnet.config import section
    from rdnet.eval.report import write_text_atomic
    cfg = section(params, "calibrate")
    interp = calibration_interpolation(cfg)       # the scenes upsampled as the calibration will
    # every block from a fresh default_rng(seed): rdnet reports in args.out, circuit in args.out/circuit
    todo = generator_blocks(args.out, generator=args.generator, quick=args.quick, names=args.cases, cfg=cfg,
                            interpolate=interp, circuit_oversample=args.circuit_oversample,
                            truth_warmup_us=args.truth_warmup_us, truth_preroll_us=args.truth_preroll_us)
    rd = next((b for b in todo if b.key == "rdnet"), None)
    if rd is not None and args.oversample > 1:
        # the truth from frames rendered denser: the calibration's own interpolation is imperfect
        key = f"oversample{args.oversample}"
        todo.append(Block(key, rd.cases, args.out / key, only=rd.only, kw=dict(cfg=cfg, interpolate=interp, oversample=args.oversample,
                                                              truth_warmup_us=args.truth_warmup_us,
                                                              truth_preroll_us=args.truth_preroll_us)))
    # the cases of all blocks share the workers, the slow circuit cases first
    runs = run_blocks(todo, args.seed, workers=args.workers)
    blocks = {b.key: (b.out_dir, runs[b.key]) for b in todo}
    compact = {}
    for key, (folder, m) in blocks.items():
        write_text_atomic(folder / "proof.md", format_table(m) + "\n")
        if key == "rdnet":
            compact.update(_compact(m))
        else:
            compact[key] = _compact(m)
    rows = [r for key, (folder, m) in blocks.items() for r in rel.block_rows(folder, m, key)]
    result = rel.reliability(rows)
    compact["reliability"] = rel.compact(result)
    write_text_atomic(args.out / "reliability.md", rel.markdown(result, str(args.out)))
    _common.write_json(args.metrics, compact)


def _compact(m):
    return {"summary": m["summary"],
            "cases": {r["case"]: {"named_right": r["outcome"] == "right" if r["true_effect"] else not r["named"],
                                  "named": r["named"], "rank": r["rank"],
                                  "param_max_rel_error": r.get("param_max_rel_error"),
                                  "heldout_before": r["heldout_before"], "heldout_after": r["heldout_after"]}
                      for r in m["cases"]}}


def _parser():
    from rdnet.calib.proof import add_proof_arguments
    p = _common.parser(__doc__)
    add_proof_arguments(p)
    p.add_argument("--oversample", type=int, default=4,
                   help="also run the rdnet proof with the truth from frames this many times denser (1: skip)")
    p.add_argument("--workers", type=int, default=2,
                   help="cases run at once, one process each (results do not depend on it)")
    p.add_argument("--cases", nargs="+", default=None,
                   help="only these cases (their names in the reports; default: all), each with the draws "
                        "it gets in the whole proof (benchmarks/proof_variant.py)")
    p.add_argument("--out", type=Path, default=Path("results/calibration/proof"))
    p.add_argument("--metrics", type=Path, default=Path("metrics/calibration_proof.json"))
    return p


_common.run(main, _parser())
