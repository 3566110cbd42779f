"""The event stream from the acquisition daemon to the worker: schema and ZeroMQ framing.

The daemon numbers every event of a test session (``seq`` from 0, no gaps) and keeps all of them
until it exits; it publishes each on its PUB socket as two frames ``[kind, JSON]`` and hands out
the kept ones on its REP socket (request ``{"from_seq": N}``, reply: one JSON list of at most
:data:`REPLAY_PAGE` events from N on; a full page means there may be more: ask again from the
next ``seq``). A worker that starts late or restarts subscribes first, then asks for the past,
page by page, and merges by ``seq``: it loses nothing.

Event kinds and their keys besides ``kind``, ``session`` and ``seq``:

``session``
    ``log_path`` (the raw log being written), ``log_start_s`` (timestamp of its first frame, s;
    times in recordings are relative to it), ``plan`` (the test's keys of
    :class:`dtid.acquisition.plan.TestPlan`), ``interface`` (``dbc`` and ``signals`` paths or
    null for the product's own), ``time_factor``. Always seq 0.
``samples``
    ``roles``: per mapped role ``{"t": [...], "value": [...], <extra>: [...]}`` with the
    absolute timestamps (s, as in the log), values in the role's canonical unit and the raw extra
    signals of the map (``counter``, ``cylinder``, ``enable``); ``frames``: frames recorded since
    the last samples event; ``received_wall_s``: wall-clock receive time of the first of them
    (``time.time()``), for latency.
``phase``
    ``phase`` (``settle``, ``chirp``, ``pause``, ``done``), ``t_s`` (bus time), ``chirp`` (index
    in the plan, or null) and ``amplitude_nm`` (or null).
``health``
    Cumulative counts: ``lost``, ``duplicated``, ``out_of_order`` (crank-synchronous frames, from
    their counters), ``bad_frames`` (wrong length or undecodable), ``foreign_tx`` (frames with
    the tool's own IDs that it did not send), ``frames`` (all recorded), ``not_measured`` (frames
    left out that carry no measurement: a value the DBC names outside the signal's range, or the
    map's validity flag not valid).
``end``
    ``status`` (``completed`` or ``aborted``), ``reason`` (why, for an abort; else null),
    ``t_s`` (bus time).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from dtid.dbc.interface import RoleSeries

KINDS = ("session", "samples", "phase", "health", "end")
REPLAY_PAGE = 500
"""Most events one replay answer carries (about 2 MB of samples): a long session is never sent
as one message."""
"""Event kinds, also the PUB topics."""

ABORT_REASONS = {
    "speed_window": "the filtered engine speed left the window around the idle set-point",
    "vehicle_timeout": "no engine speed frame arrived within the vehicle timeout",
    "foreign_tx": "another node sends frames with the tool's own test-torque request ID",
    "signal": "the daemon was told to stop (SIGINT or SIGTERM)",
    "error": "the daemon failed (bus error or internal error); see its log",
    "bus_error": "the CAN bus reported an error (bus-off, interface down, send buffer full); "
    "the zero requests were sent as far as the bus took them",
    "log_write": "the raw log cannot be written (a full disk, a removed output directory); "
    "what was written before is kept",
}
"""Why a test may be aborted: the ``reason`` of an aborted ``end`` event."""


def encode_event(event: Mapping[str, Any]) -> list[bytes]:
    """The two ZeroMQ frames of an event: topic and JSON body."""
    return [event["kind"].encode(), json.dumps(event, separators=(",", ":")).encode()]


def decode_event(frames: list[bytes]) -> dict[str, Any]:
    """An event from its ZeroMQ frames (see :func:`encode_event`)."""
    event = json.loads(frames[-1])
    if event.get("kind") not in KINDS or "seq" not in event or "session" not in event:
        raise ValueError(f"not a drivetrain-id event: {frames[-1][:80]!r}")
    return event


def samples_roles(decoded: Mapping[str, RoleSeries]) -> dict[str, dict[str, list[float | int]]]:
    """The ``roles`` of a samples event from decoded frames (roles without samples left out)."""
    roles: dict[str, dict[str, list[float | int]]] = {}
    for role, series in decoded.items():
        if len(series.timestamps) == 0:
            continue
        entry: dict[str, list[float | int]] = {
            "t": series.timestamps.tolist(),
            "value": series.values.tolist(),
        }
        for key, column in series.extra.items():
            entry[key] = column.tolist()
        roles[role] = entry
    return roles


def series_from_samples(
    events: Iterable[Mapping[str, Any]], roles: Iterable[str]
) -> dict[str, RoleSeries]:
    """Join the samples events of a session (in ``seq`` order) into one series per role.

    Parameters
    ----------
    events
        Events of one session; kinds other than ``samples`` are skipped.
    roles
        The roles to return (an empty series for a role no event carried).
    """
    parts: dict[str, dict[str, list[np.ndarray]]] = {role: {} for role in roles}
    for event in events:
        if event["kind"] != "samples":
            continue
        for role, entry in event["roles"].items():
            if role not in parts:
                continue
            for key, column in entry.items():
                dtype = np.float64 if key in ("t", "value") else np.int64
                parts[role].setdefault(key, []).append(np.asarray(column, dtype=dtype))
    return {
        role: RoleSeries(
            role=role,
            timestamps=_joined(columns, "t", np.float64),
            values=_joined(columns, "value", np.float64),
            extra={
                key: _joined(columns, key, np.int64) for key in columns if key not in ("t", "value")
            },
            n_bad=0,
        )
        for role, columns in parts.items()
    }


def _joined(columns: Mapping[str, list[np.ndarray]], key: str, dtype: type) -> np.ndarray:
    chunks = columns.get(key)
    return np.concatenate(chunks) if chunks else np.zeros(0, dtype=dtype)
