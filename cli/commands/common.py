"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TextIO

from dtid.acquisition.clock import MAX_TIME_FACTOR
from dtid.acquisition.logfile import SUPPORTED_SUFFIXES
from dtid.acquisition.metadata import sidecar_path
from dtid.errors import ConfigError
from dtid.simulator.parameters import NAMES, DrivetrainParameters, load_parameters, parse_parameters
from dtid.simulator.vehicle_data import (
    VehicleData,
    load_vehicle_data,
    vehicle_data_from_tables,
)


def add_vehicle_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--vehicle``."""
    parser.add_argument(
        "--vehicle",
        type=Path,
        help="vehicle file (TOML): [engine] gives the crank-train data the model engine needs, "
        "[sensors] the speed sensor's arithmetic, [model] integration = \"euler\" (eq. 8's "
        'discrete model) or "verlet" (a continuous plant) and engine_lag = "none" or '
        "\"measured\" (the model's engine lags as the runs' T/T_ecu shows) (default: the "
        "reference's, euler and none; see docs/model-assumptions.md)",
    )


def vehicle_data(
    args: argparse.Namespace, identification: tuple[Path, dict] | None = None
) -> VehicleData:
    """The vehicle data of ``--vehicle``, else those an identification JSON was made with
    (``(path, document)``: its ``vehicle_data``), else the reference engine's.

    Raises
    ------
    ConfigError
        If ``--vehicle`` gives other vehicle data than the identification was made with: a model
        built otherwise would not be the model identified.
    """
    given = load_vehicle_data(args.vehicle) if args.vehicle else None
    recorded = identification[1].get("vehicle_data") if identification else None
    if identification is None or not isinstance(recorded, dict):
        return given or VehicleData()
    path = identification[0]
    identified = vehicle_data_from_tables(recorded, str(path))
    if given is None:
        differs = _changed(VehicleData().as_dict(), identified.as_dict())
        return replace(identified, given=tuple(differs), source=f"{path} (the identification's)")
    changed = _changed(identified.as_dict(), given.as_dict())
    if changed:
        listed = ", ".join(
            f"{key} = {json.dumps(new)} against {json.dumps(old)}"
            for key, (old, new) in changed.items()
        )
        raise ConfigError(
            f"--vehicle {args.vehicle} gives other vehicle data than {path} was identified with "
            f"({listed}): give the vehicle file of the identification, or no --vehicle to take "
            "the identification's"
        )
    return given


def _changed(
    before: dict[str, dict[str, object]], after: dict[str, dict[str, object]]
) -> dict[str, tuple[object, object]]:
    """The keys of :meth:`VehicleData.as_dict`'s tables whose values differ: (before, after)."""
    return {
        key: (before[table][key], value)
        for table, values in after.items()
        for key, value in values.items()
        if before[table][key] != value
    }


def add_interface_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--dbc`` and ``--signals``."""
    parser.add_argument(
        "--dbc", type=Path, help="CAN database of the vehicle (default: the product's own)"
    )
    parser.add_argument(
        "--signals", type=Path, help="signal map (TOML) tying roles to the DBC's signals"
    )


MAX_SEED = 2**32 - 1
"""Largest seed numpy's generators of the search and the simulator take."""


def seed(text: str) -> int:
    """argparse type: a random seed, a whole number 0 .. :data:`MAX_SEED`."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text} must lie in 0 .. {MAX_SEED}")
    return value


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    return _finite_float(text, positive=False)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    return _finite_float(text, positive=True)


def at_most(upper: float, why: str, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a finite number > 0 and at most ``upper``; above it the message
    gives ``why`` (a unit slip, a value no test runs with)."""

    def parse(text: str) -> float:
        value = positive_float(text)
        if value > upper:
            raise argparse.ArgumentTypeError(f"{text}{unit} is above {upper:g}{unit}: {why}")
        return value

    return parse


speedup = at_most(
    MAX_TIME_FACTOR, "a virtual vehicle faster than that does not keep pace with the bus"
)
"""argparse type: bus time per wall time, in (0, :data:`MAX_TIME_FACTOR`]."""


def _finite_float(text: str, positive: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and (value > 0 if positive else value >= 0)):
        raise argparse.ArgumentTypeError(f"{text} must be a number {'>' if positive else '>='} 0")
    return value


class OutputPath(type(Path())):  # type: ignore[misc]  # Path's concrete class (PosixPath)
    """A file the command writes (:func:`new_file`), told from the files it reads by
    :func:`check_written_over`."""


