"""How the engine ECU accepts the tool's test-torque requests: the vehicle side of the safety
envelope, and the one place its rules live.

The ECU applies a request only while the stream of requests is healthy: a frame whose checksum
is wrong, or whose alive counter does not advance by exactly one from the last accepted frame, is
dropped; and when no valid frame has arrived for the signal map's ``timeout_s`` of bus time
(:data:`dtid.dbc.roles.DEFAULT_REQUEST_TIMEOUT_S` unless the map gives it), or the last valid frame
has TestEnable = 0, the test torque is zero. After a timeout the next valid frame is accepted
whatever its counter (the stream restarted).

:class:`RequestAcceptance` holds these rules. The virtual vehicle's ECU applies them frame by
frame as they arrive (:class:`RequestReceiver`); the identification applies them to the requests
a recording holds, to know the test torque that actually drove the engine
(:func:`applied_test_torque`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

import can
import numpy as np

from dtid.dbc.checksum import verify_checksum
from dtid.dbc.interface import VehicleInterface

COUNTER_MODULO = 16
"""The alive counter's wrap (4 bits in the product DBC)."""


@dataclass
class RequestAcceptance:
    """The ECU's acceptance of test-torque requests (see the module notes).

    Parameters
    ----------
    timeout_s
        How long the ECU applies the last valid request, s.

    Attributes
    ----------
    dropped
        Requests dropped, by reason (``checksum``, ``counter``).
    accepted
        Requests accepted.
    """

    timeout_s: float
    dropped: Counter[str] = field(default_factory=Counter)
    accepted: int = 0
    _value_nm: float = 0.0
    _last_valid_s: float | None = None
    _last_counter: int | None = None

    def accept(
        self,
        now_s: float,
        value_nm: float,
        counter: int | None = None,
        enable: int | None = None,
        checksum_ok: bool = True,
    ) -> bool:
        """Take a request received at bus time ``now_s`` (s); True if it is applied.

        Parameters
        ----------
        value_nm
            The requested test torque, N*m.
        counter, enable
            Its alive counter and enable signal, where the signal map names them.
        checksum_ok
            Whether its checksum verifies (True where the frame carries none).
        """
        if not checksum_ok:
            self.dropped["checksum"] += 1
            return False
        if counter is not None:
            expected = None if self._last_counter is None else self._last_counter + 1
            fresh = self.timed_out(now_s) or expected is None
            if not fresh and counter != expected % COUNTER_MODULO:
                self.dropped["counter"] += 1
                return False
            self._last_counter = counter
        self._value_nm = value_nm if enable is None or enable == 1 else 0.0
        self._last_valid_s = now_s
        self.accepted += 1
        return True

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


@dataclass
class RequestReceiver:
    """The ECU's view of the test-torque request frames on its bus.

    Parameters
    ----------
    interface
        DBC and signal map the requests are decoded with.
    timeout_s
        The signal map's ``timeout_s`` of the test torque unless given, s.

    Attributes
    ----------
    rules
        The acceptance state (:class:`RequestAcceptance`).
    dropped
        Frames dropped, by reason (``checksum``, ``counter``, ``undecodable``).
    """

    interface: VehicleInterface
    timeout_s: float | None = None
    rules: RequestAcceptance = field(init=False)

    def __post_init__(self) -> None:
        self._key = self.interface.frame_key("test_torque")
        self._checksum = self.interface.checks_checksum("test_torque")
        spec = self.interface.signal_map.roles["test_torque"]
        if self.timeout_s is None:
            self.timeout_s = spec.timeout_s
        self.rules = RequestAcceptance(self.timeout_s)

    @property
    def dropped(self) -> Counter[str]:
        """Frames dropped, by reason."""
        return self.rules.dropped

    @property
    def accepted(self) -> int:
        """Frames accepted."""
        return self.rules.accepted

    @property
    def last_valid_s(self) -> float | None:
        """Bus time of the last accepted request, s (None before the first)."""
        return self.rules.last_valid_s

    def is_request(self, frame: can.Message) -> bool:
        """True when the frame is the test-torque request's message."""
        return (frame.arbitration_id, frame.is_extended_id) == self._key

    def receive(self, frame: can.Message, now_s: float) -> None:
        """Take a request frame received at bus time ``now_s`` (s)."""
        if self._checksum and not (len(frame.data) == 8 and verify_checksum(frame.data)):
            self.rules.dropped["checksum"] += 1
            return
        series = self.interface.decode([frame])["test_torque"]
        if len(series.values) != 1:
            self.rules.dropped["undecodable"] += 1
            return
        self.rules.accept(now_s, float(series.values[0]), **_signals(series.extra, 0))

    def timed_out(self, now_s: float) -> bool:
        """True when no valid request has arrived within the timeout before ``now_s``."""
        return self.rules.timed_out(now_s)

    def test_torque(self, now_s: float) -> float:
        """Test torque the ECU applies at bus time ``now_s``, N*m (zero after a timeout)."""
        return self.rules.test_torque(now_s)


def _signals(extra: Mapping[str, np.ndarray], index: int) -> dict[str, int | bool]:
    """The counter, enable and checksum verdict of one decoded request, where present."""
    found: dict[str, int | bool] = {}
    for key in ("counter", "enable"):
        if key in extra:
            found[key] = int(extra[key][index])
    if "checksum_ok" in extra:
        found["checksum_ok"] = bool(extra["checksum_ok"][index])
    return found


def applied_test_torque(
    times: np.ndarray,
    values: np.ndarray,
    extra: Mapping[str, np.ndarray],
    timeout_s: float,
) -> tuple[np.ndarray, np.ndarray, RequestAcceptance]:
    """The test torque the ECU applied, from the requests a recording holds.

    Each accepted request holds until the next one, and the torque is zero from ``timeout_s``
    after the last accepted request when none follows in time (the tool stalled, frames were
    lost); dropped requests change nothing.

    Parameters
    ----------
    times, values
        The requests in time order: bus times, s, and test torques, N*m.
    extra
        Their ``counter``, ``enable`` and ``checksum_ok``, where decoded
        (:class:`dtid.dbc.interface.RoleSeries`).
    timeout_s
        The ECU's request timeout, s.

    Returns
    -------
    times, values, rules
        The applied torque as steps (s, N*m: each value holds until the next time) and the
        acceptance state with its counts of dropped requests.
    """
    rules = RequestAcceptance(timeout_s)
    out_t: list[float] = []
    out_v: list[float] = []
    for index, (now, value) in enumerate(zip(times.tolist(), values.tolist(), strict=True)):
        last = rules.last_valid_s
        if rules.accept(now, value, **_signals(extra, index)):
            if last is not None and now - last > timeout_s:
                out_t.append(last + timeout_s)
                out_v.append(0.0)
            out_t.append(now)
            out_v.append(rules.test_torque(now))
    if rules.last_valid_s is not None:
        out_t.append(rules.last_valid_s + timeout_s)
        out_v.append(0.0)
    return np.asarray(out_t), np.asarray(out_v), rules
