"""Stage `report`: results/ablation.md (table from the metrics, with the paper's numbers
and gaps, and the same on the independent circuit generator's events), figures (PSNR per
row, PSNR against degradation level, sample grid) and results/calibration_goals.md (the
calibration proof against issue 12's goals, from metrics/calibration_proof.json).
`python stages/report.py --sync-readme` copies both tables into README.md."""
from pathlib import Path

import _common


def main(args, params):
    import json

    from rdnet.calib.proof import goals_table
    from rdnet.eval.report import write_text_atomic
    from rdnet.study.report import CALIBRATION_END, CALIBRATION_START, sync_readme, write_report
    rows = (params.get("ablation") or {}).get("rows", {})
    order = list(rows)
    goals = args.out / "calibration_goals.md"
    if args.sync_readme:
        changed = sync_readme(Path("README.md"), (args.out / "ablation.md").read_text())
        changed |= sync_readme(Path("README.md"), goals.read_text(), CALIBRATION_START, CALIBRATION_END)
        print("README.md updated" if changed else "README.md already up to date")
        return
    write_text_atomic(goals, goals_table(json.loads(args.calibration.read_text())))
    write_report(args.details, args.restoration, args.out, order,
                 checkpoints={rid: r.get("checkpoint") for rid, r in rows.items()}, circuit_path=args.circuit)
    if args.samples:
        from rdnet.study.figures import sample_figure
        sample_figure(params, args.pairs, args.out / "samples.png")


p = _common.parser(__doc__)
p.add_argument("--details", type=Path, default=Path("results/rows"))
p.add_argument("--restoration", type=Path, default=Path("metrics/restoration.json"))
p.add_argument("--circuit", type=Path, default=Path("metrics/restoration_circuit.json"),
               help="the rows on the independent generator's events (a column when present)")
p.add_argument("--calibration", type=Path, default=Path("metrics/calibration_proof.json"),
               help="the calibration_proof stage's metrics (results/calibration_goals.md)")
p.add_argument("--pairs", type=Path, default=Path("data/pairs/test.h5"))
p.add_argument("--out", type=Path, default=Path("results"))
p.add_argument("--samples", action="store_true", help="also draw results/samples.png")
p.add_argument("--sync-readme", action="store_true")
_common.run(main, p)
