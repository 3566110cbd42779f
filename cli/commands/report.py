"""``dtid report``: one self-contained HTML page of a test, to forward.

From a session directory (the daemon's log with its metadata, the worker's
``identification.json`` and ``diagnosis.json``) or from recordings (with the JSONs of
``dtid identify`` and ``dtid diagnose`` beside them or given): the test, its FRFs as the paper's
Fig. 3, the fit as Fig. 6, the profiles as Fig. 5, the diagnosis's mismatch map, the parameter
table with intervals and verdicts, and the software and data versions. Figures are embedded: the
file opens without a network.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from dtid.cli.commands.common import add_interface_options, output_file
from dtid.dbc.loader import load_interface
from dtid.identification.html_report import REPORT_FILE, gather, write_report


def html_file(text: str) -> Path:
    """argparse type: the report's page (:func:`output_file`), named .html or .htm."""
    path = output_file(text)
    if path.suffix.lower() not in (".html", ".htm"):
        raise argparse.ArgumentTypeError(f"the report is one HTML page: name it .html, not {text}")
    return path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "report", help="write a test's report as one HTML file", description=__doc__
    )
    parser.add_argument(
        "paths",
        type=Path,
        nargs="+",
        metavar="SESSION_DIR|RECORDING",
        help="a session directory, or the recordings of one test",
    )
    parser.add_argument(
        "-o",
        "--output",
        type=html_file,
        help=f"the HTML file (default: {REPORT_FILE} in the session directory, or beside the "
        "first recording)",
    )
    parser.add_argument(
        "--identification", type=Path, metavar="ID.json", help="dtid identify's JSON to report"
    )
    parser.add_argument(
        "--diagnosis",
        type=Path,
        metavar="DIAGNOSIS.json",
        help="dtid diagnose's JSON to report (its figure: the PNG of the same name beside it)",
    )
    add_interface_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Write the report."""
    interface = load_interface(args.dbc, args.signals)
    inputs = gather(args.paths, interface, args.identification, args.diagnosis)
    first = args.paths[0]
    output = args.output or (first if first.is_dir() else first.parent) / REPORT_FILE
    path = write_report(inputs, output)
    print(f"report: {path}")
    return 0
