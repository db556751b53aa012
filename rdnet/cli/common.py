"""Arguments shared by subcommands (``--params``, ``--set``, ``--seed``)."""
from __future__ import annotations

import argparse
from pathlib import Path


def add_params_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", type=Path, default=None,
                   help="params.yaml to read (default: ./params.yaml if present, else built-in defaults)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a params.yaml key (repeatable), e.g. degrade.refractory_us=500")


def load_cli_params(args) -> dict:
    from rdnet.config import load_params
    path = args.params
    if path is None and Path("params.yaml").is_file():
        path = Path("params.yaml")
    return load_params(path, args.sets)
