"""The ``dtid`` command: one subcommand per module in :mod:`dtid.cli.commands`.

A user's mistake (a bad file, option or recording) ends as a one-line ``error: ...`` on stderr
and exit status 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from types import ModuleType

from dtid.errors import DtidError

COMMAND_NAMES = (
    "demo",
    "simulate",
    "inspect",
    "frf",
    "identify",
    "diagnose",
    "report",
    "batch",
    "plan",
    "profile",
    "acquire",
    "worker",
    "monitor",
    "vehicle",
    "keys",
)
"""The subcommands, in the order ``dtid -h`` lists them: one module each in
:mod:`dtid.cli.commands`, imported by :func:`command_modules` inside :func:`main` (numpy, scipy
and numba take seconds to load, and a Ctrl-C meanwhile must end as "interrupted", not as a
traceback)."""
EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def command_modules() -> tuple[ModuleType, ...]:
    """The subcommands' modules, in the order of :data:`COMMAND_NAMES`."""
    return tuple(importlib.import_module(f"dtid.cli.commands.{name}") for name in COMMAND_NAMES)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``dtid`` with all subcommands."""
    parser = argparse.ArgumentParser(
        prog="dtid",
        description="Chirp-test drivetrain identification over CAN (drivetrain-id).",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more detail")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in command_modules():
        command.add_parser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``dtid`` with the given arguments; return the exit status."""
    try:
        args = build_parser().parse_args(argv)
    except KeyboardInterrupt:  # while the commands' libraries load
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args.run(args) or 0)
    except DtidError as error:
        if args.debug:
            raise
        print(f"error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader went away (`dtid inspect X | head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
