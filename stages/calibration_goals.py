"""Stage `calibration_goals`: results/calibration_goals.md, the calibration proof against the
goals of issue 12 (one row per block and the total), from metrics/calibration_proof.json.
`python stages/report.py --sync-readme` copies it into README.md."""
import json
from pathlib import Path

import _common


def main(args, params):
    from rdnet.calib.proof import goals_table
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(args.out, goals_table(json.loads(args.metrics.read_text())))


p = _common.parser(__doc__)
p.add_argument("--metrics", type=Path, default=Path("metrics/calibration_proof.json"))
p.add_argument("--out", type=Path, default=Path("results/calibration_goals.md"))
_common.run(main, p)
