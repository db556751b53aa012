"""Stage `restoration_circuit`: the restoration table of the test split rendered by the
independent circuit generator (rdnet.study.independent): the truth and the degraded events
from a pixel model that shares no code with rdnet's simulator, scored as `restoration` scores
the simulated split (metrics/restoration_circuit.json, results/restoration_circuit.md)."""
import json
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.eval.report import write_text_atomic
    from rdnet.study.independent import circuit_restoration, markdown
    from rdnet.study.rows import LEARNED_RESTORERS
    learned = {k: Path(v) for k, v in LEARNED_RESTORERS.items() if Path(v).exists()}
    res = circuit_restoration(params, args.events_dir.parent, learned, draws=section(params, "study").circuit_draws,
                              seed=int(params.get("seed", 0)), ednccn=args.ednccn if args.ednccn.exists() else None)
    _common.write_json(args.out, res)
    study = json.loads(args.study.read_text()) if args.study.exists() else None
    write_text_atomic(args.table, markdown(res, study))


p = _common.parser(__doc__)
p.add_argument("--events-dir", type=Path, default=Path("data/events/test"))
p.add_argument("--ednccn", type=Path, default=Path("models/ednccn"))
p.add_argument("--study", type=Path, default=Path("metrics/restoration.json"),
               help="the simulated split's table, quoted beside (optional)")
p.add_argument("--out", type=Path, default=Path("metrics/restoration_circuit.json"))
p.add_argument("--table", type=Path, default=Path("results/restoration_circuit.md"))
_common.run(main, p)
