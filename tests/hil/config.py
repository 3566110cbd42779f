"""The configuration file of a scenario: dtid.acquisition.config keys, written into a test's folder.

:func:`write_scenario_config` puts the HIL bus in ``[bus]``, the ZeroMQ ipc endpoints and the
output folder inside the scenario's own folder (so runs never meet each other or a real
installation's ``/run/dtid``), merges the scenario's own keys, and loads the file back with
:func:`dtid.acquisition.config.load_config`, so a wrong key fails here and not inside a daemon.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dtid.acquisition.config import AcquisitionConfig, load_config
from hil.namespace import HilBus

UNIX_PATH_MAX = 107
"""Longest path of a Unix socket (an ipc:// endpoint), bytes."""


def toml_value(value: Any) -> str:
    """One TOML value: string, path, bool, int, float, list of numbers, table of those."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"TOML value must be finite, got {value}")
        return repr(value)
    if isinstance(value, str | Path):
        text = str(value).replace("\\", "\\\\").replace('"', '\\"')
        return f'"{text}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(item) for item in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{key} = {toml_value(item)}" for key, item in value.items()) + "}"
    raise TypeError(f"no TOML for {value!r}")


def toml_document(sections: Mapping[str, Mapping[str, Any]]) -> str:
    """A TOML document of ``[section]`` tables of ``key = value`` lines."""
    lines: list[str] = []
    for section, values in sections.items():
        lines.append(f"[{section}]")
        lines.extend(f"{key} = {toml_value(value)}" for key, value in values.items())
        lines.append("")
    return "\n".join(lines)


def scenario_sections(
    directory: Path, bus: HilBus, sections: Mapping[str, Mapping[str, Any]] | None = None
) -> dict[str, dict[str, Any]]:
    """The sections of a scenario's configuration: harness defaults updated by ``sections``."""
    ipc = directory / "ipc"
    merged: dict[str, dict[str, Any]] = {
        "bus": bus.bus_settings(),
        "output": {"directory": str(directory / "runs")},
        "pipeline": {name: f"ipc://{ipc / name}" for name in ("blocks", "replay", "results")},
    }
    for section, values in (sections or {}).items():
        merged.setdefault(section, {}).update(values)
    for name in ("blocks", "replay", "results"):
        endpoint = str(merged["pipeline"][name])
        if endpoint.startswith("ipc://") and len(endpoint[6:].encode()) > UNIX_PATH_MAX:
            raise ValueError(
                f"ipc endpoint {endpoint} is longer than a Unix socket path may be "
                f"({UNIX_PATH_MAX} bytes): use a shorter scenario folder"
            )
    return merged


def write_scenario_config(
    directory: Path,
    bus: HilBus,
    sections: Mapping[str, Mapping[str, Any]] | None = None,
    name: str = "dtid.toml",
) -> tuple[Path, AcquisitionConfig]:
    """Write the configuration file of a scenario into ``directory``.

    Parameters
    ----------
    directory
        The scenario's folder; ``ipc/`` (endpoints) and ``runs/`` (output) are made in it.
    bus
        The HIL bus (:func:`hil.namespace.hil_bus`), written as ``[bus]``.
    sections
        Keys per section that replace or add to the harness's, e.g.
        ``{"test": {"amplitudes_nm": [5, 10], "duration_s": 20}, "bus": {"time_factor": 20.0}}``.

    Returns
    -------
    (Path, AcquisitionConfig)
        The file and the configuration it loads to.
    """
    directory = Path(directory)
    (directory / "ipc").mkdir(parents=True, exist_ok=True)
    (directory / "runs").mkdir(parents=True, exist_ok=True)
    path = directory / name
    path.write_text(toml_document(scenario_sections(directory, bus, sections)))
    return path, load_config(path)
