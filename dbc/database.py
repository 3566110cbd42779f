"""Loading a CAN database (DBC) with cantools."""

import logging
import os
from pathlib import Path

import cantools
from cantools.database.can import Database

from dtid.errors import DbcError

logger = logging.getLogger(__name__)

_MAX_REASON_LENGTH = 200


def _reason(error: Exception) -> str:
    """Return cantools' reason for rejecting a DBC as one short printable line."""
    inner = getattr(error, "e_dbc", None) or error
    text = " ".join(str(inner).split())
    text = "".join(char if char.isprintable() else "?" for char in text)
    if len(text) > _MAX_REASON_LENGTH:
        text = text[: _MAX_REASON_LENGTH - 3] + "..."
    return text or type(inner).__name__


def load_database(path: str | os.PathLike[str]) -> Database:
    """Load a DBC file, leniently if cantools' strict checking rejects it.

    Strict loading is tried first. If cantools rejects the file only because of its strict
    checks (overlapping signals, signals beyond the frame, ...), the file is loaded again without
    them and a warning names what was rejected: such a database still decodes every signal that
    is laid out correctly.

    Parameters
    ----------
    path : str or os.PathLike
        The DBC file. It is parsed as DBC whatever its suffix.

    Returns
    -------
    cantools.database.can.Database
        The database.

    Raises
    ------
    DbcError
        If the file does not exist, is a directory, cannot be read, is not a DBC, or defines no
        message.
    """
    path = Path(path)
    if not path.exists():
        raise DbcError(f"CAN database {path} does not exist")
    if path.is_dir():
        raise DbcError(f"CAN database {path} is a directory, not a DBC file")
    try:
        with path.open("rb") as handle:
            binary = b"\0" in handle.read(4096)
    except OSError as error:
        raise DbcError(f"cannot read CAN database {path}: {error.strerror or error}") from error
    if binary:  # cantools would quote its bytes as the syntax error
        raise DbcError(
            f"{path} is a binary file, not a DBC (a text file of BO_ and SG_ lines): was a "
            "recording given as the database?"
        )
    try:
        try:
            database = cantools.database.load_file(path, database_format="dbc", strict=True)
        except cantools.database.UnsupportedDatabaseFormatError as strict_error:
            database = cantools.database.load_file(path, database_format="dbc", strict=False)
            logger.warning(
                "%s: strict checking rejected the database (%s); loaded it without strict "
                "checking, so the signals named there may decode wrongly",
                path.name,
                _reason(strict_error),
            )
    except cantools.database.UnsupportedDatabaseFormatError as error:
        raise DbcError(f"{path} is not a valid DBC file: {_reason(error)}") from error
    except OSError as error:
        raise DbcError(f"cannot read CAN database {path}: {error.strerror or error}") from error
    if not database.messages:
        raise DbcError(f"CAN database {path} defines no messages")
    return database
