"""The identification worker (``dtid worker``): the daemon's event stream in, FRFs and results out.

The worker connects to the daemon's PUB (``[pipeline] blocks``) first, then asks its REP
(``[pipeline] replay``) for the kept events from the first it lacks, and merges both by ``seq``
(:class:`dtid.identification.service.live.EventLog`): duplicates are dropped, a gap or a quiet
stream sends a new request, and a new session id starts a new session. So a worker started late or
restarted mid-test computes what one that saw the whole test live computes.

It binds its own PUB (``[pipeline] results``) and publishes, as two frames ``[topic, JSON]``:

``progress``
    ``session``, ``stage`` (``acquiring``, ``identifying``, ``identified``, ``validated``,
    ``done``, ``aborted``, ``error``), ``phase`` (the daemon's), ``data_s`` (seconds of data
    received), ``chirps`` (the completed chirps' amplitudes), and per stage ``search`` (the
    identification's stage, step, steps and best objective), ``parameters``, ``seconds_after_chirp``
    (wall time from the end of the last identification chirp to the identified parameters),
    ``message``; in a campaign's round, after each identifying run, ``precision`` (% at 2 sigma
    per parameter: the runs so far, predicted with the last round's planning information, in
    round 1 with the information at the prior) and ``precision_runs`` (how many runs it counts).
``frf``
    One entry per chirp when its phase ends and its data have arrived, with the schema of a
    ``dtid frf`` run entry (``recording``, ``amplitude_nm``, ``frequency_hz``, ``drv_db``,
    ``eng_db``, ``coherence``, ...).
``result``
    The JSON document of ``dtid identify --json``, once the validation chirp is complete (at once
    without one); also written to a file and plotted as Fig. 6.
``diagnosis``
    With ``[worker] diagnose = true``, after a validated result: ``session`` and the JSON
    document of ``dtid diagnose --json``; also written to ``diagnosis.json`` beside the log.
``plan``
    With ``[worker] plan_follow_up = true``, after the result: ``session`` and the JSON document
    of ``dtid plan --prior identification.json --after LOG --json`` (the precision reached, the
    follow-up test; a target is met only where the identification's profile intervals, in a
    campaign's round its target tests, confirm it,
    :mod:`dtid.identification.planning.confirmation`); also written to ``follow-up.json``
    beside the log.

The identification starts when the identification chirps are complete (and
:data:`dtid.identification.pipeline.HOLD_OUT_S` of data past them arrived), in a thread, while the
validation chirp is recorded; the diagnosis and the follow-up plan after the result run in a
thread as well (a minute or more), and the session's last ``progress`` (with the files written)
and its end wait for them, while the loop goes on taking events and serving a new session.
Transport: ipc by default; a ``tcp://`` endpoint without a host means 127.0.0.1.

This module is the transport and the sessions' bookkeeping; what it computes and writes for a
session lies beside it: :mod:`~dtid.identification.service.live` (a session's data and FRFs),
:mod:`~dtid.identification.service.follow_up` (the follow-up test, a campaign round's
precision) and :mod:`~dtid.identification.service.session_files` (the files beside the log).
"""

from __future__ import annotations

import json
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zmq

from dtid.acquisition.config import PipelineConfig, SafetyConfig
from dtid.acquisition.ipc import endpoint
from dtid.acquisition.security import Security
from dtid.acquisition.server import bind
from dtid.acquisition.stream import KINDS, REPLAY_PAGE
from dtid.dbc.loader import load_interface
from dtid.errors import ConfigError, DtidError
from dtid.identification.diagnosis.mismatch import adequacy_of
from dtid.identification.frf.closed_loop import DEFAULT_RESOLUTION_HZ
from dtid.identification.html_report import IDENTIFICATION_FILE
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import IdentificationReport, identify_runs, validation_runs
from dtid.identification.planning.spread import DEFAULT_VEHICLES
from dtid.identification.samples.recording import load_recording
from dtid.identification.search.identify import SearchSettings
from dtid.identification.service.follow_up import (
    FOLLOW_UP_FILE,
    PreviousRound,
    campaign_widths,
    information_at_prior,
    plan_follow_up,
    precision_so_far,
    previous_round,
)
from dtid.identification.service.live import EventLog, LiveSession
from dtid.identification.service.session_files import (
    CLOSE_WAIT_S,
    rewrite_report,
    write_diagnosis,
    write_result,
    write_session_report,
)
from dtid.jsonfile import write_json
from dtid.simulator.parameters import DrivetrainParameters, reference_parameters
from dtid.simulator.vehicle_data import VehicleData

