"""The simulator as the vehicle's engine ECU on a CAN bus (``dtid vehicle``).

The virtual vehicle runs the numba plant (:class:`dtid.simulator.plant_stepper.PlantStepper`) paced
to wall time, optionally faster by a factor (``speedup``): bus time = wall time since its start
times the speedup. Each tick it takes the test-torque requests that arrived (accepted or dropped as
the ECU does, :class:`dtid.dbc.ecu_requests.RequestReceiver`), advances the plant to the
current bus time with the test torque it holds, and sends the speed, torque-request and mean-torque
frames of that segment through the DBC (:class:`dtid.simulator.vehicle_frames.EcuFrames`).

For fault tests it can drop, duplicate or corrupt its own frames on the way to the bus
(:class:`BusFaults`) and step the idle set-point at a given bus time (a disturbance that drives
the speed out of the daemon's window). A stalled engine (speed outside 0.5..3 times the
set-point) stops sending, as a real one would.
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from threading import Event

import can
import numpy as np

from dtid.acquisition.clock import MAX_TIME_FACTOR
from dtid.dbc.ecu_requests import RequestReceiver
from dtid.dbc.interface import VehicleInterface
from dtid.errors import ConfigError
from dtid.simulator.plant_stepper import PlantStepper
from dtid.simulator.vehicle_frames import EcuFrames

TICK_S = 0.001
"""Longest wall time between two plant segments, s."""
MAX_SEGMENT_S = 0.005
"""Longest bus time of one plant segment (the tool's request period), s."""


@dataclass(frozen=True)
class BusFaults:
    """Faults the vehicle puts on its own frames, each an independent probability per frame.

    Attributes
    ----------
    drop
        The frame is not sent.
    duplicate
        The frame is sent twice.
    corrupt
        The frame is sent with its last payload byte cut off (a length the DBC rejects; on a real
        bus the CAN CRC would discard such a frame, so the receiver sees it as bad or lost).
    seed
        Seed of the draws.
    """

    drop: float = 0.0
    duplicate: float = 0.0
    corrupt: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "corrupt"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ConfigError(f"fault probability {name} must be within 0..1, got {value}")

    @property
    def any(self) -> bool:
        """True when any fault is switched on."""
        return self.drop > 0 or self.duplicate > 0 or self.corrupt > 0


@dataclass(frozen=True)
class SetpointStep:
    """Move the idle set-point to ``setpoint_rpm`` at bus time ``at_s`` (s)."""

    at_s: float
    setpoint_rpm: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.at_s) and self.at_s >= 0):
            raise ConfigError(f"set-point step: the time must be >= 0 s, got {self.at_s}")
        if not (math.isfinite(self.setpoint_rpm) and self.setpoint_rpm > 0):
            raise ConfigError(
                f"set-point step: the new set-point must be > 0 rpm, got {self.setpoint_rpm}"
            )


@dataclass
class VehicleReport:
    """What the virtual vehicle did, for the operator and the fault tests.

    Attributes
    ----------
    bus_time_s
        Bus time simulated, s.
    frames_sent
        Frames put on the bus (after faults).
    faults
        Frames dropped, duplicated and corrupted on purpose.
    requests_accepted, requests_dropped
        Test-torque request frames the ECU accepted, and dropped by reason.
    last_request_s
        Bus time of the last accepted request that asked for a non-zero test torque, s (None:
        none).
    zero_after_s
        Bus time at which the applied test torque went to zero after it, s (None: it did not).
    zero_cause
        ``request`` (the tool asked for zero or disabled the test) or ``timeout``.
    stalled_at_s
        Bus time at which the engine stalled or ran away (None: it did not).
    late_max_s, late_at_s
        Largest delay of a frame behind its bus time, in bus time (the host could not keep
        the pace: such frames arrive in a burst), s; and the bus time of that frame, s.
    """

    bus_time_s: float = 0.0
    frames_sent: int = 0
    faults: Counter[str] = field(default_factory=Counter)
    requests_accepted: int = 0
    requests_dropped: dict[str, int] = field(default_factory=dict)
    last_request_s: float | None = None
    zero_after_s: float | None = None
    zero_cause: str | None = None
    stalled_at_s: float | None = None
    late_max_s: float = 0.0
    late_at_s: float | None = None

    def as_dict(self) -> dict[str, object]:
        """The report as a JSON-ready dictionary."""
        return {
            "bus_time_s": self.bus_time_s,
            "frames_sent": self.frames_sent,
            "faults": dict(self.faults),
            "requests_accepted": self.requests_accepted,
            "requests_dropped": dict(self.requests_dropped),
            "last_request_s": self.last_request_s,
            "zero_after_s": self.zero_after_s,
            "zero_cause": self.zero_cause,
            "stalled_at_s": self.stalled_at_s,
            "late_max_s": self.late_max_s,
            "late_at_s": self.late_at_s,
        }


