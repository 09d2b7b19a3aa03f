"""frictionwatch command line: one small module per subcommand (after python-can's can/cli.py).

Every expected failure (bad engine file, unknown effect, unreadable log) ends with ONE line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import NoReturn

from frictionwatch.core.model.engine import SpecError
from frictionwatch.drivers.errors import DriverError
from frictionwatch.service.store.columns import StoreError

COMMANDS = {
    "simulate": "frictionwatch.service.cmd_simulate",
    "analyze": "frictionwatch.service.cmd_analyze",
    "import-daq": "frictionwatch.service.cmd_import_daq",
    "trace": "frictionwatch.service.cmd_trace",
    "serve": "frictionwatch.service.serve",
    "reanalyze": "frictionwatch.service.cmd_reanalyze",
    "discrepancy": "frictionwatch.service.cmd_discrepancy",
    "commission": "frictionwatch.service.cmd_commission",
}


class UsageError(Exception):
    """A problem the user can fix; printed as one line, exit code 2."""


class OneLineParser(argparse.ArgumentParser):
    """argparse with its errors as ONE line naming the option (no usage block), exit code 2 as argparse has it.
    Subparsers inherit the class (``add_subparsers`` makes them with ``type(parent)``), so ``prog`` names the
    subcommand: 'frictionwatch simulate: error: argument --seed: invalid int value: 'x''."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="frictionwatch", description="Per-cylinder engine friction monitor")
    parser.add_argument("-v", "--verbose", action="store_true", help="log warnings and details to stderr")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS.values():
        importlib.import_module(module).add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR, format="%(levelname)s %(message)s")
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:  # e.g. `frictionwatch analyze LOG | head`: the reader left, that is not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (UsageError, SpecError, DriverError, StoreError, ValueError, OSError) as exc:
        if args.verbose:
            raise
        print(f"frictionwatch {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