def new_file(text: str) -> OutputPath:
    """argparse type: a file the command writes, in a folder that exists and takes files.

    Checked when the command is read, so that a mistyped or missing folder, or one that takes
    no new files (``/proc``, a full or read-only file system), is named before minutes of
    identification, not after them (the result was then lost). A file that does not exist yet
    is created and removed to find out.
    """
    path = OutputPath(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder: give a file name in it")
    folder = path.parent
    if not folder.is_dir():
        raise argparse.ArgumentTypeError(
            f"cannot write {text}: the folder {folder} does not exist (create it first)"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"cannot write {text}: the folder {folder} is read-only")
    if not path.exists():
        try:
            path.touch(exist_ok=False)
            path.unlink()
        except OSError as error:
            raise argparse.ArgumentTypeError(
                f"cannot write {text}: {error.strerror or error}"
            ) from None
    return path


def check_written_over(args: argparse.Namespace) -> None:
    """Refuse a command that would write over a file it reads (an identification, a DBC, a
    plan, a parameter file) or write two results to one file: nothing a user gave is lost.

    Raises
    ------
    ConfigError
        Naming the file and the two options.
    """
    read: dict[Path, str] = {}
    written: dict[Path, str] = {}
    for dest, value in vars(args).items():
        for path in value if isinstance(value, list) else [value]:
            if not isinstance(path, Path):
                continue
            option = "RECORDING" if dest in ("recordings", "tests") else f"--{dest}"
            option = option.replace("_", "-")
            resolved = path.resolve()
            if not isinstance(path, OutputPath):
                read.setdefault(resolved, option)
            elif resolved in written:
                raise ConfigError(
                    f"{path} is given to both {written[resolved]} and {option}: one result "
                    "would be written over the other; give each its own file"
                )
            else:
                written[resolved] = option
    for resolved, option in written.items():
        if resolved in read:
            raise ConfigError(
                f"{resolved} is read by this command ({read[resolved]}) and would be written "
                f"over by {option}: give the result another name"
            )


def output_file(text: str) -> OutputPath:
    """argparse type: a result file (:func:`new_file`) that is neither a CAN recording nor a
    recording's metadata: nothing a user recorded is written over."""
    path = new_file(text)
    if path.suffix.lower() in SUPPORTED_SUFFIXES and path.exists():
        raise argparse.ArgumentTypeError(
            f"{text} is a CAN recording: the result would be written over it; give another name"
        )
    recording = path.with_name(path.name.removesuffix(".json"))
    if (
        sidecar_path(recording) == path
        and recording.suffix.lower() in SUPPORTED_SUFFIXES
        and recording.exists()
    ):
        raise argparse.ArgumentTypeError(
            f"{text} holds the metadata of the recording {recording}: the result would be "
            "written over it; give another name"
        )
    return path


def plot_file(text: str) -> OutputPath:
    """argparse type: a figure (:func:`output_file`) in a format matplotlib writes."""
    from matplotlib.backend_bases import FigureCanvasBase

    path = output_file(text)
    formats = FigureCanvasBase.get_supported_filetypes()
    if path.suffix[1:].lower() not in formats:
        raise argparse.ArgumentTypeError(
            f"cannot plot to {text}: give a file name ending in one of "
            + ", ".join(f".{name}" for name in sorted(formats))
        )
    return path


def read_identification(path: Path, option: str = "--identification") -> dict:
    """An identification JSON given by ``option``, or a clear error."""
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise ConfigError(f"cannot read {option} {path}: {error.strerror}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"{option} {path} is not JSON: {error}") from None
    if not isinstance(document, dict) or "parameters" not in document:
        raise ConfigError(
            f"{option} {path} is not an identification JSON (no 'parameters'): give "
            "the file `dtid identify --json` wrote"
        )
    return document


def is_identification(path: Path) -> bool:
    """Whether a parameter option names an identification's JSON (else a parameter TOML)."""
    return path.suffix.lower() == ".json"


def read_parameter_set(path: Path, option: str) -> tuple[DrivetrainParameters, dict | None]:
    """The drivetrain given by ``option``: a parameter TOML (its top level, or a vehicle file's
    ``[drivetrain]``) or an identification JSON (its parameters and T_loss), and the JSON's
    document (None for a TOML)."""
    if not is_identification(path):
        return load_parameters(path), None
    document = read_identification(path, option)
    table = {name: document["parameters"].get(name) for name in NAMES}
    table["T_loss"] = document.get("T_loss")
    missing = [name for name, value in table.items() if not isinstance(value, int | float)]
    if missing:
        raise ConfigError(f"{option} {path}: the identification has no {missing[0]!r}")
    return parse_parameters(table, str(path)), document


class ProgressBar:
    """The search's progress on stderr, one bar per stage (``global``, ``local``, ``profile``,
    ...) with its best objective so far.

    On a terminal the bar is redrawn in place, and a stage that stops before its last step
    (a converged polish) keeps its line. Elsewhere (a log file, a pipe, the journal) a line is
    written at each quarter of a stage, so that the log stays readable.

    Parameters
    ----------
    stream
        Where to write (stderr by default).
    """

    WIDTH = 30
    """Characters of the bar."""

    def __init__(self, stream: TextIO | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.terminal = self.stream.isatty()
        # the last call's stage, step, steps and quarter
        self._last: tuple[str, int, int, int] | None = None

    def __call__(self, stage: str, step: int, steps: int, best: float) -> None:
        """Show ``step`` of ``steps`` of ``stage``, its best objective ``best`` (1)."""
        step_in = min(step, steps)
        done = self.WIDTH * step_in // steps
        quarter = 4 * step_in // steps
        text = (
            f"{stage:>7} [{'#' * done}{'.' * (self.WIDTH - done)}] {step}/{steps} "
            f"objective {best:.4f}"
        )
        last, self._last = self._last, (stage, step, steps, quarter)
        if self.terminal:
            if self._stopped_early(last) and (last[0] != stage or step < last[1]):
                self.stream.write("\n")  # keep the line of the stage before
            self.stream.write(f"\r{text}" + ("\n" if step >= steps else ""))
        elif last is None or (last[0], last[3]) != (stage, quarter) or step < last[1]:
            self.stream.write(text + "\n")
        self.stream.flush()

    def finish(self) -> None:
        """End the line of a last stage that stopped early, before the result is printed."""
        if self.terminal and self._stopped_early(self._last):
            self.stream.write("\n")
            self.stream.flush()
        self._last = None

    @staticmethod
    def _stopped_early(last: tuple[str, int, int, int] | None) -> bool:
        return last is not None and last[1] < last[2]
