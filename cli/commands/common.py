"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path

from dtid.dbc.loader import load_interface
from dtid.errors import ConfigError, RecordingError
from dtid.identification.frf.closed_loop import DEFAULT_RESOLUTION_HZ
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.recording import load_recording
from dtid.simulator.vehicle_data import VehicleData, load_vehicle_data


def add_vehicle_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--vehicle``."""
    parser.add_argument(
        "--vehicle",
        type=Path,
        help="vehicle file (TOML): [engine] gives the crank-train data the model engine needs, "
        "[sensors] the speed sensor's arithmetic (default: the reference's; see "
        "docs/model-assumptions.md)",
    )


def vehicle_data(args: argparse.Namespace) -> VehicleData:
    """The vehicle data of ``--vehicle``, or the reference engine's."""
    return load_vehicle_data(args.vehicle) if args.vehicle else VehicleData()


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


def measured_tests(
    recordings: Sequence[Path],
    dbc: Path | None,
    signals: Path | None,
    vehicle: VehicleData | None = None,
) -> list[MeasuredTest]:
    """Load recordings and estimate their runs' FRFs for the identification commands."""
    interface = load_interface(dbc, signals)
    return [
        MeasuredTest.from_data(
            str(path), load_recording(path, interface).test_data(), DEFAULT_RESOLUTION_HZ, vehicle
        )
        for path in recordings
    ]
