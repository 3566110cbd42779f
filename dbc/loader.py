"""Open the vehicle interface a command works with: a DBC plus the signal map that reads it."""

from __future__ import annotations

import os
from pathlib import Path

from dtid.dbc.database import load_database
from dtid.dbc.interface import VehicleInterface
from dtid.dbc.resources import DEFAULT_DBC, DEFAULT_SIGNAL_MAP
from dtid.dbc.role_candidates import describe_candidates
from dtid.dbc.signal_map import load_signal_map
from dtid.errors import DbcError


def load_interface(
    dbc: str | os.PathLike[str] | None = None, signals: str | os.PathLike[str] | None = None
) -> VehicleInterface:
    """Load a DBC and a signal map and bind them.

    Parameters
    ----------
    dbc
        CAN database; the product's own ``drivetrain.dbc`` when omitted.
    signals
        Signal map (TOML); the product's own map when omitted. A DBC other than the product's
        needs its own map.

    Raises
    ------
    DbcError, ConfigError
        If either file cannot be read or the map names what the DBC lacks.
    """
    dbc_path = Path(dbc) if dbc is not None else DEFAULT_DBC
    map_path = Path(signals) if signals is not None else DEFAULT_SIGNAL_MAP
    database = load_database(dbc_path)
    signal_map = load_signal_map(map_path)
    try:
        return signal_map.bind(database, dbc_path)
    except DbcError as error:
        if signals is None and dbc is not None:
            candidates = describe_candidates(database, tuple(signal_map.roles))
            raise DbcError(
                f"{error}. {dbc_path} is not the product's DBC: pass a signal map for it with "
                "--signals (see dbc/drivetrain_signals.toml for the format). Its signals whose "
                f"unit fits a role: {candidates}"
            ) from None
        raise