if TYPE_CHECKING:  # imported where used: planning is needed only with a campaign or follow-up
    from dtid.identification.planning.design import Design
    from dtid.identification.planning.information import PlanInformation

logger = logging.getLogger(__name__)

TOPICS = ("progress", "frf", "result")
"""Topics of the worker's results PUB."""
REPLAY_TIMEOUT_S = 2.0
"""A replay request without answer for this long is given up and sent again, s (wall)."""
GAP_RETRY_S = 0.2
"""Shortest time between two requests for the same gap, s (wall)."""
QUIET_S = 1.0
"""A session under way from which nothing arrived for this long is asked for its tail, s."""
PROGRESS_PERIOD_S = 1.0
"""Longest time between two progress messages while data arrive, s (wall)."""
POLL_MS = 100
"""Longest wait for a message before the loop looks at its sessions again, ms."""
DRAIN = 2000
"""Most messages taken from the stream before the sessions are advanced."""
STOP_WAIT_S = 20.0
"""Longest wall time a stop waits for a session's diagnosis and follow-up plan to end, s: then
the session's report is written with what is done and says what the stop interrupted (within
systemd's 90 s for a stop, with the report threads' :data:`CLOSE_WAIT_S`)."""


def leave_a_core_to_the_bus() -> int:
    """Let the simulator's threads use one core less than numba would, unless the user set
    ``NUMBA_NUM_THREADS``: the daemon on the same machine must never wait for the search.

    Returns
    -------
    int
        The threads the simulator now uses.
    """
    import numba

    if "NUMBA_NUM_THREADS" not in os.environ:
        numba.set_num_threads(max(1, numba.config.NUMBA_NUM_THREADS - 1))
    return numba.get_num_threads()


@dataclass(frozen=True)
class WorkerOptions:
    """What the worker computes and where it writes.

    Attributes
    ----------
    settings
        Search budget and seed (``dtid identify``'s defaults).
    profile_points
        Grid points per profile; 0 skips the profiles (``dtid identify``'s default: 5). In an
        adaptive campaign's round the targets are checked by the likelihood-ratio test at their
        ends instead (:mod:`dtid.identification.uncertainty.target_test`; a whole profile of
        every parameter over a campaign's growing runs took 44 minutes after the trial's second
        round), and 0 skips that too.
    prior
        Parameter set the bounds centre on; the reference vehicle by default.
    vehicle
        The vehicle's data besides its drivetrain (crank train); the reference engine's by
        default.
    json_path, plot_path
        Result file and Fig. 6 plot; None: ``identification.json`` and ``identification.png``
        beside the session's log.
    plot
        Draw the plot at all.
    resolution_hz
        Welch resolution of the FRFs.
    diagnose
        After the validation, diagnose the identified model (``[worker] diagnose``).
    mechanisms
        The library's mechanisms the diagnosis considers (``dtid worker --mechanisms``, as
        ``dtid diagnose --mechanisms``); None: all of them, empty: locate only.
    plan_follow_up
        After the result, plan the follow-up test (``[worker] plan_follow_up``).
    plan_vehicles
        Vehicles the follow-up (and a campaign's next round) is planned for besides the
        identified one, each drivetrain parameter within twice the precision the recorded runs
        reach, as ``dtid plan --after`` plans (``--spread recorded``); 0 plans at the identified
        parameters alone.
    safety
        The daemon's safety envelope, which caps the follow-up's amplitude and speed excursion.
    """

    settings: SearchSettings = field(default_factory=SearchSettings)
    profile_points: int = 5
    prior: DrivetrainParameters | None = None
    vehicle: VehicleData = field(default_factory=VehicleData)
    json_path: Path | None = None
    plot_path: Path | None = None
    plot: bool = True
    resolution_hz: float = DEFAULT_RESOLUTION_HZ
    diagnose: bool = False
    mechanisms: tuple[str, ...] | None = None
    plan_follow_up: bool = False
    plan_vehicles: int = DEFAULT_VEHICLES
    safety: SafetyConfig = field(default_factory=SafetyConfig)


@dataclass
class _Conclusion:
    """What a session's diagnosis and follow-up plan left, filled in as each is done (a stop
    that cannot wait for the rest reports what is there)."""

    files: list[str] = field(default_factory=list)
    """The files written."""
    diagnosis: Path | None = None
    """The diagnosis JSON, once written."""
    errors: list[str] = field(default_factory=list)
    """What went wrong, to publish."""


