"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from dtid.errors import ConfigError, RecordingError


def add_interface_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--dbc`` and ``--signals``."""
    parser.add_argument(
        "--dbc", type=Path, help="CAN database of the vehicle (default: the product's own)"
    )
    parser.add_argument(
        "--signals", type=Path, help="signal map (TOML) tying roles to the DBC's signals"
    )


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text} must be a number > 0")
    return value


def write_json(path: Path, document: object) -> None:
    """Write a JSON document, naming the file when that fails."""
    try:
        path.write_text(json.dumps(document, indent=1, allow_nan=False) + "\n")
    except OSError as error:
        raise RecordingError(f"cannot write {path}: {error.strerror}") from None
    except ValueError as error:
        raise ConfigError(f"cannot write {path}: {error}") from None
