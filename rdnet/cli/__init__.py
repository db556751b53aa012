"""``rdnet`` command line. Each subcommand is a module with ``register(subparsers)``;
:data:`COMMANDS` lists them in help order (short names live in this package).

User errors (:class:`rdnet.errors.RdnetError`) print one line and exit with code 2.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from rdnet import __version__
from rdnet.errors import RdnetError

COMMANDS = ["info", "convert", "simulate", "calibrate", "restore", "deblur", "rdnet.train.run"]

log = logging.getLogger("rdnet")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rdnet", description="Simulate, restore and deblur with real-world degraded events.")
    parser.add_argument("--version", action="version", version=f"rdnet {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        mod = name if "." in name else f"rdnet.cli.{name}"
        importlib.import_module(mod).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        rc = args.func(args)
    except RdnetError as e:
        print(f"rdnet {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of stdout went away (`rdnet info rec.h5 | head -1`): as a Unix tool does,
        # stop quietly; stdout is pointed at /dev/null so the interpreter's final flush
        # does not raise again
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (AttributeError, OSError, ValueError):   # a stdout that is no file (tests, embedding)
            pass
        return 141
    return int(rc or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
