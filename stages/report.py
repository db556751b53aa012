"""Stage `report`: results/ablation.md (table from the metrics, with the paper's numbers
and gaps, and the same on the independent circuit generator's events) and figures (PSNR per
row, PSNR against degradation level, sample grid). `python stages/report.py --sync-readme`
copies that table and results/calibration_goals.md (stage `calibration_goals`) into README.md,
and results/restore_real/summary.md (stage `restore_real`) into docs/cli.md."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.study.report import (CALIBRATION_END, CALIBRATION_START, RESTORE_REAL_END, RESTORE_REAL_START,
                                    sync_readme, write_report)
    rows = (params.get("ablation") or {}).get("rows", {})
    order = list(rows)
    if args.sync_readme:      # calibration_goals.md: the calibration_goals stage's
        changed = sync_readme(Path("README.md"), (args.out / "ablation.md").read_text())
        changed |= sync_readme(Path("README.md"), (args.out / "calibration_goals.md").read_text(),
                               CALIBRATION_START, CALIBRATION_END)
        changed |= sync_readme(Path("docs/cli.md"), Path("results/restore_real/summary.md").read_text(),
                               RESTORE_REAL_START, RESTORE_REAL_END)
        print("README.md / docs/cli.md updated" if changed else "README.md and docs/cli.md already up to date")
        return
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
p.add_argument("--pairs", type=Path, default=Path("data/pairs/test.h5"))
p.add_argument("--out", type=Path, default=Path("results"))
p.add_argument("--samples", action="store_true", help="also draw results/samples.png")
p.add_argument("--sync-readme", action="store_true")
_common.run(main, p)
