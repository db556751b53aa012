"""Stage `restoration_goals`: results/restoration_goals.md, issue 11's goals for event
restoration against what the study measured (metrics/restoration.json of stage `restoration`,
metrics/restoration_circuit.json of stage `restoration_circuit`, results/restore_real/summary.json
of stage `restore_real`, results/closed_loop/summary.json of stage `closed_loop`: the frame-pair
restorer at the camera's calibrated threshold; rdnet.study.goals).
`python stages/restoration_goals.py --sync-readme` copies the table into README.md."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.study.goals import GOALS_END, GOALS_START, goals_from_files
    from rdnet.study.report import sync_readme
    if args.sync_readme:
        changed = sync_readme(Path("README.md"), args.out.read_text(), GOALS_START, GOALS_END)
        print("README.md updated" if changed else "README.md already up to date")
        return
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(args.out, goals_from_files(args.restoration, args.real, args.circuit, args.closed_loop))


p = _common.parser(__doc__)
p.add_argument("--restoration", type=Path, default=Path("metrics/restoration.json"))
p.add_argument("--circuit", type=Path, default=Path("metrics/restoration_circuit.json"))
p.add_argument("--real", type=Path, default=Path("results/restore_real/summary.json"))
p.add_argument("--closed-loop", type=Path, default=Path("results/closed_loop/summary.json"))
p.add_argument("--out", type=Path, default=Path("results/restoration_goals.md"))
p.add_argument("--sync-readme", action="store_true", help="copy --out into README.md between its markers")
_common.run(main, p)
