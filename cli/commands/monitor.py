"""``dtid monitor``: the test driver's live view of a running test, in the terminal.

Subscribes to the daemon's event stream (catching up from its replay, so it may start at any
time) and to the worker's results, and redraws one page: phase and test time left, speed and
torque, the frame and error counters, |G_DRV| of each finished chirp, the identification's
progress and result, the diagnosis, and how the test ended with the abort's reason. Plain text
with ANSI cursor codes: it works over SSH and in tmux. It only reads; Ctrl-C leaves it.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from dtid.acquisition.config import load_config
from dtid.cli.commands.common import at_most
from dtid.identification.service.monitor import run_monitor

MAX_REFRESH_S = 10.0
"""Slowest redraw: a test's phase lasts seconds (a refresh of 500 was 500 ms typed as s, and one
above 2.1e6 s overflowed ZeroMQ's poll)."""


refresh = at_most(MAX_REFRESH_S, "the period is in seconds: 0.5 redraws twice a second", " s")
"""argparse type: the redraw period, s, in (0, :data:`MAX_REFRESH_S`]."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "monitor", help="live terminal view of a running test", description=__doc__
    )
    parser.add_argument("--config", type=Path, help="configuration file (TOML; default: defaults)")
    parser.add_argument(
        "--refresh", type=refresh, default=0.5, metavar="S", help="redraw period, s"
    )
    parser.add_argument(
        "--until-finished",
        action="store_true",
        help="exit once the test has ended and the worker has said its last word on it",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Show the view."""
    config = load_config(args.config)
    return run_monitor(
        config.pipeline,
        refresh_s=args.refresh,
        until_finished=args.until_finished,
        width=lambda: shutil.get_terminal_size((100, 40)).columns,
    )
