"""``dtid keys``: the ZeroMQ CURVE key pairs of a pipeline that leaves this machine."""

from __future__ import annotations

import argparse
from pathlib import Path

from dtid.acquisition.security import create_keys


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "keys",
        help="write the CURVE keys a tcp:// pipeline off this machine needs",
        description="Write a key pair for the binding side (daemon, worker results: "
        "server.key, server.key_secret) and one for the connecting side (client.key, "
        "client.key_secret) into DIR (a new folder gets mode 0700, the secret keys 0600). "
        "Give both machines the folder (the daemon's needs server.key_secret and both public "
        "keys; the worker's both pairs) and set "
        '[pipeline] keys = "DIR" in their configurations. A tcp:// endpoint other than '
        "loopback is refused without them.",
    )
    parser.add_argument("directory", type=Path, metavar="DIR", help="folder to write the keys to")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Write the keys and say where."""
    for path in create_keys(args.directory):
        print(f"wrote {path}")
    return 0
