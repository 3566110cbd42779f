"""The acquisition daemon (``dtid acquire``): run one chirp test on the bus, record and stream it.

The receive loop takes frames from the bus (``recv`` with a timeout of ``block_period_s``), runs
each through :class:`dtid.acquisition.framepath.FramePath` (bus time, echo filter, raw log), and
publishes the pending block as a ``samples`` event when ``block_period_s`` has passed since its
first frame or when no frame is waiting: one event per frame when the bus is quiet, batches under
load. The daemon's own frames, sent by :class:`dtid.acquisition.sequence.RequestSender` from its
thread, join the same path. Between blocks the loop flushes the log, emits ``phase`` events at the
plan's phase boundaries (bus time) and checks the safety envelope.

The test starts when the first engine speed frame is decoded (the daemon waits up to
``wait_s`` wall seconds for the vehicle) and ends

* completed, at the end of the plan: exit status :data:`EXIT_COMPLETED`;
* aborted (:data:`dtid.acquisition.stream.ABORT_REASONS`): speed window, vehicle timeout, a foreign
  frame on the tool's IDs, SIGINT/SIGTERM, or any failure (bus error, exception): exit status
  :data:`EXIT_ABORTED`. An abort sends the abort heartbeat and
  :data:`dtid.acquisition.sequence.ZERO_REQUESTS` zero requests (``TestEnable`` 0) before the daemon
  stops; this runs in ``finally`` blocks, so no exit of the daemon's loop skips it (only
  ``kill -9`` does; then the vehicle's own request timeout applies).

After the ``end`` event the log is closed, the session's health counts are reported as one line
(``health: {json}``, the keys of :class:`dtid.acquisition.health.HealthCounts`), and the replay
socket stays up for ``linger_s`` (wall) so a restarting worker can still catch up; a further
signal cuts the linger short.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import can

from dtid.acquisition.bus import open_bus
from dtid.acquisition.clock import BusClock
from dtid.acquisition.config import AcquisitionConfig
from dtid.acquisition.framepath import FramePath
from dtid.acquisition.health import EchoFilter
from dtid.acquisition.metadata import session_metadata
from dtid.acquisition.recorder import Recorder, new_session_directory
from dtid.acquisition.safety import SafetyMonitor
from dtid.acquisition.sequence import ZERO_REQUESTS, Phase, RequestSender, ToolFrames, phases
from dtid.acquisition.server import EventServer
from dtid.acquisition.stream import ABORT_REASONS
from dtid.dbc.loader import load_interface
from dtid.dbc.roles import CRANK_RATE_TOLERANCE, SPEED_SAMPLES_PER_REVOLUTION
from dtid.errors import ConfigError

logger = logging.getLogger(__name__)

EXIT_COMPLETED = 0
"""Exit status of a completed test."""
EXIT_ABORTED = 3
"""Exit status of an aborted test."""
DEFAULT_LINGER_S = 5.0
"""Default wall time the replay stays up after the end event, s."""
DEFAULT_WAIT_S = 10.0
"""Default wall time to wait for the vehicle's first speed frame, s."""
_FINISH_GRACE_S = 1.0
"""Wall time allowed beyond the zero requests for the sender to finish, s."""
SWITCH_INTERVAL_S = 0.0005
"""Python's thread switch interval while the test runs, s (default 5 ms): the longest time the
sender thread may wait for the interpreter while the receive loop decodes a block."""


@dataclass(frozen=True)
class DaemonResult:
    """How a test ended.

    Attributes
    ----------
    status
        ``completed`` or ``aborted``.
    reason
        Key of :data:`dtid.acquisition.stream.ABORT_REASONS` for an abort, else None.
    session_dir
        The session's directory.
    log_path
        The raw log.
    events
        Number of events published.
    """

    status: str
    reason: str | None
    session_dir: Path
    log_path: Path
    events: int

    @property
    def exit_status(self) -> int:
        """:data:`EXIT_COMPLETED` or :data:`EXIT_ABORTED`."""
        return EXIT_COMPLETED if self.status == "completed" else EXIT_ABORTED