@dataclass
class _Session:
    """A session's events and the worker's state of its analysis."""

    id: str
    log: EventLog
    live: LiveSession | None = None
    thread: threading.Thread | None = None
    outcome: list[Any] = field(default_factory=list)
    report: IdentificationReport | None = None
    identification_failed: bool = False
    result: dict[str, Any] | None = None
    chirp_end_wall: float | None = None
    last_event_wall: float = field(default_factory=time.monotonic)
    last_progress_wall: float = 0.0
    finished: bool = False
    status: str = ""
    report_inputs: tuple[Path, Path | None] | None = None
    """The identification and diagnosis JSONs the session's report was made of."""
    earlier: list[MeasuredTest] = field(default_factory=list)
    """A campaign round's earlier rounds, read from their logs (identified together with it)."""
    precision: dict[str, float] | None = None
    """Precision the campaign's runs reach so far, % at 2 sigma (after each identifying run)."""
    before: PreviousRound | None = None
    """A campaign round's previous round: what it identified and the scatter its plan predicted
    for the runs recorded then (absolute, 1 sigma); None in round 1 or unreadable."""
    fit: dict[str, Any] | None = None
    """The diagnosis's adequacy test of the result (``[worker] diagnose``), reused by the plan."""
    concluding: threading.Thread | None = None
    """The diagnosis and the follow-up plan after the result, computed beside the loop."""
    conclusion: _Conclusion | None = None
    """What that thread has left so far."""
    pending: tuple[list[str], str] | None = None
    """The files written with the result and the stage to publish once the thread is done."""


