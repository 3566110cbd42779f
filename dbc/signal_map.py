"""Signal maps: which DBC signal carries each quantity the analysis needs.

A signal map is a TOML file with one table per *role*::

    [speed]           # filtered engine speed, rpm
    message = "EngineSpeed"
    signal = "EngineSpeedFiltered"
    counter = "CrankEventCounter"   # optional

Roles and their optional keys (besides the required ``message`` and ``signal``):

==================  ===========  ===============================================
role                canonical    optional keys
==================  ===========  ===============================================
``speed``           rpm          ``unit``, ``scale``, ``counter``, ``valid``, ``valid_values``
``mean_torque``     N*m          ``unit``, ``scale``, ``cylinder``, ``counter``, ``valid``,
                                 ``valid_values``
``test_torque``     N*m          ``unit``, ``scale``, ``counter``, ``enable``, ``checksum``,
                                 ``timeout_s``
``torque_request``  N*m          ``unit``, ``scale``, ``counter``, ``valid``, ``valid_values``
``heartbeat``       (raw state)  none
==================  ===========  ===============================================

Every role may also give ``channel``: the bus channel of its message in a recording of several
buses, as the recording names it (an integer for .asc, .blf, .trc and .mf4 files, counted as the
file and Vector's tools count, from 1; a string such as ``"can1"`` for a candump log). A logger on
two buses may see a message on both (a gateway forwards it), or two buses may use one ID for
different messages: without ``channel`` such a recording is refused, naming the channels. The
daemon, on one bus, ignores it.

``counter``, ``cylinder``, ``enable``, ``checksum`` and ``valid`` name further signals of the
same message. ``valid`` is the ECU's validity flag of the value (the independent DBC's
``EMS_EngSpdValid``): a frame whose flag's raw value is not among ``valid_values`` (``[1]``
unless given) carries no measurement and is left out of the role.
``unit`` is the unit of the decoded signal after ``scale`` when it differs from the canonical one,
and ``scale`` a factor applied after decoding (for a torque in % of a 450 N*m reference,
``scale = 4.5``): ``canonical = unit_convert(decoded * scale, unit)``. ``timeout_s`` is how long
the engine ECU keeps applying the last test-torque request when no valid one follows, s
(:data:`dtid.dbc.roles.DEFAULT_REQUEST_TIMEOUT_S` when not given): after it the ECU applies zero,
and the analysis reads a recording's requests so (:mod:`dtid.identification.samples.recording`).

``speed``, ``mean_torque`` and ``test_torque`` are needed by the analysis commands; a map may lack
them (``inspect`` reports what is missing), and :meth:`SignalMap.require` raises a clear error
when a command needs a role that is not mapped.
"""

import difflib
import math
import os
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from cantools.database.can import Database

from dtid.dbc.interface import VehicleInterface
from dtid.dbc.roles import (
    CANONICAL_UNITS,
    DEFAULT_REQUEST_TIMEOUT_S,
    EXTRA_SIGNAL_KEYS,
    REQUIRED_ROLES,
    ROLES,
)
from dtid.errors import ConfigError

UNIT_FACTORS: Mapping[str, Mapping[str, float]] = MappingProxyType(
    {
        "rpm": MappingProxyType({"rpm": 1.0, "rad/s": 60.0 / (2.0 * math.pi)}),
        "N*m": MappingProxyType({"N*m": 1.0}),
    }
)
"""Factor from each unit a map may give (``unit``) to its role's canonical unit, per canonical
unit."""
_NAME_KEYS = ("message", "signal")


@dataclass(frozen=True)
class RoleSpec:
    """Where one role is found in the DBC and how its values convert to the canonical unit.

    Attributes
    ----------
    role : str
        The role, one of :data:`ROLES`.
    message : str
        Name of the DBC message.
    signal : str
        Name of the signal carrying the role's value.
    unit : str or None
        Unit of ``decoded * scale``; the canonical unit unless the map says otherwise, None for
        the heartbeat.
    scale : float
        Factor applied to the decoded signal value, > 0.
    counter, cylinder, enable, checksum : str or None
        Names of further signals of the same message, where the map names them.
    timeout_s : float
        For the test torque: bus time after the last valid request from which the ECU applies
        zero, s; :data:`dtid.dbc.roles.DEFAULT_REQUEST_TIMEOUT_S` unless the map gives it.
    channel : str or None
        The recording's bus channel of the message, as the recording names it
        (:func:`dtid.acquisition.logfile.recorded_channel`); None: wherever it is, on one channel.
    valid : str or None
        The validity flag's signal, where the map names one.
    valid_values : tuple of int
        Raw values of the validity flag that mean the value is a measurement ((1,) unless given).
    """

    role: str
    message: str
    signal: str
    unit: str | None
    scale: float = 1.0
    counter: str | None = None
    cylinder: str | None = None
    enable: str | None = None
    checksum: str | None = None
    timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S
    channel: str | None = None
    valid: str | None = None
    valid_values: tuple[int, ...] = (1,)

    @property
    def canonical_unit(self) -> str | None:
        """Unit of the role's decoded values: rpm, N*m, or None for the heartbeat's raw state."""
        return CANONICAL_UNITS[self.role]

    @property
    def gain(self) -> float:
        """Canonical value per unit of decoded signal value (scale times unit conversion)."""
        if self.canonical_unit is None or self.unit is None:
            return self.scale
        return self.scale * UNIT_FACTORS[self.canonical_unit][self.unit]

    def extra_signals(self) -> dict[str, str]:
        """Return the further signals the map names, as ``{key: signal name}``."""
        names = {key: getattr(self, key) for key in EXTRA_SIGNAL_KEYS[self.role]}
        return {key: name for key, name in names.items() if name is not None}