class Daemon:
    """One test session on the bus.

    Parameters
    ----------
    config
        The configuration.
    linger_s
        Wall time the replay stays up after the end event, s.
    wait_s
        Wall time to wait for the vehicle's first speed frame before aborting, s.
    report
        Called with one line of text per step worth telling an operator (log path, phases, end).
    campaign
        The round of an adaptive campaign this test is (:mod:`dtid.acquisition.campaign`), told
        to the worker in the ``session`` event; None for a test of its own.
    """

    def __init__(
        self,
        config: AcquisitionConfig,
        linger_s: float = DEFAULT_LINGER_S,
        wait_s: float = DEFAULT_WAIT_S,
        report: Callable[[str], None] = lambda line: None,
        campaign: Mapping[str, Any] | None = None,
    ) -> None:
        self.config = config
        self.linger_s = linger_s
        self.wait_s = wait_s
        self.report = report
        self.campaign = campaign
        self._signals = 0
        self._status: str | None = None
        self._reason: str | None = None
        self._t_end: float | None = None
        self._t_start: float | None = None
        self._sampling_checked = False

    def run(self) -> DaemonResult:
        """Run the test and return how it ended.

        Raises
        ------
        ConfigError, DbcError, RecordingError
            If the interface (it needs the ``speed`` and ``test_torque`` roles), plan, bus, output
            or endpoints are unusable (before the test runs).
        """
        config = self.config
        interface = load_interface(config.vehicle_interface.dbc, config.vehicle_interface.signals)
        interface.signal_map.require("speed", "test_torque")
        plan = config.test
        self._tool = ToolFrames(interface, plan)
        self._phases = phases(plan)
        self._clock = clock = BusClock(config.bus.time_factor)
        bus = open_bus(config.bus)
        with contextlib.ExitStack() as cleanup:
            cleanup.callback(bus.shutdown)
            self._bus = bus
            session_dir = new_session_directory(Path(config.output.directory))
            try:
                server = EventServer(config.pipeline, session_dir.name)
            except ConfigError:
                session_dir.rmdir()  # still empty: no session took place
                raise
            cleanup.callback(server.close)
            log_path = session_dir / f"{session_dir.name}.{config.output.log_format}"
            metadata = session_metadata(
                session=session_dir.name,
                started_s=clock.start_wall_s,
                source="dtid acquire",
                vehicle=config.output.vehicle,
                interface=interface,
                plan=plan.as_dict(),
                bus={
                    "interface": config.bus.interface,
                    "channel": config.bus.channel,
                    "time_factor": config.bus.time_factor,
                },
            )
            recorder = Recorder(
                log_path,
                clock.start_wall_s,
                config.output.flush_period_s,
                config.bus.channel,
                metadata,
            )
            cleanup.callback(recorder.close)
            self._recorder = recorder
            keys = [interface.frame_key("test_torque")]
            if "heartbeat" in interface.present_roles():
                keys.append(interface.frame_key("heartbeat"))
            echo = EchoFilter(keys)
            self._sent: deque[can.Message] = deque()
            self._sender = RequestSender(bus, self._tool, clock, echo, self._sent)
            self._path = FramePath(interface, clock, recorder, server, echo, self._session_fields())
            self.report(f"log: {log_path}")
            self.report(
                f"bus: {config.bus.interface} {config.bus.channel}; events: "
                f"{config.pipeline.blocks} (replay {config.pipeline.replay})"
            )
            with self._signal_handlers(), _soft_real_time():
                try:
                    self._loop()
                except KeyboardInterrupt:
                    self._abort("signal")
                except can.CanError as error:
                    self._bus_failed("receiving", error)
                except Exception:
                    logger.exception("the acquisition failed; aborting the test")
                    self._abort("error")
                finally:
                    self._finish()
                self._linger()
            return DaemonResult(
                self._status or "aborted", self._reason, session_dir, log_path, server.count
            )

    def _session_fields(self) -> dict[str, Any]:
        config = self.config
        plan = config.test.as_dict()
        paths = asdict(config.vehicle_interface)
        fields = {
            "plan": plan,
            "interface": {key: None if p is None else str(p) for key, p in paths.items()},
            "time_factor": config.bus.time_factor,
        }
        if self.campaign is not None:
            fields["campaign"] = dict(self.campaign)
        return fields

    def _signal_handlers(self) -> contextlib.AbstractContextManager[None]:
        """SIGINT and SIGTERM abort the test (main thread only; elsewhere nothing changes)."""

        def handler(signum: int, frame: object) -> None:
            self._signals += 1

        return on_stop_signals(handler)

    def _pump(self) -> bool:
        """Take what the bus has within one block period and publish it; True when the bus had
        nothing more waiting at the end (every frame up to now is taken)."""
        bus, path = self._bus, self._path
        period = self.config.pipeline.block_period_s
        frame = bus.recv(period)
        self._take_sent()
        drained = frame is None
        if frame is not None:
            take = path.take
            take(frame)
            first = time.monotonic()
            while time.monotonic() - first < period:
                frame = bus.recv(0)
                if frame is None:
                    drained = True
                    break
                take(frame)
            self._take_sent()
        if path.pending:
            path.publish_block()
        self._recorder.flush_if_due()
        return drained

    def _take_sent(self) -> None:
        sent, take = self._sent, self._path.take_sent
        while sent:
            take(sent.popleft())

    def _loop(self) -> None:
        wait_until = time.monotonic() + self.wait_s
        self.report(f"waiting up to {self.wait_s:g} s for the vehicle's engine speed")
        next_phase = 0
        while True:
            drained = self._pump()
            if self._signals:
                self._abort("signal")
            elif self._path.alarm is not None:
                self._abort(self._path.alarm)
            elif self._sender.failure is not None:
                failure = self._sender.failure
                if isinstance(failure, can.CanError):
                    self._bus_failed("sending", failure)
                else:
                    self._abort("error")
            elif self._recorder.failure is not None:
                self._abort("log_write")
            if self._status is not None:
                return
            if self._t_start is None:
                if self._path.speed_seen:
                    self._start()
                elif time.monotonic() > wait_until:
                    self._abort("vehicle_timeout")
                continue
            now = self._clock.now()
            tau = now - self._t_start
            while next_phase < len(self._phases) and self._phases[next_phase].start_s <= tau:
                self._publish_phase(self._phases[next_phase])
                next_phase += 1
            if self._status is not None:
                return
            assert self._path.safety is not None
            if not self._sampling_checked:
                self._check_speed_sampling(self._path.safety)
            timeout = self._path.safety.check_timeout(now) if drained else None
            if timeout is not None:
                self._abort(timeout)
                return

    def _check_speed_sampling(self, safety: SafetyMonitor) -> None:
        """Once the settle phase has ended: warn when the speed did not come once per crank
        event. Such a recording will not identify (`dtid identify` refuses it), and the
        operator can stop the test now instead of after minutes; it is not aborted, since a
        signal map mapping the right message can still read the recorded frames."""
        per_revolution = safety.settle_samples_per_revolution
        if per_revolution is None:
            return
        self._sampling_checked = True
        expected = SPEED_SAMPLES_PER_REVOLUTION
        if abs(per_revolution / expected - 1.0) <= CRANK_RATE_TOLERANCE:
            return
        message = (
            f"the engine speed came {per_revolution:.1f} times a crank revolution over the "
            f"settle phase where the ECU's crank-synchronous speed comes {expected}: this "
            "recording will not identify. Check [bus] time_factor "
            f"({self.config.bus.time_factor:g}) against the vehicle's (a virtual vehicle's "
            "--speedup), the speed's unit and scale in the signal map, and that the map names "
            "the speed the ECU sends once per crank event, not one sent on a timer"
        )
        logger.warning("%s", message)
        self.report(f"warning: {message}")

    def _start(self) -> None:
        self._t_start = t_start = self._clock.now()
        plan = self._tool.plan
        self._path.safety = SafetyMonitor(self.config.safety, t_start, plan.settle_s)
        self._sender.start(t_start)
        self.report(
            f"test started: {len(plan.chirps)} chirps of {plan.duration_s:g} s, "
            f"{plan.end_s:g} s in all (bus time)"
        )

    def _publish_phase(self, phase: Phase) -> None:
        assert self._t_start is not None
        t_s = self._t_start + phase.start_s
        self._path.publish(
            "phase",
            {
                "phase": phase.name,
                "t_s": t_s,
                "chirp": phase.chirp,
                "amplitude_nm": phase.amplitude_nm,
            },
        )
        text = f"{phase.start_s:8.2f} s  {phase.name}"
        if phase.chirp is not None:
            text += (
                f" {phase.chirp + 1} of {len(self._tool.plan.chirps)}: {phase.amplitude_nm:g} N*m"
            )
        counts = self._path.health.counts
        text += f"  (frames {self._recorder.frames}"
        for name, value in asdict(counts).items():
            if name != "frames" and value:
                text += f", {name} {value}"
        self.report(text + ")")
        if phase.name == "done":
            self._status, self._t_end = "completed", t_s

    def _bus_failed(self, doing: str, error: can.CanError) -> None:
        """Abort on an error the bus reported, saying what it reported."""
        self.report(f"bus: error while {doing}: {error}")
        self._abort("bus_error")

    def _abort(self, reason: str) -> None:
        """Abort the test (first reason wins): stop the sequence, the zero requests go out."""
        if self._status is not None:
            return
        self._status, self._reason, self._t_end = "aborted", reason, self._clock.now()
        logger.warning("aborting the test: %s", ABORT_REASONS[reason])
        self._sender.abort()

    def _finish(self) -> None:
        """Make sure the test is ended and the zero requests are out; take the frames still
        waiting on the bus; publish the end."""
        if self._status is None:
            self._abort("error")
        sender = self._sender
        grace = (
            ZERO_REQUESTS * self._tool.plan.request_period_s / self._clock.time_factor
            + _FINISH_GRACE_S
        )
        deadline = time.monotonic() + grace
        drained = False
        while (sender.running() or not drained) and time.monotonic() < deadline:
            try:
                drained = self._pump()
            except Exception:  # the bus may be what failed: wait for the zero requests alone
                drained = True
                sender.join(max(0.0, deadline - time.monotonic()))
        if self._status == "aborted" and not sender.running():
            try:
                sender.send_zero_requests()  # when the thread never started or failed
            except Exception:
                logger.exception("cannot send the zero requests")
        if sender.running():
            logger.error("the sender did not stop within %.1f s", grace)
        self._take_sent()
        path = self._path
        if path.pending:
            path.publish_block(final=True)
        path.publish_health()
        path.publish("end", {"status": self._status, "reason": self._reason, "t_s": self._t_end})
        self._recorder.outcome = {
            "status": self._status,
            "reason": self._reason,
            "health": asdict(path.health.counts),
        }
        self._recorder.close()
        if self._recorder.failure is not None:
            self.report(
                f"log: {self._recorder.failure}; {self._recorder.frames} frames kept, "
                f"{self._recorder.lost} not written"
            )
        self.report("health: " + json.dumps(asdict(path.health.counts)))
        if self._status == "completed":
            self.report("end: completed")
        else:
            self.report(f"end: aborted ({self._reason}: {ABORT_REASONS[self._reason]})")

    def _linger(self) -> None:
        signals = self._signals
        until = time.monotonic() + self.linger_s
        while time.monotonic() < until and self._signals == signals:
            time.sleep(min(0.05, max(0.0, until - time.monotonic())))


@contextlib.contextmanager
def on_stop_signals(handler: Callable[[int, object], None]) -> Iterator[None]:
    """``handler`` takes SIGINT and SIGTERM meanwhile, the previous handlers come back after
    (main thread only: elsewhere nothing changes, as Python allows handlers there only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


@contextlib.contextmanager
def _soft_real_time() -> Iterator[None]:
    """The thread switch interval at :data:`SWITCH_INTERVAL_S`, and every object alive at the
    start frozen out of the garbage collector, so that no collection walks them in mid-test."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
        sys.setswitchinterval(interval)
