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

from dtid.acquisition.config import load_config
from dtid.cli import EXIT_INTERRUPTED
from dtid.cli.commands.common import add_vehicle_option, output_file, plot_file, vehicle_data
from dtid.cli.commands.diagnose import add_mechanisms_option
from dtid.cli.commands.identify import add_search_options, print_report, search_settings
from dtid.errors import ConfigError
from dtid.identification.planning.spread import DEFAULT_VEHICLES
from dtid.identification.service.worker import Worker, WorkerOptions, leave_a_core_to_the_bus
from dtid.simulator.parameters import load_parameters


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
        help="parameter set (TOML, as dtid identify --prior) the default +-100 %% bounds centre "
        "on (default: reference)",
    )
    add_vehicle_option(parser)
    add_search_options(parser)
    parser.add_argument(
        "--json",
        type=output_file,
        help="result file, with --once (default: identification.json beside the log)",
    )
    parser.add_argument(
        "--plot",
        type=plot_file,
        help="Fig. 6 plot, with --once (default: identification.png beside the log)",
    )
    parser.add_argument("--no-plot", action="store_true", help="do not plot")
    add_mechanisms_option(parser, " in the diagnosis ([worker] diagnose = true)")
    parser.add_argument(
        "--plan-vehicles",
        type=int,
        default=DEFAULT_VEHICLES,
        metavar="N",
        help="vehicles the follow-up and a campaign's next round are planned for besides the "
        "identified one, each parameter within twice the precision reached (dtid plan --after "
        f"--spread recorded; default: {DEFAULT_VEHICLES}; 0: the identified parameters alone)",
    )
    parser.set_defaults(run=run)


class _Terminal:
    """One line on stderr per stage or phase change and per FRF; each result on stdout."""

    def __init__(self) -> None:
        self.last: tuple[object, ...] = ()

    def __call__(self, topic: str, document: dict[str, Any]) -> None:
        if topic == "frf":
            print(f"FRF of the {document['amplitude_nm']:g} N*m chirp", file=sys.stderr)
        elif topic == "result":
            print_report(document, document.get("fixed", {}))
        elif topic == "progress" and "search" not in document:
            state = (document["session"], document["stage"], document.get("phase"))
            if state == self.last and "message" not in document:
                return
            self.last = state
            data = document.get("data_s")
            text = f"session {document['session']}: {document['stage']}"
            text += f", phase {document['phase']}" if document.get("phase") else ""
            text += f", {data:.1f} s of data" if data is not None else ""
            text += f": {document['message']}" if document.get("message") else ""
            text += f" ({', '.join(document['files'])})" if document.get("files") else ""
            print(text, file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """Serve sessions until SIGINT/SIGTERM (or one session with --once)."""
    if (args.json or args.plot) and not args.once:  # each session would write over the last's
        raise ConfigError(
            "--json and --plot name one file, for one session: give them with --once (a worker "
            "serving sessions writes each one's identification.json and .png beside its log)"
        )
    settings = search_settings(args)
    config = load_config(args.config)
    if args.plan_vehicles < 0:
        raise ConfigError("--plan-vehicles must be 0 or more")
    options = WorkerOptions(
        settings=settings,
        profile_points=args.profile_points,
        prior=load_parameters(args.prior) if args.prior else None,
        vehicle=vehicle_data(args),
        json_path=args.json,
        plot_path=args.plot,
        plot=not args.no_plot,
        diagnose=config.worker.diagnose,
        mechanisms=None if args.mechanisms is None else tuple(args.mechanisms),
        plan_follow_up=config.worker.plan_follow_up,
        plan_vehicles=args.plan_vehicles,
        safety=config.safety,
    )
    leave_a_core_to_the_bus()
    worker = Worker(config.pipeline, options)
    worker.listeners.append(_Terminal())
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        status = worker.serve(once=args.once, stop=stop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if stop.is_set():
        served = ", ".join(f"{sid} {end}" for sid, end in worker.finished.items()) or "none"
        print(f"worker stopped (sessions served: {served})", file=sys.stderr)
        if args.once and not worker.finished:  # the one session it was to serve never ended
            return EXIT_INTERRUPTED
    return status
