"""``dtid acquire``: the acquisition daemon; runs one chirp test on the vehicle bus."""

from __future__ import annotations

import argparse
from pathlib import Path

from dtid.acquisition.campaign import Campaign
from dtid.acquisition.config import load_config
from dtid.acquisition.daemon import DEFAULT_LINGER_S, DEFAULT_WAIT_S, Daemon
from dtid.cli.commands.common import non_negative_float, positive_float
from dtid.errors import ConfigError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "acquire",
        help="run the chirp test on the vehicle bus, record it and stream it to the worker",
        description="Run one chirp test on the configured CAN bus: wait for the engine speed, "
        "settle, chirp at each amplitude, validate; record every frame to a new session folder "
        "and publish the decoded samples on ZeroMQ. Aborts with a zero request when the speed "
        "leaves its window, the vehicle stops answering, another node sends on the tool's IDs, "
        "or on SIGINT/SIGTERM. With [test] adaptive = true, runs rounds: after each the worker "
        "plans the next at what it identified, until the targets are met or [test] max_time_s "
        "is spent (campaign.json says why it stopped). Exit status 0: completed; 3: aborted; "
        "2: configuration error.",
    )
    parser.add_argument("--config", type=Path, help="configuration file (TOML; default: built-in)")
    parser.add_argument("--output", type=Path, help="folder of the session folders ([output])")
    parser.add_argument("--interface", help="python-can interface (overrides [bus])")
    parser.add_argument("--channel", help="bus channel (overrides [bus])")
    parser.add_argument(
        "--linger",
        type=non_negative_float,
        default=DEFAULT_LINGER_S,
        metavar="S",
        help="seconds the replay stays up after the test for a late worker (default: %(default)s)",
    )
    parser.add_argument(
        "--wait",
        type=positive_float,
        default=DEFAULT_WAIT_S,
        metavar="S",
        help="seconds to wait for the vehicle's first speed frame (default: %(default)s)",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run the test; return 0 when it completed, 3 when it was aborted."""
    config = load_config(args.config)
    bus = {k: v for k, v in (("interface", args.interface), ("channel", args.channel)) if v}
    if bus:
        config = config.with_changes("bus", **bus)
    if args.output is not None:
        config = config.with_changes("output", directory=args.output)
    _check_targets(config.campaign.targets)  # a misspelt name, adaptive or not
    if config.campaign.adaptive:
        campaign = Campaign(config, linger_s=args.linger, wait_s=args.wait, report=_print)
        return campaign.run().exit_status
    daemon = Daemon(config, linger_s=args.linger, wait_s=args.wait, report=_print)
    return daemon.run().exit_status


def _check_targets(targets: dict[str, float]) -> None:
    """Refuse an unknown ``[test] targets`` name before anything runs on the bus."""
    from dtid.identification.planning.design import parse_targets

    try:
        parse_targets([f"{name}={percent}" for name, percent in targets.items()])
    except ConfigError as error:
        raise ConfigError(f"[test] targets: {error}".replace("--target ", "")) from None


def _print(line: str) -> None:
    print(line, flush=True)
