"""What travels with a recording: the session's metadata and what the log kept of the bus.

A recording alone does not say which vehicle, DBC, signal map, test plan or software made it; an
engineer who finds it months later, or a fleet table, needs to. The metadata is a JSON object
(schema ``docs/schemas/recording-metadata.schema.json``):

- ``schema``: :data:`SCHEMA`;
- ``session``: the session's name; ``started_utc``: ISO 8601 time of its start; ``source``: what
  wrote it (``dtid acquire``, ``dtid simulate``); ``vehicle``: its name or VIN, if said;
- ``software``: versions of drivetrain-id, python-can, cantools, numpy and Python;
- ``interface``: the DBC and the signal map (file name and SHA-256 each) and the roles as
  ``MESSAGE.SIGNAL``;
- ``plan``: the test plan; ``bus``: interface, channel, time factor (where a bus was used);
- ``integrity``: frames written, frames lost, whether the log was closed cleanly and why not;
- ``outcome``: how the daemon's test ended (``status``, abort ``reason``, the health counters);
  None until it ends, and for a simulated recording.

Where it goes: inside an .mf4 file, in the header comment (:mod:`dtid.acquisition.mf4`); beside
any other log, in a sidecar ``<log name>.json`` (``session.blf`` -> ``session.blf.json``). The
daemon writes the sidecar when the session starts (``closed`` false) and again at its end, so a
session that dies still leaves its metadata.
"""

from __future__ import annotations

import datetime
import hashlib
import importlib.metadata
import json
import os
import platform
from pathlib import Path
from typing import Any

from dtid.acquisition.mf4 import read_mf4_metadata
from dtid.dbc.interface import VehicleInterface
from dtid.errors import RecordingError

SCHEMA = "dtid-recording-metadata/1"
"""Value of the metadata's ``schema`` key."""
_PACKAGES = ("drivetrain-id", "python-can", "cantools", "numpy", "asammdf")


