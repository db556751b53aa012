"""Stage `restoration_circuit`: the restoration table of the test split rendered by the
independent circuit generator (rdnet.study.independent): the truth and the degraded events
from a pixel model that shares no code with rdnet's simulator, scored as `restoration` scores
the simulated split, and every ablation row scored on those events with its gap to row 2
(metrics/restoration_circuit.json, results/restoration_circuit.md)."""
import json
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.eval.report import write_text_atomic
    from rdnet.study.independent import circuit_restoration, markdown
    from rdnet.study.rows import LEARNED_RESTORERS
    learned = {k: Path(v) for k, v in LEARNED_RESTORERS.items() if Path(v).exists()}
    ablation = section(params, "ablation")
    rows = tuple(r for r in ablation.rows if not ablation.row(r).checkpoint or Path(ablation.row(r).checkpoint).exists())
    res = circuit_restoration(params, args.events, learned, draws=section(params, "study").circuit_draws,
                              seed=int(params.get("seed", 0)), ednccn=args.ednccn if args.ednccn.exists() else None,
                              rows=rows)
    _common.write_json(args.out, res)
    study = json.loads(args.study.read_text()) if args.study.exists() else None
    study_rows = {r: json.loads((args.rows / f"{r}.json").read_text()) for r in rows if (args.rows / f"{r}.json").exists()}
    write_text_atomic(args.table, markdown(res, study, study_rows))


p = _common.parser(__doc__)
p.add_argument("--events", type=Path, default=Path("data/events"), help="the study's event files (test split read)")
p.add_argument("--ednccn", type=Path, default=Path("models/ednccn"))
p.add_argument("--study", type=Path, default=Path("metrics/restoration.json"),
               help="the simulated split's table, quoted beside (optional)")
p.add_argument("--rows", type=Path, default=Path("results/rows"), help="the study's per-row results, quoted beside")
p.add_argument("--out", type=Path, default=Path("metrics/restoration_circuit.json"))
p.add_argument("--table", type=Path, default=Path("results/restoration_circuit.md"))
_common.run(main, p)
