"""``dtid batch``: a fleet's tests identified in parallel on Dask, one table, a fleet view.

Each argument is one test: a session directory (its recordings) or one recording. Every test is
identified as ``dtid identify`` does (and with ``--diagnose`` located as ``dtid diagnose
--mechanisms`` does), on a local Dask cluster (``--workers`` processes) or on an existing Dask
scheduler (``--scheduler``). Writes ``OUT/fleet.csv`` (vehicle, date, parameters, intervals,
verdicts, NRMSEs per test), ``OUT/tests/*.json``, and the fleet view ``OUT/fleet.png`` /
``OUT/fleet.html`` (trends per vehicle, outliers against the fleet). Needs Dask:
``pip install 'drivetrain-id[fleet]'``. Exit status 0: every test identified; 1: one or more
failed (their rows say why; the table and view are written all the same); 2: usage error.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from dtid.batch import TABLE, BatchOptions, find_tests, run_batch
from dtid.cli.commands.common import add_interface_options, add_vehicle_option
from dtid.cli.commands.identify import (
    add_bounds_options,
    add_search_options,
    fixed_and_bounds,
    search_settings,
)
from dtid.errors import ConfigError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "batch", help="identify many tests in parallel on Dask; fleet table and view",
        description=__doc__,
    )  # fmt: skip
    parser.add_argument(
        "tests", type=Path, nargs="+", metavar="SESSION_DIR|RECORDING", help="one test each"
    )
    parser.add_argument(
        "--scheduler", metavar="ADDRESS", help="an existing Dask scheduler (default: local)"
    )
    parser.add_argument(
        "--workers", type=int, default=2, help="processes of the local cluster (default: 2)"
    )
    parser.add_argument(
        "--out", type=Path, default=Path("dtid-batch"), help="output folder (default: dtid-batch)"
    )
    parser.add_argument(
        "--diagnose", action="store_true", help="also locate where each model misses its test"
    )
    parser.add_argument(
        "--fix", nargs="+", default=[], metavar="NAME=VALUE", help="hold parameters (as identify)"
    )
    add_interface_options(parser)
    add_vehicle_option(parser)
    add_bounds_options(parser)
    add_search_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run the batch and print a line per test."""
    if args.workers < 1:
        raise ConfigError("--workers must be at least 1")
    fixed, bounds = fixed_and_bounds(args)
    options = BatchOptions(
        dbc=args.dbc,
        signals=args.signals,
        vehicle=args.vehicle,
        prior=args.prior,
        fixed=fixed,
        bounds=bounds,
        span=None if args.span is None else args.span / 100,
        settings=search_settings(args),
        profile_points=args.profile_points,
        diagnose=args.diagnose,
    )
    tests = find_tests(args.tests)
    logging.getLogger("distributed").setLevel(logging.WARNING)  # its INFO lines, not ours
    rows = run_batch(tests, options, args.out, args.scheduler, args.workers, report=print)
    failed = sum(row["status"] != "ok" for row in rows)
    print(f"{len(rows)} test(s), {failed} failed: {args.out / TABLE}, {args.out / 'fleet.html'}")
    return 1 if failed else 0
