"""Vehicle CAN interface: the product's DBC, signal maps and the bound decoder/encoder.

Typical use::

    from dtid.dbc import DEFAULT_DBC, DEFAULT_SIGNAL_MAP, load_database, load_signal_map

    interface = load_signal_map(DEFAULT_SIGNAL_MAP).bind(load_database(DEFAULT_DBC), DEFAULT_DBC)
    series = interface.decode(frames)   # {"speed": RoleSeries, ...}
"""

from dtid.dbc.checksum import apply_checksum, compute_checksum, verify_checksum
from dtid.dbc.database import load_database
from dtid.dbc.interface import RoleSeries, VehicleInterface
from dtid.dbc.resources import DEFAULT_DBC, DEFAULT_SIGNAL_MAP
from dtid.dbc.roles import CANONICAL_UNITS, REQUIRED_ROLES, ROLES
from dtid.dbc.signal_map import RoleSpec, SignalMap, load_signal_map

__all__ = [
    "CANONICAL_UNITS",
    "DEFAULT_DBC",
    "DEFAULT_SIGNAL_MAP",
    "REQUIRED_ROLES",
    "ROLES",
    "RoleSeries",
    "RoleSpec",
    "SignalMap",
    "VehicleInterface",
    "apply_checksum",
    "compute_checksum",
    "load_database",
    "load_signal_map",
    "verify_checksum",
]
