"""Drivetrain parameter names, units and validation: the one place these facts live.

The names follow the paper's eq. (6): three inertias J1 (engine side), J2 (dual-mass-flywheel
secondary side) and J3 (clutch disc and gearbox input in neutral), the DMF arc spring c12/d12 with
Coulomb friction Tc12 and free play eps12, the clutch/gear coupling c23/d23 with gear play eps23,
the constant loss torque T_loss on J1 and the engine gain K (eq. 3 and 24). Free plays are *total*
widths: the coupling is free for -eps/2 < delta < +eps/2.

Parameter sets load from TOML files holding exactly these twelve keys (see
``simulator/reference_vehicle.toml``); :func:`load_parameters` names any unknown, missing or
non-physical key.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dtid.errors import ConfigError

logger = logging.getLogger(__name__)

REFERENCE_VEHICLE = Path(__file__).with_name("reference_vehicle.toml")


@dataclass(frozen=True)
class ParameterSpec:
    """Name, SI unit, meaning and admissible range of one drivetrain parameter."""

    name: str
    unit: str
    meaning: str
    strictly_positive: bool
    """True where zero is not physical (an inertia, the engine gain); else zero is allowed."""
    car_range: tuple[float, float]
    """Where any passenger car's value lies, generously (SI): a value outside is more likely in
    another unit than a car's (:func:`implausible`)."""
    other_unit: tuple[str, float] | None = None
    """A unit the value is often given in, and that unit in SI units (1 g*m^2 = 1e-3 kg*m^2)."""


DEG = math.pi / 180.0
SPECS: tuple[ParameterSpec, ...] = (
    ParameterSpec("J1", "kg*m^2", "engine-side inertia (crank train, DMF primary)", True,
                  (0.03, 1.5), ("g*m^2", 1e-3)),
    ParameterSpec("J2", "kg*m^2", "DMF secondary inertia with clutch cover", True,
                  (0.01, 1.5), ("g*m^2", 1e-3)),
    ParameterSpec("J3", "kg*m^2", "clutch disc and gearbox input inertia in neutral", True,
                  (0.001, 0.3), ("g*m^2", 1e-3)),
    ParameterSpec("c12", "N*m/rad", "DMF arc-spring stiffness", False,
                  (20.0, 5000.0), ("N*m/deg", 1 / DEG)),
    ParameterSpec("c23", "N*m/rad", "clutch/gear coupling stiffness", False,
                  (2.0, 3000.0), ("N*m/deg", 1 / DEG)),
    ParameterSpec("d12", "N*m*s/rad", "DMF viscous damping", False, (0.0, 30.0)),
    ParameterSpec("d23", "N*m*s/rad", "clutch/gear viscous damping", False, (0.0, 10.0)),
    ParameterSpec("Tc12", "N*m", "DMF Coulomb friction torque", False, (0.0, 50.0)),
    ParameterSpec("eps12", "rad", "DMF free play, total width", False, (0.0, 0.5), ("deg", DEG)),
    ParameterSpec("eps23", "rad", "gear and clutch-hub play, total width", False, (0.0, 0.2),
                  ("deg", DEG)),
    ParameterSpec("T_loss", "N*m", "constant loss torque on J1 at idle", False, (0.0, 150.0)),
    ParameterSpec("K", "1", "engine gain from requested to mean torque (eq. 3)", True,
                  (0.3, 3.0), ("%", 0.01)),
)  # fmt: skip
NAMES: tuple[str, ...] = tuple(spec.name for spec in SPECS)
UNITS: dict[str, str] = {spec.name: spec.unit for spec in SPECS}
INDEX: dict[str, int] = {name: i for i, name in enumerate(NAMES)}


@dataclass(frozen=True)
class DrivetrainParameters:
    """One physical parameter set of the three-mass drivetrain, SI units (see :data:`SPECS`)."""

    J1: float
    J2: float
    J3: float
    c12: float
    c23: float
    d12: float
    d23: float
    Tc12: float
    eps12: float
    eps23: float
    T_loss: float
    K: float

    def __post_init__(self) -> None:
        for spec in SPECS:
            _check_value(spec, getattr(self, spec.name), source="parameter set")

    def as_array(self) -> np.ndarray:
        """Return the values as a float64 array ordered as :data:`NAMES`."""
        return np.array([getattr(self, name) for name in NAMES], dtype=np.float64)

    @classmethod
    def from_array(cls, values: np.ndarray) -> DrivetrainParameters:
        """Build a parameter set from an array ordered as :data:`NAMES`."""
        if len(values) != len(NAMES):
            raise ConfigError(f"expected {len(NAMES)} parameter values, got {len(values)}")
        return cls(**{name: float(v) for name, v in zip(NAMES, values, strict=True)})

    def replace(self, **changes: float) -> DrivetrainParameters:
        """Return a copy with some values changed (validated like any parameter set)."""
        unknown = sorted(set(changes) - set(NAMES))
        if unknown:
            raise ConfigError(f"unknown parameter {unknown[0]!r}; known: {', '.join(NAMES)}")
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        """Return ``{name: value}`` in SI units, ordered as :data:`NAMES`."""
        return {name: getattr(self, name) for name in NAMES}


