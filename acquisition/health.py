"""Health of the bus as the daemon sees it: lost, duplicated, out-of-order, bad and foreign frames.

Crank-synchronous frames carry rolling counters (product DBC: ``CrankEventCounter`` 16 bits,
``StrokeCounter`` and ``RequestCounter`` 8 bits; the widths are read from the DBC). Counting them
per role, a step of one is the normal case; a step of 0 is a duplicate; a forward step of ``k``
(less than half the counter's range) means ``k - 1`` frames lost; a backward step means a frame
arriving late. A late frame that fills a hole counts as out of order and no longer as lost; one
whose counter was already seen counts as a duplicate. Holes more than half the range behind the
newest counter are final (lost).

Echoes: python-can's ``udp_multicast`` delivers a sender's own frames back to it (SocketCAN does
not, unless ``receive_own_messages``). A received frame with the ID and payload of a frame the
daemon sent within the last :data:`ECHO_WINDOW_S` (wall) is such an echo and is dropped before
anything records it (the log holds the sent frame already). Any other frame on the tool's own IDs
was sent by another node: ``foreign_tx``, which aborts the test. A foreign frame identical to one
the daemon sent moments before cannot be told from an echo.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import can
import numpy as np

from dtid.dbc.interface import RoleSeries, VehicleInterface

COUNTED_ROLES = ("speed", "mean_torque", "torque_request")
"""Crank-synchronous roles whose counters are checked."""
ECHO_WINDOW_S = 2.0
"""Longest wall time after sending within which an identical received frame is an echo, s."""


class CounterTracker:
    """Lost, duplicated and out-of-order frames of one role from its rolling counter.

    Parameters
    ----------
    modulo
        Number of counter values (2 ** signal length).

    Attributes
    ----------
    lost, duplicated, out_of_order : int
        Cumulative counts.
    """

    def __init__(self, modulo: int) -> None:
        if modulo < 4:
            raise ValueError(f"a rolling counter needs at least 2 bits, got modulo {modulo}")
        self.modulo = modulo
        self.lost = 0
        self.duplicated = 0
        self.out_of_order = 0
        self._half = modulo // 2
        self._newest: int | None = None  # unwrapped position of the newest counter
        self._holes: set[int] = set()  # unwrapped positions not yet seen

    def update(self, counters: np.ndarray) -> None:
        """Take the counters of newly received frames, in arrival order."""
        if len(counters) == 0:
            return
        values = counters.astype(np.int64) % self.modulo
        if self._newest is not None and not self._holes:
            steps = np.diff(values, prepend=self._newest % self.modulo) % self.modulo
            if np.all(steps == 1):  # the normal case, without a Python loop
                self._newest += len(values)
                return
        for value in values.tolist():
            self._take(value)

    def _take(self, value: int) -> None:
        if self._newest is None:
            self._newest = value
            return
        step = (value - self._newest) % self.modulo
        if step == 0:
            self.duplicated += 1
        elif step < self._half:
            self.lost += step - 1
            self._holes.update(range(self._newest + 1, self._newest + step))
            self._newest += step
            horizon = self._newest - self._half
            if any(hole <= horizon for hole in self._holes):
                self._holes = {hole for hole in self._holes if hole > horizon}
        else:
            position = self._newest - (self.modulo - step)
            if position in self._holes:
                self._holes.discard(position)
                self.lost -= 1
                self.out_of_order += 1
            else:
                self.duplicated += 1


@dataclass
class HealthCounts:
    """Cumulative counts of a session (the keys of a ``health`` event)."""

    lost: int = 0
    duplicated: int = 0
    out_of_order: int = 0
    bad_frames: int = 0
    foreign_tx: int = 0
    frames: int = 0
    not_measured: int = 0

    def anomalies(self) -> tuple[int, int, int, int, int, int]:
        """Every count but ``frames``: a change of these is worth a health event."""
        return (
            self.lost,
            self.duplicated,
            self.out_of_order,
            self.bad_frames,
            self.foreign_tx,
            self.not_measured,
        )


class Health:
    """Counter and bad-frame bookkeeping of the decoded blocks of a session.

    Parameters
    ----------
    interface
        The vehicle interface; the counter widths come from its DBC.
    """

    def __init__(self, interface: VehicleInterface) -> None:
        self.counts = HealthCounts()
        self._trackers = {
            role: CounterTracker(modulo)
            for role, modulo in counter_moduli(interface, COUNTED_ROLES).items()
        }
        self._message_of = {role: spec.message for role, spec in interface.signal_map.roles.items()}

    def update(self, decoded: Mapping[str, RoleSeries]) -> None:
        """Count the lost, duplicated, out-of-order and bad frames of one decoded block, and
        those that carry no measurement (:attr:`dtid.dbc.interface.RoleSeries.not_measured`)."""
        for role, tracker in self._trackers.items():
            series = decoded.get(role)
            if series is not None:
                tracker.update(series.extra["counter"])
        bad_by_message = {self._message_of[role]: s.n_bad for role, s in decoded.items()}
        counts = self.counts
        counts.bad_frames += sum(bad_by_message.values())
        counts.not_measured += sum(s.not_measured for s in decoded.values())
        counts.lost = sum(t.lost for t in self._trackers.values())
        counts.duplicated = sum(t.duplicated for t in self._trackers.values())
        counts.out_of_order = sum(t.out_of_order for t in self._trackers.values())


def counter_moduli(interface: VehicleInterface, roles: Iterable[str]) -> dict[str, int]:
    """Number of values of each role's ``counter`` signal (roles without one are left out)."""
    moduli = {}
    for role in roles:
        spec = interface.signal_map.roles.get(role)
        if spec is None or spec.counter is None:
            continue
        message = interface.database.get_message_by_name(spec.message)
        moduli[role] = 1 << message.get_signal_by_name(spec.counter).length
    return moduli


