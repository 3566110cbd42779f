"""How the engine ECU accepts the tool's test-torque requests (the vehicle side of the safety
envelope).

The ECU applies a request only while the stream of requests is healthy: a frame whose checksum
is wrong, or whose alive counter does not advance by exactly one from the last accepted frame, is
dropped; and when no valid frame has arrived for the signal map's ``timeout_s`` of bus time
(:data:`dtid.dbc.roles.DEFAULT_REQUEST_TIMEOUT_S` unless the map gives it), or the last valid frame
has TestEnable = 0, the test torque is zero. After a timeout the next valid frame is accepted
whatever its counter (the stream restarted).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import can

from dtid.dbc.checksum import verify_checksum
from dtid.dbc.interface import VehicleInterface

COUNTER_MODULO = 16
"""The alive counter's wrap (4 bits in the product DBC)."""


@dataclass
class RequestReceiver:
    """The ECU's view of the test-torque request.

    Parameters
    ----------
    interface
        DBC and signal map the requests are decoded with.
    timeout_s
        The signal map's ``timeout_s`` of the test torque unless given, s.

    Attributes
    ----------
    dropped
        Frames dropped, by reason (``checksum``, ``counter``, ``undecodable``).
    accepted
        Frames accepted.
    """

    interface: VehicleInterface
    timeout_s: float | None = None
    dropped: Counter[str] = field(default_factory=Counter)
    accepted: int = 0
    _value_nm: float = 0.0
    _last_valid_s: float | None = None
    _last_counter: int | None = None

    def __post_init__(self) -> None:
        self._key = self.interface.frame_key("test_torque")
        self._checksum = self.interface.checks_checksum("test_torque")
        spec = self.interface.signal_map.roles["test_torque"]
        if self.timeout_s is None:
            self.timeout_s = spec.timeout_s
        self._has_counter = bool(spec.counter)
        self._has_enable = bool(spec.enable)

    def is_request(self, frame: can.Message) -> bool:
        """True when the frame is the test-torque request's message."""
        return (frame.arbitration_id, frame.is_extended_id) == self._key

    def receive(self, frame: can.Message, now_s: float) -> None:
        """Take a request frame received at bus time ``now_s`` (s)."""
        if self._checksum and not (len(frame.data) == 8 and verify_checksum(frame.data)):
            self.dropped["checksum"] += 1
            return
        series = self.interface.decode([frame])["test_torque"]
        if len(series.values) != 1:
            self.dropped["undecodable"] += 1
            return
        timed_out = self.timed_out(now_s)
        if self._has_counter:
            counter = int(series.extra["counter"][0])
            expected = None if self._last_counter is None else (self._last_counter + 1)
            if not timed_out and expected is not None and counter != expected % COUNTER_MODULO:
                self.dropped["counter"] += 1
                return
            self._last_counter = counter
        enabled = not self._has_enable or int(series.extra["enable"][0]) == 1
        self._value_nm = float(series.values[0]) if enabled else 0.0
        self._last_valid_s = now_s
        self.accepted += 1

    @property
    def last_valid_s(self) -> float | None:
        """Bus time of the last accepted request, s (None before the first)."""
        return self._last_valid_s

    def timed_out(self, now_s: float) -> bool:
        """True when no valid request has arrived within the timeout before ``now_s``."""
        return self._last_valid_s is None or now_s - self._last_valid_s > self.timeout_s

    def test_torque(self, now_s: float) -> float:
        """Test torque the ECU applies at bus time ``now_s``, N*m (zero after a timeout)."""
        return 0.0 if self.timed_out(now_s) else self._value_nm
