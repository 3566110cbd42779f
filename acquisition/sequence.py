"""The test sequence on the bus: phases, the tool's frames, and the thread that sends them.

The plan (:meth:`dtid.acquisition.plan.TestPlan`) runs in test time ``tau`` (s since the
test started, bus time): settle at idle, chirp A1, pause, chirp A2, pause, validation chirp, pause.
The
tool sends exactly the frames a simulated test has (:mod:`dtid.simulator.vehicle_frames`):

* the test torque request at ``tau_k = k * request_period_s`` for every ``tau_k < plan.end_s``,
  the chirp value held at ``tau_k`` (:func:`dtid.acquisition.plan.tool_requests`), ``TestEnable``
  1 while a chirp runs, the alive counter +1 per frame modulo its width in the DBC, the checksum
  filled in by :meth:`dbc.VehicleInterface.encode`;
* the heartbeat every :data:`dtid.dbc.tool_state.HEARTBEAT_PERIOD_S` with the tool state (settling,
  chirp, done after the last chirp).

:class:`RequestSender` sends them from its own thread against deadlines ``t_start + tau_k``
(converted to wall time by the bus clock), so the rate does not drift and the receive loop never
waits on it; each frame carries the bus time at which it is sent. A frame late by less than
:data:`MAX_CATCH_UP` periods is still sent (the sequence stays the simulated one); beyond that the
sender skips to the current slot and logs it. On abort it sends a zero request (``TestEnable`` 0,
value 0) :data:`ZERO_REQUESTS` times at the request period, after one heartbeat in state abort.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass

import can
import numpy as np

from dtid.acquisition.clock import BusClock
from dtid.acquisition.health import EchoFilter, counter_moduli
from dtid.acquisition.plan import TestPlan, tool_requests
from dtid.dbc.interface import VehicleInterface
from dtid.dbc.tool_state import HEARTBEAT_PERIOD_S, TOOL_ABORT, TOOL_CHIRP, TOOL_DONE, TOOL_SETTLING

logger = logging.getLogger(__name__)

ZERO_REQUESTS = 5
"""Zero requests sent on abort (one request period apart)."""
MAX_CATCH_UP = 10
"""Request periods a late sender still catches up on, frame by frame."""
SEND_TIMEOUT_S = 0.1
"""Longest wall time one send may block (a full transmit queue), s."""


@dataclass(frozen=True)
class Phase:
    """A phase of the test.

    Attributes
    ----------
    name
        ``settle``, ``chirp``, ``pause`` or ``done``.
    start_s
        Test time at which it begins, s.
    chirp
        Index of the chirp in the plan (for ``chirp``), else None.
    amplitude_nm
        The chirp's amplitude, N*m (for ``chirp``), else None.
    """

    name: str
    start_s: float
    chirp: int | None = None
    amplitude_nm: float | None = None


def phases(plan: TestPlan) -> list[Phase]:
    """The phases of a plan in order, ending with ``done`` at ``plan.end_s``."""
    result = [Phase("settle", 0.0)] if plan.settle_s > 0 else []
    for index, chirp in enumerate(plan.chirps):
        result.append(Phase("chirp", chirp.start_s, index, chirp.amplitude_nm))
        if plan.pause_s > 0:
            result.append(Phase("pause", chirp.end_s))
    result.append(Phase("done", plan.end_s))
    return result


class ToolFrames:
    """The tool's frames of a test plan, slot by slot.

    Parameters
    ----------
    interface
        DBC and signal map; needs the ``test_torque`` role, sends the heartbeat when mapped.
    plan
        The test plan.

    Attributes
    ----------
    request_times, request_values, request_enable : numpy.ndarray
        Test time (s), value (N*m) and ``TestEnable`` of each request slot.
    heartbeat_times, heartbeat_states : numpy.ndarray
        Test time (s) and tool state of each heartbeat slot (empty without a heartbeat role).

    Raises
    ------
    ConfigError
        If the signal map has no ``test_torque`` role, or the plan's largest request does not fit
        the DBC's test torque signal.
    """

    def __init__(self, interface: VehicleInterface, plan: TestPlan) -> None:
        interface.signal_map.require("test_torque")
        self.interface = interface
        self.plan = plan
        self.request_times, self.request_values = tool_requests(plan)
        self.request_enable = np.array(
            [any(c.start_s <= t < c.end_s for c in plan.chirps) for t in self.request_times],
            dtype=np.int64,
        )
        present = interface.present_roles()
        times = np.arange(0.0, plan.end_s, HEARTBEAT_PERIOD_S) if "heartbeat" in present else []
        self.heartbeat_times = np.asarray(times, dtype=np.float64)
        self.heartbeat_states = np.array([self.state_at(t) for t in times], dtype=np.int64)
        moduli = counter_moduli(interface, ("test_torque", "heartbeat"))
        self._modulo = {role: moduli.get(role, 1) for role in ("test_torque", "heartbeat")}
        self._keys = {
            role: {
                key: key for key in ("counter", "enable") if getattr(spec, key, None) is not None
            }
            for role, spec in interface.signal_map.roles.items()
        }
        largest = float(np.max(np.abs(self.request_values), initial=0.0))
        for value in (largest, -largest):  # a value the DBC cannot carry fails here, not mid-test
            self._request(value, 1, 0, 0.0)

    def state_at(self, tau: float) -> int:
        """Tool state at test time ``tau`` (s): chirp, done after the last chirp, else settling."""
        chirps = self.plan.chirps
        if any(c.start_s <= tau < c.end_s for c in chirps):
            return TOOL_CHIRP
        return TOOL_DONE if tau >= chirps[-1].end_s else TOOL_SETTLING

    def request(self, slot: int, index: int, timestamp: float) -> can.Message:
        """The request of ``slot`` as the ``index``-th request frame sent, at ``timestamp`` (s)."""
        value = float(self.request_values[slot])
        return self._request(value, int(self.request_enable[slot]), index, timestamp)

    def zero_request(self, index: int, timestamp: float) -> can.Message:
        """A zero request (``TestEnable`` 0) as the ``index``-th request frame sent."""
        return self._request(0.0, 0, index, timestamp)

    def heartbeat(self, state: int, index: int, timestamp: float) -> can.Message:
        """The ``index``-th heartbeat frame with a tool state, at ``timestamp`` (s)."""
        extras = self._extras("heartbeat", counter=index % self._modulo["heartbeat"])
        return self._sent(self.interface.encode("heartbeat", state, timestamp, **extras))

    def _request(self, value: float, enable: int, index: int, timestamp: float) -> can.Message:
        extras = self._extras(
            "test_torque", counter=index % self._modulo["test_torque"], enable=enable
        )
        return self._sent(self.interface.encode("test_torque", value, timestamp, **extras))

    def _extras(self, role: str, **values: int) -> dict[str, int]:
        keys = self._keys[role]
        return {key: value for key, value in values.items() if key in keys}

    @staticmethod
    def _sent(frame: can.Message) -> can.Message:
        frame.is_rx = False
        return frame


class RequestSender:
    """Send the tool's frames of a test from a thread, deadline by deadline.

    Every frame is announced to the echo filter before it is sent and appended to ``sent``
    afterwards (the receive loop records and decodes it from there).

    Parameters
    ----------
    bus
        The open bus.
    frames
        The tool's frames of the plan.
    clock
        The bus clock.
    echo
        The echo filter of the session.
    sent
        Queue of sent frames, read by the receive loop.

    Attributes
    ----------
    failure : BaseException or None
        What stopped the thread, if it failed (e.g. the bus refused a frame).
    skipped : int
        Request slots skipped because the sender was too late for them.
    """

    def __init__(
        self,
        bus: can.BusABC,
        frames: ToolFrames,
        clock: BusClock,
        echo: EchoFilter,
        sent: deque[can.Message],
    ) -> None:
        self._bus = bus
        self._frames = frames
        self._clock = clock
        self._echo = echo
        self._sent = sent
        self._abort = threading.Event()
        self._thread = threading.Thread(target=self._run, name="dtid-sender", daemon=True)
        self._lock = threading.Lock()
        self._requests_sent = 0
        self._heartbeats_sent = 0
        self._zeros_sent = False
        self.t_start: float | None = None
        self.failure: BaseException | None = None
        self.skipped = 0

    def start(self, t_start: float) -> None:
        """Start the test at bus time ``t_start`` (s)."""
        self.t_start = t_start
        self._thread.start()

    def abort(self) -> None:
        """Stop the sequence; the thread sends the zero requests and ends."""
        self._abort.set()

    def running(self) -> bool:
        """True while the thread runs."""
        return self._thread.is_alive()

    def join(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s (wall) for the thread; True when it has ended."""
        if self._thread.ident is not None:
            self._thread.join(timeout)
        return not self._thread.is_alive()

    def send_zero_requests(self) -> None:
        """Send the abort heartbeat and the zero requests now, unless they were sent already.

        The thread does this itself on abort; the receive loop calls it when the thread cannot
        (it failed, or never started).
        """
        with self._lock:
            if self._zeros_sent:
                return
            self._zeros_sent = True
        frames = self._frames
        if len(frames.heartbeat_times):
            self._send(frames.heartbeat(TOOL_ABORT, self._heartbeats_sent, self._clock.now()))
            self._heartbeats_sent += 1
        period_wall = frames.plan.request_period_s / self._clock.time_factor
        deadline = time.time()
        refused: list[str] = []
        for _ in range(ZERO_REQUESTS):
            time.sleep(max(0.0, deadline - time.time()))
            try:  # each one, whatever the bus did to the one before (a full buffer may clear)
                self._send(frames.zero_request(self._requests_sent, self._clock.now()))
            except can.CanError as error:
                refused.append(str(error))
            self._requests_sent += 1
            deadline += period_wall
        if refused:
            logger.error(
                "the bus refused %d of %d zero requests (%s); the vehicle's request timeout "
                "zeroes the test torque",
                len(refused),
                ZERO_REQUESTS,
                refused[-1],
            )

    def _send(self, frame: can.Message) -> None:
        self._echo.expect(frame)
        self._bus.send(frame, timeout=SEND_TIMEOUT_S)
        self._sent.append(frame)

    def _run(self) -> None:
        try:
            self._sequence()
            if self._abort.is_set():
                self.send_zero_requests()
        except Exception as error:  # reported to the receive loop, which aborts the test
            self.failure = error
            logger.error("sender failed: %s", error)

    def _sequence(self) -> None:
        frames, clock = self._frames, self._clock
        assert self.t_start is not None
        start = self.t_start
        requests, heartbeats = frames.request_times, frames.heartbeat_times
        period = frames.plan.request_period_s
        k = j = 0
        while not self._abort.is_set():
            t_request = start + requests[k] if k < len(requests) else math.inf
            t_beat = start + heartbeats[j] if j < len(heartbeats) else math.inf
            due = min(t_request, t_beat)
            if due == math.inf:
                return
            wait = clock.to_wall(due) - time.time()
            if wait > 0 and self._abort.wait(wait):
                return
            if t_request <= t_beat:
                late = int((clock.now() - t_request) / period)
                if late > MAX_CATCH_UP:
                    k = min(k + late, len(requests) - 1)
                    self.skipped += late
                    logger.warning("sender %d request periods late; skipped to the current", late)
                self._send(frames.request(k, self._requests_sent, clock.now()))
                self._requests_sent += 1
                k += 1
            else:
                state = int(frames.heartbeat_states[j])
                self._send(frames.heartbeat(state, self._heartbeats_sent, clock.now()))
                self._heartbeats_sent += 1
                j += 1
