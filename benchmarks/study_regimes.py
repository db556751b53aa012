"""Regime sweep of the RDNet row (issue "DVC study": where does restoration pay off?).

For each variant of ``rdnet.study.regimes.VARIANTS`` (one params change each: more
training scenes, wider networks, larger crops, more iterations) it trains rows 1-4's
networks and RDNet once per seed of ``study.seeds`` and scores them on the study's test
set, next to the committed study (``results/rows``). Needs the study's data first:

    .venv/bin/dvc repro blur
    .venv/bin/python benchmarks/study_regimes.py                       # every variant (hours on 2 cores)
    .venv/bin/python benchmarks/study_regimes.py --variants data_x4 --parallel 2
    .venv/bin/python benchmarks/study_regimes.py --report-only      # table + figure, after `dvc repro`

Results are merged variant by variant into ``benchmarks/results/rdnet_regimes.json``, with
``rdnet_regimes.md`` (the table docs/study.md quotes) and ``rdnet_regimes.png``. Networks
live in ``data/regimes/<variant>/models`` (not in git); a rerun resumes or skips them.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rdnet.config import load_params  # noqa: E402
from rdnet.errors import RdnetError  # noqa: E402
from rdnet.eval.report import write_text_atomic  # noqa: E402
from rdnet.study import regimes  # noqa: E402

log = logging.getLogger("study_regimes")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", nargs="+", choices=sorted(regimes.VARIANTS), default=list(regimes.VARIANTS))
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--parallel", type=int, default=None, help="trainings at once (default study.parallel)")
    ap.add_argument("--data", type=Path, default=ROOT / "data", help="the study's data (dvc repro blur)")
    ap.add_argument("--work", type=Path, default=ROOT / "data" / "regimes")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "rdnet_regimes.json")
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite the .md/.png from the JSON and the committed study (no training)")
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        base = load_params(a.params)
        done = json.loads(a.out.read_text()) if a.out.is_file() else {}
        variants = dict(done.get("variants", {}))
        for name in [] if a.report_only else a.variants:
            t0 = time.perf_counter()
            res = regimes.run_variant(name, regimes.VARIANTS[name], base, data_dir=a.data, work=a.work,
                                      parallel=a.parallel, progress=not a.no_progress)
            res["wall_s"] = round(time.perf_counter() - t0, 1)
            res["load_average_1min_after"] = os.getloadavg()[0]
            variants[name] = res
            log.info("%s: RDNet - row 2 = %+.2f dB", name, res["gaps"]["rdnet_minus_row2"]["mean"])
            _write(a.out, base, variants)
        if a.report_only:
            _write(a.out, base, variants)
    except RdnetError as e:
        print(f"study_regimes: error: {e}", file=sys.stderr)
        return 2
    return 0


def _write(out: Path, base: dict, variants: dict) -> None:
    ref = regimes.study_reference(ROOT / "results" / "rows", ROOT / "metrics" / "restoration.json")
    order = {n: i for i, n in enumerate(regimes.VARIANTS)}
    variants = dict(sorted(variants.items(), key=lambda kv: order.get(kv[0], len(order))))
    table = ({"study": ref} if ref else {}) | variants
    doc = {"benchmark": "rdnet_regimes", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                     "platform": platform.platform()},
           "seeds": list(base["study"]["seeds"]), "reference": ref, "variants": variants}
    write_text_atomic(out, json.dumps(doc, indent=2) + "\n")
    write_text_atomic(out.with_suffix(".md"), regimes.markdown(table))
    regimes.plot(table, out.with_suffix(".png"))


if __name__ == "__main__":
    sys.exit(main())