@dataclass(frozen=True)
class SignalMap:
    """A loaded signal map.

    Attributes
    ----------
    source : pathlib.Path
        The file the map was loaded from (used in messages).
    roles : Mapping[str, RoleSpec]
        The mapped roles, read-only.
    """

    source: Path
    roles: Mapping[str, RoleSpec]

    def present_roles(self) -> tuple[str, ...]:
        """Return the mapped roles, in the order of :data:`ROLES`."""
        return tuple(role for role in ROLES if role in self.roles)

    def missing_roles(self, required: Iterable[str] = REQUIRED_ROLES) -> tuple[str, ...]:
        """Return the roles of ``required`` that the map lacks."""
        return tuple(role for role in required if role not in self.roles)

    def require(self, *roles: str) -> None:
        """Check that the map defines the given roles (default: :data:`REQUIRED_ROLES`).

        Raises
        ------
        ConfigError
            Naming the missing roles and how to add them.
        """
        missing = self.missing_roles(roles or REQUIRED_ROLES)
        if missing:
            names = ", ".join(f"'{role}'" for role in missing)
            raise ConfigError(
                f"signal map {self.source} lacks role {names} which this command needs; add a "
                f'[{missing[0]}] table with message = "<message>" and signal = "<signal>"'
            )

    def bind(
        self, database: Database, dbc_source: str | os.PathLike[str] | None = None
    ) -> VehicleInterface:
        """Bind the map to a CAN database.

        Parameters
        ----------
        database : cantools.database.can.Database
            The database, e.g. from :func:`dtid.dbc.load_database`.
        dbc_source : str or os.PathLike, optional
            The database's file, named in error messages.

        Returns
        -------
        VehicleInterface
            Decoder and encoder of the mapped roles.

        Raises
        ------
        DbcError
            If a mapped message or signal is not in the database.
        """
        return VehicleInterface(self, database, dbc_source)