class EchoFilter:
    """Tell echoes of the daemon's own frames from frames another node sends on its IDs.

    Thread-safe: the sender thread announces frames, the receive loop classifies.

    Parameters
    ----------
    tx_keys
        ``(arbitration_id, is_extended_id)`` of the tool's own messages.
    window_s
        :data:`ECHO_WINDOW_S` unless given.
    """

    def __init__(
        self, tx_keys: Iterable[tuple[int, bool]], window_s: float = ECHO_WINDOW_S
    ) -> None:
        self.tx_ids = frozenset(key[0] for key in tx_keys)
        """Arbitration IDs of the tool's messages (a quick pre-check)."""
        self._tx_keys = frozenset(tx_keys)
        self._window_s = window_s
        self._pending: dict[tuple[int, bool, bytes], deque[float]] = {}
        self._sent: deque[tuple[float, tuple[int, bool, bytes]]] = deque()
        self._lock = threading.Lock()
        self.echoes = 0
        """Echoes dropped."""

    def expect(self, frame: can.Message) -> None:
        """Announce a frame about to be sent (call before sending it)."""
        key = (frame.arbitration_id, frame.is_extended_id, bytes(frame.data))
        now = time.monotonic()
        with self._lock:
            self._expire(now)
            self._pending.setdefault(key, deque()).append(now)
            self._sent.append((now, key))

    def is_tool_frame(self, frame: can.Message) -> bool:
        """True for a data frame on one of the tool's own IDs."""
        return (
            (frame.arbitration_id, frame.is_extended_id) in self._tx_keys
            and not frame.is_error_frame
            and not frame.is_remote_frame
        )

    def is_echo(self, frame: can.Message) -> bool:
        """For a frame on the tool's IDs: True if it is an echo (and consume it), else foreign."""
        key = (frame.arbitration_id, frame.is_extended_id, bytes(frame.data))
        with self._lock:
            self._expire(time.monotonic())
            times = self._pending.get(key)
            if not times:
                return False
            times.popleft()  # the oldest send of this frame not yet echoed
            self.echoes += 1
            return True

    def _expire(self, now: float) -> None:
        sent = self._sent
        while sent and now - sent[0][0] > self._window_s:
            sent_at, key = sent.popleft()
            times = self._pending.get(key)
            if times and times[0] <= sent_at:
                times.popleft()
            if not times:
                self._pending.pop(key, None)