class Worker:
    """The worker of one daemon: events in, progress, FRFs and results out.

    Parameters
    ----------
    pipeline
        The endpoints (``[pipeline]`` of the configuration).
    options
        What to compute and where to write.
    context
        ZeroMQ context (a new one by default).
    """

    def __init__(
        self,
        pipeline: PipelineConfig,
        options: WorkerOptions | None = None,
        context: zmq.Context | None = None,
    ) -> None:
        self.pipeline = pipeline
        self.options = options or WorkerOptions()
        self.context = context or zmq.Context.instance()
        self.prior = self.options.prior or reference_parameters()
        self.sessions: dict[str, _Session] = {}
        self.current: _Session | None = None
        self.finished: dict[str, str] = {}
        """Status of each session served: ``completed``, ``aborted`` or ``error``."""
        self.unwritten: set[str] = set()
        """Sessions whose result could not be written (published all the same)."""
        self._outbox: queue.SimpleQueue[tuple[str, dict[str, Any]]] = queue.SimpleQueue()
        self._req: zmq.Socket | None = None
        self._security = Security(self.pipeline.keys, self.context)
        self._req_sent = 0.0
        self._req_waiting = False
        self._replayed = False
        self._pub: zmq.Socket | None = None
        self._poller = zmq.Poller()
        self._report_threads: list[threading.Thread] = []
        self._campaigns: dict[str, tuple[PlanInformation, list[Design]]] = {}
        """Per campaign id, the last round's planning information and its recorded runs (the
        designs of :mod:`dtid.identification.planning.design`): what each new run adds."""
        self.listeners: list[Callable[[str, dict[str, Any]], None]] = []
        """Called with each message sent (for the command's terminal output and for tests)."""

    # --- the loop -----------------------------------------------------------------------------

    def serve(self, once: bool = False, stop: threading.Event | None = None) -> int:
        """Serve sessions until ``stop`` is set (or, with ``once``, until one session ends).

        Returns
        -------
        int
            0, or 2 when ``once`` and the session's analysis failed or its result could not be
            written.
        """
        stop = stop or threading.Event()
        sub = self.context.socket(zmq.SUB)
        sub.setsockopt(zmq.RCVHWM, 0)  # never drop: the IO thread buffers while we compute
        sub.setsockopt(zmq.LINGER, 0)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        blocks = endpoint(self.pipeline.blocks)
        self._security.connect(sub, blocks, "blocks")
        sub.connect(blocks)
        self._pub = self.context.socket(zmq.PUB)
        self._pub.setsockopt(zmq.LINGER, 1000)
        try:
            bind(self._pub, endpoint(self.pipeline.results, bind=True), "results", self._security)
        except ConfigError:
            sub.close(linger=0)
            self._pub.close(linger=0)
            self._security.close()
            raise
        self._poller = zmq.Poller()
        self._poller.register(sub, zmq.POLLIN)
        self._ask(0)
        try:
            while not stop.is_set():
                ready = dict(self._poller.poll(POLL_MS))
                for _ in range(DRAIN if ready.get(sub) else 0):
                    if not sub.poll(0):
                        break
                    self._receive_frames(sub.recv_multipart(zmq.NOBLOCK))
                if self._req is not None and ready.get(self._req):
                    self._receive_replay(self._req.recv())
                elif self._req_waiting and time.monotonic() - self._req_sent > REPLAY_TIMEOUT_S:
                    logger.info("no answer from the replay %s; asking again", self._replay)
                    self._close_req()
                for session in list(self.sessions.values()):
                    self._advance(session)
                self._ask_if_needed()
                self._flush()
                if once and self.finished:
                    failed = "error" in self.finished.values() or self.unwritten
                    return 2 if failed else 0
            return 0
        finally:
            for session in list(self.sessions.values()):  # stopped while diagnosing: end it first
                if session.concluding is not None and session.live is not None:
                    self._settle(session, session.live, wait_s=STOP_WAIT_S)
                elif session.thread is not None and session.live is not None:  # identifying
                    self._progress(session, "error", message=_stopped_identifying(session.live))
            for thread in self._report_threads:  # bounded: each waits CLOSE_WAIT_S at most
                thread.join(CLOSE_WAIT_S + 10.0)
            self._flush()
            self._close_req()
            sub.close(linger=0)
            self._pub.close()
            self._pub = None
            self._security.close()

    @property
    def _replay(self) -> str:
        return endpoint(self.pipeline.replay)

    # --- events in ----------------------------------------------------------------------------

    def _receive_frames(self, frames: list[bytes]) -> None:
        try:
            event = json.loads(frames[-1])
        except ValueError:
            logger.warning("not an event: %r", frames[-1][:80])
            return
        self._receive(event)

    def _receive_replay(self, reply: bytes) -> None:
        self._req_waiting = False
        self._replayed = True
        try:
            events = json.loads(reply)
        except ValueError:
            logger.warning("replay answer is not JSON: %r", reply[:80])
            return
        if not isinstance(events, list):
            logger.warning("replay answer is not a list of events: %r", reply[:80])
            return
        for event in events:
            self._receive(event)
        seqs = [e["seq"] for e in events if isinstance(e, dict) and isinstance(e.get("seq"), int)]
        if len(events) >= REPLAY_PAGE and seqs:
            self._ask(max(seqs) + 1)  # a full page: the rest follows

    def _receive(self, event: Any) -> None:
        if (
            not isinstance(event, dict)
            or event.get("kind") not in KINDS
            or not isinstance(event.get("seq"), int)
            or "session" not in event
        ):
            logger.warning("not a drivetrain-id event: %.80r", event)
            return
        sid = str(event["session"])
        if sid in self.finished or (
            sid in self.sessions and self.sessions[sid] is not self.current
        ):
            return  # a session served, or one a newer session superseded
        if self.current is None or self.current.id != sid:
            if self.current is not None and not self.current.finished:
                self._supersede(self.current)
            self.current = self.sessions[sid] = _Session(sid, EventLog(sid))
        self.current.last_event_wall = time.monotonic()
        self.current.log.add(event)

    def _supersede(self, session: _Session) -> None:
        """A new session began before this one ended: it ends here, as aborted."""
        logger.warning("session %s superseded before its end event", session.id)
        if session.live is not None and session.live.end is None:
            session.live.end = {"status": "aborted", "reason": "superseded"}
        elif session.live is None:
            self._finish(session, "aborted")

    # --- replay requests ----------------------------------------------------------------------

    def _ask(self, from_seq: int) -> None:
        """Ask the daemon's replay for its kept events from ``from_seq`` on."""
        if self._req_waiting:
            return
        if self._req is None:
            self._req = self.context.socket(zmq.REQ)
            self._req.setsockopt(zmq.LINGER, 0)
            self._security.connect(self._req, self._replay, "replay")
            self._req.connect(self._replay)
            self._poller.register(self._req, zmq.POLLIN)
        try:  # never block the loop: a REQ whose CURVE handshake failed has no peer to send to
            self._req.send(json.dumps({"from_seq": from_seq}).encode(), zmq.NOBLOCK)
        except zmq.Again:  # waited out and asked again, as an unanswered request
            logger.info("the replay %s took no request (do the keys match?)", self._replay)
        self._req_sent = time.monotonic()
        self._req_waiting = True

    def _close_req(self) -> None:
        """Give up a request (a REQ socket cannot send again before its answer: a new one)."""
        if self._req is not None:
            self._poller.unregister(self._req)
            self._req.close(linger=0)
        self._req = None
        self._req_waiting = False

    def _ask_if_needed(self) -> None:
        """Ask for a gap, for the tail of a quiet session, or for the past until answered."""
        if self._req_waiting:
            return
        now = time.monotonic()
        since = now - self._req_sent
        session = self.current if self.current is not None and not self.current.finished else None
        if session is None:
            if not self._replayed and since > REPLAY_TIMEOUT_S:
                self._ask(0)
            return
        ended = session.live is not None and session.live.end is not None
        quiet = now - session.last_event_wall > QUIET_S and since > QUIET_S
        if (
            (session.log.gap and since > GAP_RETRY_S)
            or (quiet and not ended)
            or (not self._replayed and since > REPLAY_TIMEOUT_S)
        ):
            self._ask(session.log.next_seq)

    # --- analysis -----------------------------------------------------------------------------

    def _advance(self, session: _Session) -> None:
        """Apply the session's new events and compute what is due."""
        if session.finished:
            return
        for event in session.log.take():
            if session.live is None:
                if event["kind"] != "session":
                    self._fail(session, f"session {session.id} does not begin with its start")
                    return
                try:
                    interface = load_interface(
                        (event.get("interface") or {}).get("dbc"),
                        (event.get("interface") or {}).get("signals"),
                    )
                except DtidError as error:
                    self._fail(session, str(error))
                    return
                session.live = LiveSession(
                    event, interface, self.options.resolution_hz, self.options.vehicle
                )
                self._measure_at_prior(session.live)
                self._progress(session, "acquiring")
                continue
            before = session.live.phase
            closed = session.live.identification_complete()
            session.live.apply(event)
            if not closed and session.live.identification_complete():
                session.chirp_end_wall = time.monotonic()
            if session.live.phase != before or event["kind"] == "end":
                self._progress(session, self._state(session))
        live = session.live
        if live is None:
            return
        try:
            self._compute(session, live)
        except DtidError as error:
            self._fail(session, str(error))
            return
        except Exception as error:  # a bug: the session fails, the worker keeps serving
            logger.exception("session %s: internal error", session.id)
            self._fail(session, f"internal error: {error!r}")
            return
        now = time.monotonic()
        if now - session.last_progress_wall > PROGRESS_PERIOD_S and not session.finished:
            # none while the diagnosis and plan are computed: the stage they end with is the
            # session's last word (dtid monitor takes "validated" after the end as finished)
            if (live.end is None or session.thread is not None) and session.concluding is None:
                self._progress(session, self._state(session))

    @staticmethod
    def _state(session: _Session) -> str:
        """The stage a session is in between the stage changes."""
        if session.result is not None:
            return "validated" if session.result["nrmse"]["validation"] else "identified"
        if session.thread is not None:
            return "identifying"
        return "identified" if session.report is not None else "acquiring"

    def _compute(self, session: _Session, live: LiveSession) -> None:
        due = live.frfs_due()
        validation_due = session.report is not None and live.validation_due()
        identification_due = (
            session.report is None and session.thread is None and not session.identification_failed
        ) and live.identification_due()
        data = live.test_data() if due or validation_due or identification_due else None
        if due:
            live.estimate(due, data)
            for chirp in due:
                if chirp.frf is not None:
                    entry = {"recording": live.name, **chirp.frf.as_dict()}
                    self._publish("frf", entry)
                else:
                    self._progress(session, "error", message=chirp.failed)
            self._precision_so_far(session, live)
        if identification_due:
            self._start_identification(session, live, data)
        if session.thread is not None and not session.thread.is_alive() and session.outcome:
            outcome = session.outcome.pop()
            session.thread = None
            if isinstance(outcome, BaseException):
                session.identification_failed = True
                self._progress(session, "error", message=str(outcome))
            else:
                session.report = outcome
                after = None
                if session.chirp_end_wall is not None:
                    after = time.monotonic() - session.chirp_end_wall
                self._progress(
                    session,
                    "identified",
                    parameters=outcome.parameters,
                    seconds_after_chirp=after,
                )
            validation_due = session.report is not None and live.validation_due()
            if validation_due:
                data = live.test_data()
        if session.report is not None and session.result is None:
            if live.validation_index is None:
                self._conclude(session, live, self._validated_by_earlier(session, live))
            elif validation_due:
                report = session.report.validated(live.validation_selection(data))
                self._conclude(session, live, report)
            elif live.end is not None:
                self._conclude(session, live, session.report)  # aborted before A3 was complete
        if session.concluding is not None and not session.concluding.is_alive():
            self._settle(session, live)
        if live.end is not None and session.thread is None and not live.frfs_due():
            if session.result is not None:
                if session.concluding is None:  # else the diagnosis or plan is being computed
                    self._finish(session, str(live.end.get("status", "completed")))
            elif session.report is None and not live.identification_due():
                reason = live.end.get("reason")
                self._progress(
                    session,
                    "aborted",
                    message="the identification chirps are not complete; no identification"
                    + (f" (abort: {reason})" if reason else ""),
                )
                self._finish(session, "aborted")
            elif session.identification_failed:
                self._finish(session, "error")

    def _measure_at_prior(self, live: LiveSession) -> None:
        """A campaign's first round: measure the planning information at the prior in a thread
        (as ``dtid plan`` does, about 10 s), so that the precision is said after each run from
        the first run on; the rounds after it use their last round's plan's."""
        campaign = live.campaign
        if campaign is None or str(campaign.get("id")) in self._campaigns:
            return
        key = str(campaign.get("id"))

        def run() -> None:
            try:
                info = information_at_prior(self.prior, live.identify_nm, self.options.vehicle)
            except Exception:  # the precision so far is a help; the round goes on without it
                logger.exception("campaign %s: the information at the prior", key)
                return
            self._campaigns.setdefault(key, (info, []))

        threading.Thread(target=run, name=f"information-{key}", daemon=True).start()

    def _precision_so_far(self, session: _Session, live: LiveSession) -> None:
        """In a campaign round, publish the precision its runs reach so far
        (:func:`dtid.identification.service.follow_up.precision_so_far`) as ``precision`` in a
        ``progress`` message, after each run from the first at which it can be said."""
        known = self._campaigns.get(str((live.campaign or {}).get("id")))
        if known is None:
            return
        info, recorded = known
        runs = [
            c.frf.run
            for c in sorted(live.chirps.values(), key=lambda c: c.index)
            if c.frf is not None
        ]
        so_far = precision_so_far(info, recorded, runs, live.identify_nm)
        if so_far is None:
            return
        session.precision, counted = so_far
        self._progress(session, self._state(session), precision_runs=counted)

    def _start_identification(self, session: _Session, live: LiveSession, data: Any) -> None:
        options = self.options
        logs = (live.campaign or {}).get("logs") or []

        def progress(stage: str, step: int, steps: int, best: float) -> None:
            # the search's thread only queues: the loop composes the message from the session
            search = {"stage": stage, "step": step, "steps": steps, "objective": best}
            self._outbox.put(("", {"session": session, "search": search}))

        def run() -> None:
            try:
                if logs:  # read in this thread: a campaign's earlier rounds take a while
                    session.earlier = [
                        MeasuredTest.from_data(
                            str(path),
                            load_recording(path, live.interface).test_data(),
                            live.resolution_hz,
                            options.vehicle,
                        )
                        for path in logs
                    ]
                    folder = Path(logs[-1]).parent
                    session.before = previous_round(
                        self._json_path(folder), folder / FOLLOW_UP_FILE
                    )
                selection = live.identification_selection(data, session.earlier)
                widths = campaign_widths(live.campaign) if options.profile_points else None
                report = identify_runs(
                    selection,
                    self.prior,
                    settings=options.settings,
                    profile_points=0 if widths else options.profile_points,
                    progress=progress,
                    warm_starts=[session.before[0]] if session.before else (),
                    target_widths=widths,
                )
            except BaseException as error:  # handed to the loop, which reports it
                session.outcome.append(error)
            else:
                session.outcome.append(report)

        session.thread = threading.Thread(target=run, name=f"identify-{session.id}", daemon=True)
        self._progress(session, "identifying")
        session.thread.start()

    def _json_path(self, folder: Path) -> Path:
        """The identification's JSON of the session whose log lies in ``folder``."""
        return self.options.json_path or folder / IDENTIFICATION_FILE

    @staticmethod
    def _validated_by_earlier(session: _Session, live: LiveSession) -> IdentificationReport:
        """The report, validated on the earlier campaign rounds' validation runs if they have
        any (a round planned by the worker has none of its own)."""
        assert session.report is not None
        if not session.earlier:
            return session.report
        selection = validation_runs(session.earlier, live.identify_nm, live.resolution_hz)
        return session.report.validated(selection) if selection.tests else session.report

    def _conclude(self, session: _Session, live: LiveSession, report: IdentificationReport) -> None:
        """Publish the result and write it; then diagnose and plan the follow-up, as the options
        ask, in a thread beside the loop (:meth:`_after_result`: a minute or more, during which
        the loop goes on taking events and serving other sessions), and write the report."""
        document = report.as_dict()
        session.result = document
        self._publish("result", document)
        folder = live.log_path.parent
        plot_path = None
        if self.options.plot:
            plot_path = self.options.plot_path or folder / "identification.png"
        try:
            written = write_result(report, document, self._json_path(folder), plot_path)
        except DtidError as error:
            self.unwritten.add(session.id)
            self._progress(session, "error", message=str(error))
            return
        stage = "validated" if document["nrmse"]["validation"] else "done"
        session.fit = None
        session.pending = (written, stage)
        diagnose = stage == "validated" and self.options.diagnose
        plan = self.options.plan_follow_up or live.campaign is not None
        session.conclusion = _Conclusion()
        if not (diagnose or plan):
            self._settle(session, live)
            return
        session.concluding = threading.Thread(
            target=self._after_result,
            args=(session, report, folder, live.campaign, diagnose, plan),
            name=f"conclude-{session.id}",
            daemon=True,
        )
        session.concluding.start()

    def _after_result(
        self,
        session: _Session,
        report: IdentificationReport,
        folder: Path,
        campaign: Mapping[str, Any] | None,
        diagnose: bool,
        plan: bool,
    ) -> None:
        """The diagnosis and the follow-up plan (in the session's ``concluding`` thread): each
        published as it is done, its files and errors added to ``session.conclusion`` for the
        loop (:meth:`_settle`)."""
        conclusion = session.conclusion
        assert conclusion is not None
        try:
            if diagnose:
                written = self._diagnose(session, report, folder, conclusion.errors)
                conclusion.files += written
                conclusion.diagnosis = Path(written[0]) if written else None
            if plan:
                conclusion.files += self._plan(session, report, folder, campaign, conclusion.errors)
        except Exception as error:  # a bug: said on the session, the worker keeps serving
            logger.exception("session %s: internal error after the result", session.id)
            conclusion.errors.append(f"internal error: {error!r}")

    def _settle(self, session: _Session, live: LiveSession, wait_s: float | None = None) -> None:
        """After the diagnosis and the plan: publish their errors, write the report and publish
        the session's stage with every file written. ``wait_s`` bounds the wait for them (a
        stop): what is not done by then is said interrupted, and the thread, a daemon, is left."""
        conclusion = session.conclusion
        assert conclusion is not None and session.pending is not None
        assert session.result is not None
        errors = conclusion.errors
        if session.concluding is not None:
            session.concluding.join(wait_s)
            if session.concluding.is_alive():
                errors = [*errors, _interrupted(live, self._json_path(live.log_path.parent))]
            session.concluding = None
        written, stage = session.pending
        session.conclusion = session.pending = None
        for message in errors:
            self._progress(session, "error", message=message)
        written = [*written, *conclusion.files]
        diagnosis_path = conclusion.diagnosis
        session.report_inputs = (self._json_path(live.log_path.parent), diagnosis_path)
        try:
            written.append(str(write_session_report(live, session.result, diagnosis_path)))
        except DtidError as error:
            self._progress(session, "error", message=f"the report: {error}")
        self._progress(session, stage, files=written)

    def _diagnose(
        self, session: _Session, report: IdentificationReport, folder: Path, errors: list[str]
    ) -> list[str]:
        """Diagnose the validated identification, publish and write it; the files written, what
        went wrong added to ``errors``."""
        from dtid.identification.diagnosis.diagnose import diagnose_report

        try:
            diagnosis = diagnose_report(report, mechanisms=self.options.mechanisms)
        except DtidError as error:
            errors.append(f"the diagnosis: {error}")
            return []
        session.fit = adequacy_of(diagnosis.mismatch)
        self._publish("diagnosis", {"session": session.id, **diagnosis.as_dict()})
        try:
            return write_diagnosis(diagnosis, folder, self.options.plot)
        except DtidError as error:
            errors.append(str(error))
            return []

    def _plan(
        self,
        session: _Session,
        report: IdentificationReport,
        folder: Path,
        campaign: Mapping[str, Any] | None,
        errors: list[str],
    ) -> list[str]:
        """Plan the follow-up test (:func:`dtid.identification.service.follow_up.plan_follow_up`),
        publish and write it; the files written, what went wrong added to ``errors``. In a
        campaign a failure is published as a plan without a test and with the ``error``, so the
        campaign stops saying why."""
        assert session.result is not None
        try:
            follow_up = plan_follow_up(
                report,
                session.result,
                safety=self.options.safety,
                vehicle=self.options.vehicle,
                vehicles=self.options.plan_vehicles,
                campaign=campaign,
                before=session.before,
                fit=session.fit,
            )
        except (DtidError, KeyError, TypeError, ValueError) as error:
            message = f"the follow-up plan: {error}"
            if campaign is not None:
                self._publish(
                    "plan",
                    {"session": session.id, "plan": None, "meets_targets": False, "error": message},
                )
            errors.append(message)
            return []
        if campaign is not None:
            self._campaigns[str(campaign.get("id"))] = (follow_up.information, follow_up.recorded)
        self._publish("plan", {"session": session.id, **follow_up.document})
        path = folder / FOLLOW_UP_FILE
        try:
            write_json(path, follow_up.document)
        except DtidError as error:
            errors.append(str(error))
            return []
        return [str(path)]

    def _fail(self, session: _Session, message: str) -> None:
        logger.error("session %s: %s", session.id, message)
        self._progress(session, "error", message=message)
        self._finish(session, "error")

    def _finish(self, session: _Session, status: str) -> None:
        session.finished = True
        self.finished[session.id] = status
        self.sessions.pop(session.id, None)
        if session.live is not None:
            self._progress(session, "done" if status == "completed" else status)
        if session.live is not None and session.report_inputs is not None:
            thread = threading.Thread(
                target=rewrite_report,
                args=(session.live, *session.report_inputs),
                name=f"report-{session.id}",
                daemon=True,
            )
            thread.start()
            self._report_threads.append(thread)

    # --- results out --------------------------------------------------------------------------

    def _progress(self, session: _Session, stage: str, **extra: Any) -> None:
        live = session.live
        message: dict[str, Any] = {"session": session.id, "stage": stage}
        if live is not None:
            message.update(
                phase=live.phase,
                data_s=live.data_s,
                chirps=[
                    c.amplitude_nm
                    for c in sorted(live.chirps.values(), key=lambda c: c.index)
                    if c.end_s is not None
                ],
            )
            if live.end is not None:
                message["end"] = {k: live.end.get(k) for k in ("status", "reason")}
        if session.precision is not None:
            message["precision"] = session.precision
        message.update(extra)
        session.last_progress_wall = time.monotonic()
        self._publish("progress", message)

    def _publish(self, topic: str, document: Mapping[str, Any]) -> None:
        """Queue a message (any thread); the loop sends it."""
        self._outbox.put((topic, dict(document)))

    def _flush(self) -> None:
        while True:
            try:
                topic, document = self._outbox.get_nowait()
            except queue.Empty:
                return
            if not topic:  # the search's progress, from its thread
                self._progress(document["session"], "identifying", search=document["search"])
                continue
            if topic == "progress":
                logger.info("progress %s", document)
            if self._pub is not None:
                body = json.dumps(document, separators=(",", ":"), allow_nan=False)
                self._pub.send_multipart([topic.encode(), body.encode()])
            for callback in self.listeners:
                callback(topic, document)


def _interrupted(live: LiveSession, json_path: Path) -> str:
    """What a stop said of a session whose diagnosis or follow-up plan it could not wait for."""
    return (
        f"the worker was stopped before the diagnosis and the follow-up plan were done (it waited"
        f" {STOP_WAIT_S:g} s): the result is written; `dtid diagnose {live.log_path}"
        f"{_interface_options(live)} --identification {json_path}` diagnoses it and `dtid plan`"
        " plans the next test"
    )


def _stopped_identifying(live: LiveSession) -> str:
    """What a stop said of a session it stopped in its identification (the search is not
    waited for: a minute or more)."""
    return (
        "the worker was stopped during the identification: no result; restarted, it identifies"
        " the session again from the events the daemon keeps, or once the log is closed"
        f" `dtid identify {live.log_path}{_interface_options(live)}` does"
    )


def _interface_options(live: LiveSession) -> str:
    """The session's ``--dbc`` and ``--signals`` options for a command line, if it had any."""
    files = live.start.get("interface") or {}
    return "".join(f" --{key} {files[key]}" for key in ("dbc", "signals") if files.get(key))
