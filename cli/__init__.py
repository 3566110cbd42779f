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
    add_global_options(parser, False)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in command_modules():
        command.add_parser(subparsers)
    for subparser in subparsers.choices.values():  # `dtid identify REC --debug` too
        add_global_options(subparser, argparse.SUPPRESS)
    return parser


def add_global_options(parser: argparse.ArgumentParser, default: object) -> None:
    """``--debug`` and ``-v``, before the command or after it (``default`` SUPPRESS there, so
    that the command's parser leaves what was given before it)."""
    parser.add_argument(
        "--debug", action="store_true", default=default, help="show tracebacks of errors"
    )
    parser.add_argument(
        "-v", "--verbose", action="store_true", default=default, help="log more detail"
    )


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
        from dtid.cli.commands.common import check_written_over

        check_written_over(args)
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
