"""Stage `restoration_goals`: results/restoration_goals.md, issue 11's goals for event
restoration against what the study measured (metrics/restoration.json of stage `restoration`,
metrics/restoration_circuit.json of stage `restoration_circuit`, results/restore_real/summary.json
of stage `restore_real`; rdnet.study.goals).
`python stages/restoration_goals.py --sync-readme` copies the table into README.md."""
import json
from pathlib import Path

import _common


def _load(path: Path) -> dict:
    from rdnet.errors import FormatError
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise FormatError(path, None, "no such file (run its stage first)") from None
    except json.JSONDecodeError as e:
        raise FormatError(path, None, f"not JSON ({e})") from None


def main(args, params):
    from rdnet.study.goals import GOALS_END, GOALS_START, goals_table
    from rdnet.study.report import sync_readme
    if args.sync_readme:
        changed = sync_readme(Path("README.md"), args.out.read_text(), GOALS_START, GOALS_END)
        print("README.md updated" if changed else "README.md already up to date")
        return
    from rdnet.eval.report import write_text_atomic
    table = goals_table(_load(args.restoration), _load(args.real), _load(args.circuit),
                        sources=(args.restoration, args.real, args.circuit))
    write_text_atomic(args.out, table)


p = _common.parser(__doc__)
p.add_argument("--restoration", type=Path, default=Path("metrics/restoration.json"))
p.add_argument("--circuit", type=Path, default=Path("metrics/restoration_circuit.json"))
p.add_argument("--real", type=Path, default=Path("results/restore_real/summary.json"))
p.add_argument("--out", type=Path, default=Path("results/restoration_goals.md"))
p.add_argument("--sync-readme", action="store_true", help="copy --out into README.md between its markers")
_common.run(main, p)