def _suggest(name: str, candidates: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(candidates), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _type_name(value: object) -> str:
    return {bool: "boolean", int: "integer", float: "number", str: "string"}.get(
        type(value), "table" if isinstance(value, dict) else type(value).__name__
    )


def _parse_role(source: Path, role: str, table: Mapping[str, Any]) -> RoleSpec:
    where = f"signal map {source}: role '{role}'"
    extra_keys = EXTRA_SIGNAL_KEYS[role]
    canonical = CANONICAL_UNITS[role]
    timeout_keys = ("timeout_s",) if role == "test_torque" else ()
    valid_keys = ("valid_values",) if "valid" in extra_keys else ()
    allowed = (
        _NAME_KEYS
        + (("unit", "scale") if canonical else ())
        + extra_keys
        + valid_keys
        + timeout_keys
        + ("channel",)
    )
    for key in table:
        if key not in allowed:
            raise ConfigError(
                f"{where} has unknown key '{key}'{_suggest(key, allowed)}; "
                f"allowed keys are {', '.join(allowed)}"
            )
    for key in _NAME_KEYS:
        if key not in table:
            raise ConfigError(f"{where} lacks key '{key}'; add {key} = \"<{key} name in the DBC>\"")
    names: dict[str, str] = {}
    for key in _NAME_KEYS + extra_keys:
        if key not in table:
            continue
        value = table[key]
        if not isinstance(value, str) or not value.strip():
            kind = "message" if key == "message" else "signal"
            raise ConfigError(
                f"{where} key '{key}' must be a non-empty string naming a DBC {kind}, "
                f"got {_type_name(value)} {value!r}"
            )
        names[key] = value.strip()
    unit = table.get("unit", canonical)
    if canonical is not None:
        accepted = UNIT_FACTORS[canonical]
        if not isinstance(unit, str) or unit not in accepted:
            raise ConfigError(
                f"{where} key 'unit' is {unit!r}, which is not a unit this role accepts; "
                f"use one of {', '.join(repr(name) for name in accepted)}"
            )
    scale = table.get("scale", 1.0)
    if isinstance(scale, bool) or not isinstance(scale, int | float):
        raise ConfigError(
            f"{where} key 'scale' must be a number, got {_type_name(scale)} {scale!r}; "
            "write it without quotes, e.g. scale = 4.5"
        )
    if not math.isfinite(scale) or scale <= 0:
        raise ConfigError(
            f"{where} key 'scale' must be a finite number > 0, got {scale!r}; e.g. scale = 4.5 "
            "for a torque in % of a 450 N*m reference"
        )
    timeout = table.get("timeout_s", DEFAULT_REQUEST_TIMEOUT_S)
    if (
        isinstance(timeout, bool)
        or not isinstance(timeout, int | float)
        or not math.isfinite(timeout)
        or timeout <= 0
    ):
        raise ConfigError(
            f"{where} key 'timeout_s' must be a number of seconds > 0, got {_type_name(timeout)} "
            f"{timeout!r}; e.g. timeout_s = 0.05 for an ECU that drops the test torque 50 ms "
            "after the last request"
        )
    channel = table.get("channel")
    if channel is not None and (
        isinstance(channel, bool)
        or not isinstance(channel, int | str)
        or (isinstance(channel, int) and channel < 0)
        or (isinstance(channel, str) and not channel.strip())
    ):
        raise ConfigError(
            f"{where} key 'channel' must be the recording's bus channel: a number as an .asc or "
            f".blf file counts it (channel = 1) or a name as a candump log gives it (channel = "
            f'"can1"), got {_type_name(channel)} {channel!r}'
        )
    valid_values = table.get("valid_values", [1])
    if (
        not isinstance(valid_values, list)
        or not valid_values
        or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in valid_values)
    ):
        raise ConfigError(
            f"{where} key 'valid_values' must list the raw values of the validity flag that mean "
            f"a measurement, e.g. valid_values = [1], got {_type_name(valid_values)} "
            f"{valid_values!r}"
        )
    if "valid_values" in table and "valid" not in names:
        raise ConfigError(f"{where} gives 'valid_values' without 'valid', the flag's signal")
    return RoleSpec(
        role=role,
        unit=unit,
        scale=float(scale),
        timeout_s=float(timeout),
        channel=None if channel is None else str(channel).strip(),
        valid_values=tuple(valid_values),
        **names,
    )


def load_signal_map(path: str | os.PathLike[str]) -> SignalMap:
    """Load a signal map from a TOML file.

    Maps that lack roles are accepted (see :meth:`SignalMap.require`); an empty one is not.

    Parameters
    ----------
    path : str or os.PathLike
        The TOML file.

    Returns
    -------
    SignalMap
        The map.

    Raises
    ------
    ConfigError
        If the file is missing or unreadable, is not valid TOML, or holds an unknown role table, an
        unknown key, a value of the wrong type, an unknown unit or a scale that is not a finite
        number > 0; the message names the file, the role and the key.
    """
    source = Path(path)
    try:
        with source.open("rb") as file:
            document = tomllib.load(file)
    except FileNotFoundError as error:
        raise ConfigError(f"signal map {source} does not exist") from error
    except IsADirectoryError as error:
        raise ConfigError(f"signal map {source} is a directory, not a TOML file") from error
    except OSError as error:
        raise ConfigError(f"cannot read signal map {source}: {error.strerror or error}") from error
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"signal map {source} is not valid TOML: {error}") from error
    if not document:
        raise ConfigError(
            f"signal map {source} maps no role: it needs a table for each of "
            f"{', '.join(REQUIRED_ROLES)} (see dbc/drivetrain_signals.toml for the format)"
        )
    roles: dict[str, RoleSpec] = {}
    for role, table in document.items():
        if role not in ROLES:
            raise ConfigError(
                f"signal map {source}: unknown role [{role}]{_suggest(role, ROLES)}; "
                f"the roles are {', '.join(ROLES)}"
            )
        if not isinstance(table, dict):
            raise ConfigError(
                f"signal map {source}: role '{role}' must be a table, got {_type_name(table)}; "
                f'write it as [{role}] followed by message = "..." and signal = "..."'
            )
        roles[role] = _parse_role(source, role, table)
    ordered = {role: roles[role] for role in ROLES if role in roles}
    return SignalMap(source=source, roles=MappingProxyType(ordered))
