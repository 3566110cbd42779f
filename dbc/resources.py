"""Paths of the data files packaged with :mod:`dtid.dbc`."""

from pathlib import Path

_HERE = Path(__file__).resolve().parent

#: The product's own vehicle interface DBC.
DEFAULT_DBC: Path = _HERE / "drivetrain.dbc"
#: The signal map that binds the analysis roles to :data:`DEFAULT_DBC`.
DEFAULT_SIGNAL_MAP: Path = _HERE / "drivetrain_signals.toml"