class VirtualVehicle:
    """The plant as an engine ECU on a python-can bus.

    Parameters
    ----------
    bus
        The bus (any python-can interface).
    interface
        DBC and signal map of the frames.
    plant
        The drivetrain to run.
    speedup
        Bus time per wall time (1: real time).
    faults
        Faults on the vehicle's own frames.
    setpoint_step
        Optional set-point disturbance.
    """

    def __init__(
        self,
        bus: can.BusABC,
        interface: VehicleInterface,
        plant: PlantStepper,
        speedup: float = 1.0,
        faults: BusFaults | None = None,
        setpoint_step: SetpointStep | None = None,
    ) -> None:
        if not (math.isfinite(speedup) and 0 < speedup <= MAX_TIME_FACTOR):
            raise ConfigError(
                f"speedup must lie in (0, {MAX_TIME_FACTOR:g}], got {speedup:g}: beyond, the "
                "plant and the bus cannot keep pace"
            )
        self.bus = bus
        self.plant = plant
        self.speedup = speedup
        self.faults = faults or BusFaults()
        self.setpoint_step = setpoint_step
        self.receiver = RequestReceiver(interface)
        self.ecu = EcuFrames(interface)
        self.report = VehicleReport()
        self._rng = np.random.default_rng(self.faults.seed)
        self._applied = 0.0
        self._start_wall = 0.0
        self._start_epoch = 0.0

    def run(self, duration_s: float | None = None, stop: Event | None = None) -> VehicleReport:
        """Run until ``duration_s`` of bus time has passed or ``stop`` is set.

        The plant runs one tick ahead of bus time; each frame is sent when its own time comes,
        so its receive time stamps it to within the scheduler's jitter.

        Returns
        -------
        VehicleReport
        """
        stop = stop or Event()
        self._start_wall = time.monotonic()
        self._start_epoch = time.time()
        end = math.inf if duration_s is None else duration_s
        pending: deque[can.Message] = deque()  # stamped with bus time until sent
        step_pending = self.setpoint_step
        while not stop.is_set():
            now = (time.monotonic() - self._start_wall) * self.speedup
            if now >= end and not pending:
                break
            horizon = min(now + TICK_S * self.speedup, end)
            if step_pending is not None and horizon >= step_pending.at_s:
                self.plant.set_setpoint(step_pending.setpoint_rpm)
                step_pending = None
            pending.extend(self._advance_to(horizon))
            wake = time.monotonic() + TICK_S
            if pending:
                wake = min(wake, self._due(pending[0]))
            self._receive_until(wake)
            while pending and (due := self._due(pending[0])) <= (sent := time.monotonic()):
                self._note_lateness(pending[0].timestamp, (sent - due) * self.speedup)
                self._send(pending.popleft())
        self.report.bus_time_s = self.plant.time_s
        self.report.requests_accepted = self.receiver.accepted
        self.report.requests_dropped = dict(self.receiver.dropped)
        return self.report

    def _note_lateness(self, bus_time_s: float, late_s: float) -> None:
        """Keep the largest delay of a frame behind its bus time (both bus time, s)."""
        if late_s > self.report.late_max_s:
            self.report.late_max_s = late_s
            self.report.late_at_s = bus_time_s

    def _due(self, frame: can.Message) -> float:
        """Monotonic wall time at which a frame stamped with bus time is due."""
        return self._start_wall + frame.timestamp / self.speedup

    def _receive_until(self, deadline_wall: float) -> None:
        """Take the frames arriving before ``deadline_wall`` (monotonic time)."""
        while (remaining := deadline_wall - time.monotonic()) > 0:
            frame = self.bus.recv(timeout=remaining)
            if frame is None:
                return
            if self.receiver.is_request(frame):
                arrival = (time.monotonic() - self._start_wall) * self.speedup
                self.receiver.receive(frame, max(arrival, self.plant.time_s))

    def _advance_to(self, horizon: float) -> list[can.Message]:
        """Advance the plant to bus time ``horizon`` in segments; return their frames."""
        frames: list[can.Message] = []
        while self.plant.time_s < horizon and not self.plant.stalled:
            t_end = min(horizon, self.plant.time_s + MAX_SEGMENT_S)
            self._track_applied(self.plant.time_s)
            speed, torque = self.plant.advance(t_end, self._applied)
            segment = self.ecu.speed_frames(speed[:, :3]) + self.ecu.stroke_frames(torque)
            segment.sort(key=lambda frame: frame.timestamp)
            frames += segment
            if self.plant.stalled and self.report.stalled_at_s is None:
                self.report.stalled_at_s = self.plant.time_s
        return frames

    def _track_applied(self, now: float) -> None:
        """Update the applied test torque and note when it goes to zero, and why."""
        applied = self.receiver.test_torque(now)
        if applied != 0.0:
            self.report.last_request_s = self.receiver.last_valid_s
            self.report.zero_after_s = None
            self.report.zero_cause = None
        elif self._applied != 0.0:
            self.report.zero_after_s = now
            self.report.zero_cause = "timeout" if self.receiver.timed_out(now) else "request"
        self._applied = applied

    def _send(self, frame: can.Message) -> None:
        """Send a frame (its bus time restamped as wall time), with the configured faults."""
        frame.timestamp = self._start_epoch + frame.timestamp / self.speedup
        copies = 1
        if self.faults.any:
            draw = self._rng.random(3)
            if draw[0] < self.faults.drop:
                self.report.faults["dropped"] += 1
                return
            if draw[1] < self.faults.duplicate:
                self.report.faults["duplicated"] += 1
                copies = 2
            if draw[2] < self.faults.corrupt:
                self.report.faults["corrupted"] += 1
                frame = can.Message(
                    timestamp=frame.timestamp,
                    arbitration_id=frame.arbitration_id,
                    is_extended_id=frame.is_extended_id,
                    data=frame.data[:-1],
                )
        for _ in range(copies):
            self.bus.send(frame)
            self.report.frames_sent += 1
