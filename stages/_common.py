"""Shared argument handling of the stage scripts (named arguments only)."""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # run as `python stages/x.py` from the repo root
    sys.path.insert(0, str(ROOT))


def parser(doc: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=doc)
    p.add_argument("--params", type=Path, default=Path("params.yaml"))
    return p


def run(main, p: argparse.ArgumentParser) -> None:
    """Parse, load params, call ``main(args, params)``; user errors exit 2 with one line."""
    from rdnet.config import load_params
    from rdnet.errors import RdnetError
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    args = p.parse_args()
    try:
        params = load_params(args.params)
        main(args, params)
    except RdnetError as e:
        print(f"{Path(sys.argv[0]).name}: error: {e}", file=sys.stderr)
        sys.exit(2)


def write_json(path: Path, data) -> None:
    """JSON with sorted keys, written atomically (rdnet's one atomic-write helper)."""
    from rdnet.eval.report import write_text_atomic
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True) + "\n")
