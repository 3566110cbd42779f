"""``dtid worker``: estimate FRFs and identify the parameters while the daemon runs the test.

Consumes the acquisition daemon's event stream (``[pipeline] blocks``, catching up from
``[pipeline] replay``), publishes progress, each chirp's FRF and the result on
``[pipeline] results``, and writes the result (the JSON of ``dtid identify``) and the Fig. 6 plot
beside the session's log. The identification uses the search settings of ``dtid identify`` and
gives what ``dtid identify`` gives on the daemon's log.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from acquisition.config import load_config
from dtid.commands.identify import add_search_options, print_report, search_settings
from identification.worker import Worker, WorkerOptions
from simulator.parameters import load_parameters


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "worker",
        help="identify from the acquisition daemon's stream while the test runs",
        description=__doc__,
    )
    parser.add_argument("--config", type=Path, help="configuration file (TOML; default: defaults)")
    parser.add_argument("--once", action="store_true", help="exit after one session has ended")
    parser.add_argument(
        "--prior",
        type=Path,
        help="parameter set (TOML) the default +-100 %% bounds centre on (default: reference)",
    )
    add_search_options(parser)
    parser.add_argument(
        "--json", type=Path, help="result file (default: identification.json beside the log)"
    )
    parser.add_argument(
        "--plot", type=Path, help="Fig. 6 plot (default: identification.png beside the log)"
    )
    parser.add_argument("--no-plot", action="store_true", help="do not plot")
    parser.set_defaults(run=run)


def _terminal(topic: str, document: dict[str, Any]) -> None:
    """One line per stage change on stderr; the result's parameters on stdout."""
    if topic == "frf":
        print(f"FRF: {document['amplitude_nm']:g} N*m", file=sys.stderr)
    elif topic == "progress" and "search" not in document:
        detail = document.get("message") or ""
        files = ", ".join(document.get("files", []))
        data = document.get("data_s")
        data_text = f" {data:.1f} s of data" if data is not None else ""
        print(
            f"{document['session']}: {document['stage']}{data_text} {detail}{files}",
            file=sys.stderr,
        )


def run(args: argparse.Namespace) -> int:
    """Serve sessions until SIGINT/SIGTERM (or one session with --once)."""
    settings = search_settings(args)
    config = load_config(args.config)
    options = WorkerOptions(
        settings=settings,
        profile_points=args.profile_points,
        prior=load_parameters(args.prior) if args.prior else None,
        json_path=args.json,
        plot_path=args.plot,
        plot=not args.no_plot,
    )
    worker = Worker(config.pipeline, options)
    worker.listeners.append(_terminal)
    reports = []
    worker.listeners.append(lambda topic, doc: reports.append(doc) if topic == "result" else None)
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        status = worker.serve(once=args.once, stop=stop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    for document in reports:
        print_report(document, {})
    return status