def software_versions() -> dict[str, str]:
    """Versions of the packages that write and read a recording, and of Python."""
    versions = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def file_digest(path: str | os.PathLike[str]) -> dict[str, str]:
    """A file's name and SHA-256 (hex), to tell later which DBC or map was used."""
    path = Path(path)
    return {"file": path.name, "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}


def session_metadata(
    *,
    session: str,
    started_s: float,
    source: str,
    interface: VehicleInterface,
    plan: dict[str, Any] | None = None,
    bus: dict[str, Any] | None = None,
    vehicle: str | None = None,
) -> dict[str, Any]:
    """The metadata of a session, before its integrity is known.

    Parameters
    ----------
    session
        The session's name (the daemon's session directory, a simulated recording's file stem).
    started_s
        Start of the session, s since the Unix epoch (a simulated one: when it was simulated).
    source
        What wrote the recording, e.g. ``dtid acquire``.
    interface
        The DBC and signal map that read the recording (their files are hashed, the roles listed
        as ``MESSAGE.SIGNAL``).
    plan
        The test plan as a dictionary (:meth:`dtid.acquisition.plan.TestPlan.as_dict`).
    bus
        Bus settings (interface, channel, time factor); None where no bus was used.
    vehicle
        The vehicle's name or VIN; None when not said.
    """
    started = datetime.datetime.fromtimestamp(started_s, datetime.UTC)
    return {
        "schema": SCHEMA,
        "session": session,
        "started_utc": started.isoformat(timespec="milliseconds"),
        "source": source,
        "vehicle": vehicle or None,
        "software": software_versions(),
        "interface": interface_metadata(interface),
        "plan": plan,
        "bus": bus,
        "integrity": {"frames": 0, "lost": 0, "closed": False, "failure": None},
        "outcome": None,
    }


def interface_metadata(interface: VehicleInterface) -> dict[str, Any]:
    """The metadata's ``interface``: the DBC and signal map (file, SHA-256) and the roles."""
    return {
        "dbc": file_digest(interface.dbc_source) if interface.dbc_source else None,
        "signal_map": file_digest(interface.signal_map.source),
        "roles": {
            role: f"{spec.message}.{spec.signal}"
            for role, spec in sorted(interface.signal_map.roles.items())
        },
    }


def with_integrity(
    metadata: dict[str, Any], frames: int, lost: int, closed: bool, failure: str | None
) -> dict[str, Any]:
    """A copy of ``metadata`` with what the log kept: frames written and lost, clean close."""
    return {
        **metadata,
        "integrity": {"frames": frames, "lost": lost, "closed": closed, "failure": failure},
    }


def journal_path(log: str | os.PathLike[str]) -> Path:
    """The crash-safe BLF journal an .mf4 session is recorded in until it ends
    (:class:`dtid.acquisition.recorder.Recorder`): ``<stem>.journal.blf`` beside it."""
    log = Path(log)
    return log.with_name(f"{log.stem}.journal.blf")


def session_log_metadata(log: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The metadata of a session's log, or of its journal while an .mf4 session is still being
    recorded or converted (:func:`read_metadata` of whichever exists).

    Raises
    ------
    RecordingError
        As :func:`read_metadata` (an .mf4 file still being written is unreadable).
    """
    log = Path(log)
    journal = journal_path(log)
    return read_metadata(log if log.exists() or not journal.exists() else journal)


def sidecar_path(log: str | os.PathLike[str]) -> Path:
    """The sidecar JSON of a log: its name with ``.json`` appended."""
    log = Path(log)
    return log.with_name(log.name + ".json")


def write_sidecar(log: str | os.PathLike[str], metadata: dict[str, Any]) -> Path:
    """Write (or replace) a log's sidecar JSON, whole or not at all.

    Raises
    ------
    RecordingError
        If it cannot be written.
    """
    path = sidecar_path(log)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        temporary.write_text(json.dumps(metadata, indent=2, sort_keys=True) + "\n")
        temporary.replace(path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        raise RecordingError(
            f"cannot write the metadata {path}: {error.strerror or error}"
        ) from error
    return path


def read_metadata(log: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The metadata that travels with a recording: an .mf4 file's header, else its sidecar.

    Returns None when there is none (a recording from another tool). A sidecar that is not a
    JSON object is reported, not ignored.

    Raises
    ------
    RecordingError
        If the sidecar exists but cannot be read as a JSON object.
    """
    log = Path(log)
    if log.suffix.lower() == ".mf4":
        return read_mf4_metadata(log)
    path = sidecar_path(log)
    if not path.exists():
        return None
    try:
        value = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RecordingError(
            f"the metadata {path} of recording {log} is not readable JSON ({error}); move it "
            "aside to read the recording without it"
        ) from error
    if not isinstance(value, dict):
        raise RecordingError(f"the metadata {path} of recording {log} is not a JSON object")
    return value


def interface_differences(metadata: dict[str, Any], interface: VehicleInterface) -> list[str]:
    """How the DBC and signal map a recording is read with differ from those it was made with.

    Returns one sentence per difference (a file whose content changed, a role bound to another
    signal); empty when they agree or the metadata does not say.
    """
    recorded = metadata.get("interface") or {}
    now = interface_metadata(interface)
    differences = []
    for key, what in (("dbc", "DBC"), ("signal_map", "signal map")):
        then, current = recorded.get(key), now[key]
        if then and current and then.get("sha256") != current["sha256"]:
            differences.append(
                f"the {what} differs from the one the recording was made with "
                f"({then.get('file')}, SHA-256 {str(then.get('sha256'))[:12]}...)"
            )
    for role, signal in (recorded.get("roles") or {}).items():
        if now["roles"].get(role, signal) != signal:
            differences.append(
                f"role '{role}' was recorded as {signal}, is read as {now['roles'][role]}"
            )
    return differences
