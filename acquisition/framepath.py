"""The daemon's per-frame path: every frame to the log, then in blocks to the event stream.

For each frame taken from the bus (:meth:`FramePath.take`):

1. its receive timestamp is mapped to bus time (:class:`dtid.acquisition.clock.BusClock`);
2. on the tool's own IDs, an echo of a frame the daemon sent is dropped, anything else there is
   counted as ``foreign_tx`` and raises the alarm (:class:`dtid.acquisition.health.EchoFilter`);
3. it is written to the raw log (:class:`dtid.acquisition.recorder.Recorder`);
4. it joins the pending block.

The daemon's own frames join at step 3 with their sending time (:meth:`FramePath.take_sent`).
:meth:`FramePath.publish_block` decodes the pending block with
:meth:`dbc.VehicleInterface.decode` (message by message, see :func:`message_decoders`), updates
the health counts and the safety monitor, and publishes one ``samples`` event; a ``health`` event
follows when a count changed (at most every :data:`HEALTH_PERIOD_S`). The ``session`` event goes
out before any other, right after the first frame is written to the log. All events go through
:meth:`FramePath.publish`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, replace
from types import MappingProxyType
from typing import Any

import can

from dtid.acquisition.clock import BusClock
from dtid.acquisition.health import EchoFilter, Health
from dtid.acquisition.recorder import Recorder
from dtid.acquisition.safety import SafetyMonitor
from dtid.acquisition.server import EventServer
from dtid.acquisition.stream import samples_roles
from dtid.dbc.interface import RoleSeries, VehicleInterface
from dtid.dbc.interface import logger as interface_logger
from dtid.dbc.signal_map import RoleSpec

HEALTH_PERIOD_S = 0.5
"""Shortest wall time between two health events, s (the last counts always go out at the end)."""


class FramePath:
    """Record, decode, check and publish the frames of one session.

    Parameters
    ----------
    interface
        DBC and signal map to decode with.
    clock
        The bus clock.
    recorder
        The session's raw log.
    server
        The session's event server.
    echo
        The session's echo filter.
    session_fields
        Keys of the ``session`` event besides ``log_path`` and ``log_start_s`` (``plan``,
        ``interface``, ``time_factor``).

    Attributes
    ----------
    health : Health
        Counts of the session.
    safety : SafetyMonitor or None
        Checks each block's speed once the test has started.
    alarm : str or None
        The first abort reason found in the frames (``foreign_tx`` or ``speed_window``).
    speed_seen : bool
        True once a speed frame was decoded.
    """

    def __init__(
        self,
        interface: VehicleInterface,
        clock: BusClock,
        recorder: Recorder,
        server: EventServer,
        echo: EchoFilter,
        session_fields: Mapping[str, Any],
    ) -> None:
        self._clock = clock
        self._recorder = recorder
        self._write = recorder.write
        self._server = server
        self._echo = echo
        self._tx_ids = echo.tx_ids
        self._session_fields = dict(session_fields)
        self._pending = 0
        self._decoders = message_decoders(interface)
        self._buckets: dict[int, list[can.Message]] = {key: [] for key in self._decoders}
        self._first_wall: float | None = None
        self._last_health: tuple[int, ...] = (0,) * 6
        self._first_warnings = _FirstOfEach()
        self._last_health_wall = 0.0
        self.health = Health(interface)
        self.safety: SafetyMonitor | None = None
        self.alarm: str | None = None
        self.speed_seen = False

    @property
    def pending(self) -> int:
        """Frames waiting for the next samples event."""
        return self._pending

    def take(self, frame: can.Message) -> None:
        """Take a received frame (timestamp: wall receive time, s)."""
        wall = frame.timestamp
        if not self._clock.identity:
            frame.timestamp = self._clock.to_bus(wall)
        arbitration_id = frame.arbitration_id
        if arbitration_id in self._tx_ids and self._echo.is_tool_frame(frame):
            if self._echo.is_echo(frame):
                return
            self.health.counts.foreign_tx += 1
            self.alarm = self.alarm or "foreign_tx"
        self._write(frame)
        if not self._pending:
            self._first_wall = wall
        self._pending += 1
        bucket = self._buckets.get(arbitration_id)
        if bucket is not None:
            bucket.append(frame)

    def take_sent(self, frame: can.Message) -> None:
        """Take a frame the daemon sent (timestamp: bus time of sending, s)."""
        self._write(frame)
        if not self._pending:
            self._first_wall = self._clock.to_wall(frame.timestamp)
        self._pending += 1
        self._buckets[frame.arbitration_id].append(frame)

    def publish_block(self, final: bool = False) -> None:
        """Decode the pending frames, check them and publish their samples event.

        A block that decodes to no samples (only frames the signal map does not use, or bad
        ones) publishes nothing: its frames are counted in the next samples event. On a bus
        busy with other traffic an event per block would fill the replay (every event of a
        session is kept) with empty ones: 500 a second at full load. ``final`` publishes
        whatever is pending.
        """
        decoded: dict[str, RoleSeries] = {}
        with self._first_warnings.on(interface_logger):  # the health events count the rest
            for arbitration_id, bucket in self._buckets.items():
                if bucket:
                    for decoder in self._decoders[arbitration_id]:
                        decoded.update(decoder.decode(bucket))
                    bucket.clear()
        self.health.update(decoded)
        speed = decoded.get("speed")
        if speed is not None and len(speed.timestamps):
            self.speed_seen = True
            if self.safety is not None:
                self.alarm = self.alarm or self.safety.on_speed(speed.timestamps, speed.values)
        roles = samples_roles(decoded)
        if roles or final or self._server.count == 0:
            self.publish(
                "samples",
                {"roles": roles, "frames": self._pending, "received_wall_s": self._first_wall},
            )
            self._pending = 0
        counts = self.health.counts.anomalies()
        now = time.monotonic()
        if counts != self._last_health and now - self._last_health_wall >= HEALTH_PERIOD_S:
            self.publish_health()

    def publish_health(self) -> None:
        """Publish the current health counts."""
        counts = self.health.counts
        counts.frames = self._recorder.frames
        self._last_health = counts.anomalies()
        self._last_health_wall = time.monotonic()
        self.publish("health", asdict(counts))

    def publish(self, kind: str, fields: Mapping[str, Any]) -> dict[str, Any]:
        """Publish an event, after the ``session`` event if that has not gone out yet."""
        if self._server.count == 0:
            self._server.publish(
                "session",
                {
                    "log_path": str(self._recorder.path),
                    "log_start_s": self._recorder.first_timestamp,
                    **self._session_fields,
                },
            )
        return self._server.publish(kind, fields)


def message_decoders(interface: VehicleInterface) -> dict[int, list[VehicleInterface]]:
    """The interface split by message: for each arbitration ID of a mapped message, interfaces
    that decode only that message's roles (one per message with that ID, standard or extended).

    Decoding a block message by message skips the empty series of the roles a block lacks, which
    dominate the cost of a small block.
    """
    by_message: dict[str, dict[str, RoleSpec]] = {}
    for role, spec in interface.signal_map.roles.items():
        by_message.setdefault(spec.message, {})[role] = spec
    decoders: dict[int, list[VehicleInterface]] = {}
    quiet = _DropWarnings()  # warnings of the binding were given for the whole interface
    interface_logger.addFilter(quiet)
    try:
        for roles in by_message.values():
            signal_map = replace(interface.signal_map, roles=MappingProxyType(roles))
            decoder = signal_map.bind(interface.database)
            arbitration_id, _ = decoder.frame_key(next(iter(roles)))
            decoders.setdefault(arbitration_id, []).append(decoder)
    finally:
        interface_logger.removeFilter(quiet)
    return decoders


class _FirstOfEach(logging.Filter):
    """Passes the first of each kind of decoding warning per role in a session; the blocks come
    four a second, and the health events count the frames of the rest (``bad_frames``,
    ``not_measured``).

    It sits on the interface's module logger only while a block decodes (:meth:`on`), and judges
    only the records of the thread decoding it: another thread's pass untouched.
    """

    def __init__(self) -> None:
        super().__init__()
        self._seen: set[tuple[object, object]] = set()
        self._thread: int | None = None

    @contextmanager
    def on(self, logger: logging.Logger) -> Iterator[None]:
        """Filter ``logger``'s records of the calling thread for the ``with`` block."""
        self._thread = threading.get_ident()
        logger.addFilter(self)
        try:
            yield
        finally:
            logger.removeFilter(self)
            self._thread = None

    def filter(self, record: logging.LogRecord) -> bool:
        if record.thread != self._thread:
            return True
        args = record.args if isinstance(record.args, tuple) else ()
        key = (record.msg, args[0] if args else None)
        if key in self._seen:
            return False
        self._seen.add(key)
        return True


class _DropWarnings(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno > logging.WARNING