def _check_value(spec: ParameterSpec, value: object, source: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{source}: {spec.name} must be a number in {spec.unit}, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{source}: {spec.name} must be finite, got {value!r}")
    if spec.strictly_positive and value <= 0:
        raise ConfigError(
            f"{source}: {spec.name} = {value} is not physical: the {spec.meaning} must be > 0 "
            f"{spec.unit}"
        )
    if value < 0:
        raise ConfigError(
            f"{source}: {spec.name} = {value} is not physical: the {spec.meaning} must be >= 0 "
            f"{spec.unit}"
        )


def implausible(parameters: DrivetrainParameters, source: str) -> list[str]:
    """What to say of each value outside its :attr:`ParameterSpec.car_range`: most likely given
    in another unit (an inertia in g*m^2, a stiffness in N*m/deg, a play in degrees), which the
    search box and the model then take as a car beyond any passenger car's. Where the value read
    in the spec's :attr:`~ParameterSpec.other_unit` lies within the range, the message gives it.
    """
    messages = []
    for spec in SPECS:
        value = getattr(parameters, spec.name)
        low, high = spec.car_range
        if low <= value <= high:
            continue
        message = (
            f"{source}: {spec.name} = {value:g} {spec.unit} lies outside {low:g}-{high:g} "
            f"{spec.unit}, where a passenger car's {spec.meaning} lies"
        )
        if spec.other_unit is not None:
            unit, factor = spec.other_unit
            if low <= value * factor <= high:
                message += (
                    f"; if it is in {unit}, it is {value * factor:.4g} {spec.unit}: give it in "
                    f"{spec.unit}"
                )
        messages.append(message)
    return messages


def parse_parameters(table: dict[str, object], source: str) -> DrivetrainParameters:
    """Validate a ``{name: value}`` mapping and build a parameter set.

    Parameters
    ----------
    table
        Exactly the twelve keys of :data:`NAMES`, values in SI units.
    source
        Where the table came from, used in error messages (a file name).

    Raises
    ------
    ConfigError
        Naming the first unknown, missing or non-physical key.
    """
    unknown = [key for key in table if key not in INDEX]
    if unknown:
        raise ConfigError(
            f"{source}: unknown parameter {unknown[0]!r}; the keys are {', '.join(NAMES)}"
        )
    missing = [name for name in NAMES if name not in table]
    if missing:
        raise ConfigError(
            f"{source}: missing parameter {missing[0]!r} ({UNITS[missing[0]]}); "
            f"a parameter set needs all of {', '.join(NAMES)}"
        )
    for spec in SPECS:
        _check_value(spec, table[spec.name], source)
    parameters = DrivetrainParameters(**{name: float(table[name]) for name in NAMES})  # type: ignore[arg-type]
    for message in implausible(parameters, source):
        logger.warning("%s", message)
    return parameters


VEHICLE_TABLES = ("engine", "sensors", "model")
"""Tables of a vehicle file besides ``[drivetrain]`` (:mod:`dtid.simulator.vehicle_data`)."""


def load_parameters(path: str | Path) -> DrivetrainParameters:
    """Load a parameter set from a TOML file with the keys of :data:`NAMES` (SI units): at its
    top level, or in the ``[drivetrain]`` table of a vehicle file (whose
    :data:`VEHICLE_TABLES` are then left to :func:`dtid.simulator.vehicle_data.load_vehicle_data`),
    so that one file can be both ``--prior`` and ``--vehicle``.

    Raises
    ------
    ConfigError
        If the file is missing, is not TOML, or has an unknown, missing or non-physical key.
    """
    path = Path(path)
    document = read_toml(path, "parameter file")
    drivetrain = document.get("drivetrain")
    if not isinstance(drivetrain, dict):
        return parse_parameters(document, source=str(path))
    beside = [key for key in document if key not in ("drivetrain", *VEHICLE_TABLES)]
    if beside:
        raise ConfigError(
            f"{path}: {beside[0]!r} beside [drivetrain]; a vehicle file gives the drivetrain "
            f"parameters in [drivetrain] and its vehicle data in "
            f"{', '.join(f'[{name}]' for name in VEHICLE_TABLES)} only"
        )
    return parse_parameters(drivetrain, source=f"{path} [drivetrain]")


def read_toml(path: Path, kind: str) -> dict[str, object]:
    """A TOML file's document; ConfigError naming the ``kind`` of file if it cannot be read."""
    try:
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"{kind} {path} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"{kind} {path} is a directory, not a TOML file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"{kind} {path} is not valid TOML: {error}") from None


def reference_parameters() -> DrivetrainParameters:
    """Return the reference vehicle of ``simulator/reference_vehicle.toml``."""
    return load_parameters(REFERENCE_VEHICLE)
