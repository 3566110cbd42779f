"""Which signals of a foreign DBC could fill the roles of a signal map, found by their units.

A vehicle's own DBC names its engine speed and torques as its maker does (``EngAout_N_Actl``,
``MO5_Drehzahl``, ``TQ_STND``); what it does say in a form the product can read is each signal's
unit. When the product's signal map does not fit a DBC, the error lists the DBC's signals whose
unit is an engine speed's or a torque's, with the ``unit`` a signal map would give them, so that
a user writing the map starts from the right few dozen signals instead of a few thousand.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from cantools.database.can import Database

from dtid.dbc.roles import CANONICAL_UNITS
from dtid.dbc.signal_map import UNIT_FACTORS

DBC_UNITS: Mapping[str, str] = MappingProxyType(
    {
        "rpm": "rpm",
        "1/min": "rpm",
        "u/min": "rpm",
        "min-1": "rpm",
        "min^-1": "rpm",
        "rad/s": "rad/s",
        "nm": "N*m",
        "n*m": "N*m",
        "n.m": "N*m",
        "n m": "N*m",
        "n·m": "N*m",
    }
)
"""A DBC's spelling of a unit (lower case, spaces around it dropped) -> the unit a signal map
gives for it (``unit`` of :mod:`dtid.dbc.signal_map`): the spellings of production DBCs (Ford
``RPM``, Volkswagen ``U/min`` and ``1/min``, Hyundai ``Nm``)."""
_CANONICAL = {unit: canonical for canonical, units in UNIT_FACTORS.items() for unit in units}
"""The canonical unit (:data:`dtid.dbc.roles.CANONICAL_UNITS`) each map unit converts to."""
SHOWN = 12
"""Most signals named per unit in a message."""


def signals_by_unit(database: Database) -> dict[str, list[tuple[str, str]]]:
    """The database's signals in an engine speed's or a torque's unit.

    Returns
    -------
    dict
        Canonical unit (``"rpm"``, ``"N*m"``) -> ``(message.signal, map unit)``, those in the
        canonical unit first (an engine speed comes in rpm, a wheel's in rad/s), each in the
        database's order; a unit without signals is left out.
    """
    found: dict[str, list[tuple[str, str]]] = {}
    for message in database.messages:
        for signal in message.signals:
            unit = DBC_UNITS.get(" ".join((signal.unit or "").split()).lower())
            if unit is not None:
                found.setdefault(_CANONICAL[unit], []).append(
                    (f"{message.name}.{signal.name}", unit)
                )
    return {
        canonical: sorted(signals, key=lambda signal: signal[1] != canonical)
        for canonical, signals in found.items()
    }


def describe_candidates(database: Database, roles: tuple[str, ...]) -> str:
    """One sentence naming, per canonical unit the ``roles`` need, the database's signals in it
    (at most :data:`SHOWN` each), or saying that it has none; and that a torque in % or without
    a unit is not among them."""
    found = signals_by_unit(database)
    parts = []
    for unit in dict.fromkeys(CANONICAL_UNITS[role] for role in roles):
        if unit is None:
            continue
        needing = ", ".join(role for role in roles if CANONICAL_UNITS[role] == unit)
        signals = found.get(unit, [])
        if not signals:
            parts.append(f"{needing} ({unit}): none")
            continue
        named = [
            name if mapped == unit else f'{name} (unit = "{mapped}")' for name, mapped in signals
        ]
        more = len(named) - SHOWN
        listed = ", ".join(named[:SHOWN]) + (f" and {more} more" if more > 0 else "")
        parts.append(f"{needing} ({unit}): {listed}")
    note = (
        " (many ECUs give their torques in % of a reference torque or without a unit: those"
        " are not listed, and their map gives the `scale` to N*m)"
        if "N*m" in (CANONICAL_UNITS[role] for role in roles)
        else ""
    )
    return "; ".join(parts) + note
