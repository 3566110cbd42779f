"""The test driver's live view (``dtid monitor``): a terminal page redrawn from the pipeline.

It subscribes to the daemon's event stream (and asks its replay for what came before, as the
worker does, so it can be started at any time) and to the worker's results, folds every message
into a :class:`MonitorState`, and redraws the page with plain text and ANSI cursor codes (no
curses: it works over SSH, in tmux and in a log). The page shows:

- the session, the phase and the test time left (bus time, from the plan);
- the latest engine speed, mean torque and test torque, and the chirp's swept frequency;
- the frame and error counters of the daemon's health events;
- |G_DRV| of every finished chirp as the worker publishes it, and of the chirp being swept as
  far as it has come (re-estimated once a second from the samples received), drawn as a
  character plot;
- the worker's stage (identifying, its search's progress), the identified parameters, the
  validation NRMSE and the diagnosis's verdict;
- how the test ended, with the abort's reason.

The view only reads: it sends nothing to the bus and changes nothing in the pipeline.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TextIO

import zmq

from dtid.acquisition.config import PipelineConfig
from dtid.acquisition.ipc import endpoint
from dtid.acquisition.plan import Chirp, TestPlan
from dtid.acquisition.security import Security
from dtid.acquisition.stream import ABORT_REASONS, KINDS, REPLAY_PAGE
from dtid.dbc.loader import load_interface
from dtid.errors import AnalysisError, ConfigError, DtidError
from dtid.identification.frf.closed_loop import estimate_frf
from dtid.identification.frf.runs import ChirpRun
from dtid.identification.service.live import EventLog, LiveSession

PLOT_ROWS = 9
"""Rows of the |G_DRV| character plot."""
PLOT_MARKS = "123456789"
"""Mark of the n-th chirp's curve."""
REPLAY_RETRY_S = 2.0
"""Shortest wall time between two requests to the daemon's replay, s."""
SHOWN_PARAMETERS = ("J_sum", "x1", "x12", "c12", "c23", "d12", "d23", "Tc12", "eps12", "eps23")


@dataclass
class MonitorState:
    """What the page shows, folded from the daemon's events and the worker's messages."""

    session: str | None = None
    plan: TestPlan | None = None
    log_path: str | None = None
    start_t: float | None = None
    phase: str | None = None
    phase_t: float | None = None
    chirp: int | None = None
    amplitude_nm: float | None = None
    last_t: float | None = None
    latest: dict[str, float] = field(default_factory=dict)
    health: dict[str, int] = field(default_factory=dict)
    end: dict[str, Any] | None = None
    seqs: set[int] = field(default_factory=set)
    frfs: list[dict[str, Any]] = field(default_factory=list)
    stage: str | None = None
    search: str | None = None
    result: dict[str, Any] | None = None
    diagnosis: dict[str, Any] | None = None
    messages: list[str] = field(default_factory=list)
    building: dict[str, Any] | None = None

    def apply_event(self, event: dict[str, Any]) -> None:
        """Fold one daemon event of this session (any order; a repeated ``seq`` is ignored)."""
        if event.get("kind") not in KINDS or not isinstance(event.get("seq"), int):
            return
        if self.session is not None and event.get("session") != self.session:
            return
        if event["seq"] in self.seqs:
            return
        self.seqs.add(event["seq"])
        kind = event["kind"]
        if kind == "session":
            self.session = str(event["session"])
            self.log_path = event.get("log_path")
            self.plan = _plan(event.get("plan") or {})
        elif kind == "phase":
            if event["phase"] == "settle":  # the test's start
                self.start_t = event["t_s"]
            if self.phase_t is None or event["t_s"] >= self.phase_t:
                self.phase, self.phase_t = event["phase"], event["t_s"]
                self.chirp, self.amplitude_nm = event.get("chirp"), event.get("amplitude_nm")
                self.building = None
        elif kind == "samples":
            for role, entry in event.get("roles", {}).items():
                if entry.get("t") and (self.last_t is None or entry["t"][-1] >= self.last_t):
                    self.latest[role] = entry["value"][-1]
                    self.last_t = max(self.last_t or -math.inf, entry["t"][-1])
        elif kind == "health":
            self.health = {k: v for k, v in event.items() if isinstance(v, int) and k != "seq"}
        elif kind == "end":
            self.end = {k: event.get(k) for k in ("status", "reason", "t_s")}

    def apply_result(self, topic: str, document: dict[str, Any]) -> None:
        """Fold one worker message (``progress``, ``frf``, ``result``, ``diagnosis``)."""
        if self.session is not None and document.get("session", self.session) != self.session:
            return
        if topic == "progress":
            self.stage = document.get("stage")
            search = document.get("search")
            self.search = " ".join(str(search).split()) if search else self.search
            if document.get("message"):
                self.messages.append(str(document["message"]))
        elif topic == "frf":
            self.frfs.append(document)
        elif topic == "result":
            self.result = document
        elif topic == "diagnosis":
            self.diagnosis = document

    @property
    def finished(self) -> bool:
        """The test ended and the worker has said its last word on it."""
        return self.end is not None and self.stage in ("done", "validated", "error", "aborted")


def _plan(keys: dict[str, Any]) -> TestPlan | None:
    """The session event's plan (its constructor's keys; None when they do not make one)."""
    names = {f.name for f in dataclasses.fields(TestPlan) if f.init}
    try:
        return TestPlan(
            **{k: tuple(v) if isinstance(v, list) else v for k, v in keys.items() if k in names}
        )
    except (TypeError, ValueError, ConfigError):
        return None


def render(state: MonitorState, width: int = 100) -> list[str]:
    """The page's lines (at most ``width`` characters each)."""
    lines = [f"dtid monitor | session {state.session or '(waiting for the daemon)'}"]
    if state.session is None:
        return lines
    lines.append(_phase_line(state))
    latest = state.latest
    lines.append(
        "speed "
        + _value(latest.get("speed"), "rpm", ".1f")
        + " | mean torque "
        + _value(latest.get("mean_torque"), "N*m", ".2f")
        + " | test torque "
        + _value(latest.get("test_torque"), "N*m", ".2f")
    )
    health = state.health
    if health:
        lines.append(
            f"frames {health.get('frames', 0)} | lost {health.get('lost', 0)} | duplicated "
            f"{health.get('duplicated', 0)} | out of order {health.get('out_of_order', 0)} | "
            f"bad {health.get('bad_frames', 0)} | foreign tx {health.get('foreign_tx', 0)}"
            + (f" | no measurement {health['not_measured']}" if health.get("not_measured") else "")
        )
    lines.append("")
    lines += _frf_plot(state.frfs, state.building, width)
    lines.append("")
    lines.append(f"worker: {state.stage or '(no message yet)'}")
    if state.search and state.stage == "identifying":
        lines.append(f"  search: {state.search[-(width - 10) :]}")
    if state.result:
        parameters = state.result.get("parameters", {})
        shown = [f"{k} {parameters[k]:.4g}" for k in SHOWN_PARAMETERS if k in parameters]
        lines += _wrapped("identified: " + ", ".join(shown), width)
        validation = (state.result.get("nrmse") or {}).get("validation") or {}
        if validation:
            values = ", ".join(f"{v:.3f}" for v in validation.values())
            lines.append(f"  validation NRMSE {values}")
    if state.diagnosis:
        explanation = (state.diagnosis.get("verdict") or {}).get("explanation", "")
        lines += _wrapped(f"diagnosis: {explanation}", width)
    for message in state.messages[-3:]:
        lines += _wrapped(f"! {message}", width)
    if state.end:
        reason = state.end.get("reason")
        ended = f"test ended: {state.end.get('status')}"
        if reason:
            ended += f" ({reason}: {ABORT_REASONS.get(reason, reason)})"
        lines += _wrapped(ended, width)
    return [line[:width] for line in lines]


def _phase_line(state: MonitorState) -> str:
    plan, phase = state.plan, state.phase or "waiting"
    text = f"phase {phase}"
    if phase == "chirp" and state.chirp is not None and plan is not None:
        chirp = plan.chirps[state.chirp]
        text += f" {state.chirp + 1}/{len(plan.chirps)} at {chirp.amplitude_nm:g} N*m"
        if state.last_t is not None and state.phase_t is not None:
            tau = min(max(state.last_t - state.phase_t, 0.0), chirp.duration_s)
            f_hz = chirp.f1_hz + (chirp.f2_hz - chirp.f1_hz) * tau / chirp.duration_s
            text += f", sweeping {f_hz:.1f} Hz ({chirp.f1_hz:g}-{chirp.f2_hz:g} Hz)"
    if plan is not None and state.start_t is not None and state.last_t is not None:
        left = max(plan.end_s - (state.last_t - state.start_t), 0.0)
        text += f" | test time left {left:.0f} s of {plan.end_s:.0f} s"
    return text


def _frf_plot(
    finished: list[dict[str, Any]], building: dict[str, Any] | None, width: int
) -> list[str]:
    """|G_DRV| of the finished chirps (a digit each) and of the one being swept (``*``) as a
    character plot."""
    frfs = finished + ([building] if building else [])
    if not frfs:
        return ["|G_DRV|: no chirp finished yet"]
    columns = max(width - 12, 20)
    f_lo = min(min(e["frequency_hz"]) for e in frfs)
    f_hi = max(max(e["frequency_hz"]) for e in frfs)
    values = [v for e in frfs for v in e["drv_db"] if math.isfinite(v)]
    top, bottom = max(values), min(values)
    span = max(top - bottom, 1e-9)
    grid = [[" "] * columns for _ in range(PLOT_ROWS)]
    for index, estimate in enumerate(frfs):
        mark = "*" if estimate is building else PLOT_MARKS[index % len(PLOT_MARKS)]
        for f_hz, db in zip(estimate["frequency_hz"], estimate["drv_db"], strict=True):
            if not math.isfinite(db):
                continue
            column = round((f_hz - f_lo) / max(f_hi - f_lo, 1e-9) * (columns - 1))
            row = round((top - db) / span * (PLOT_ROWS - 1))
            grid[row][column] = mark
    legend = ", ".join(
        f"{PLOT_MARKS[i % len(PLOT_MARKS)]} = {e['amplitude_nm']:g} N*m"
        for i, e in enumerate(finished)
    )
    if building:
        legend += (", " if legend else "") + (
            f"* = {building['amplitude_nm']:g} N*m so far, to {building['to_hz']:.1f} Hz"
        )
    lines = [f"|G_DRV| / dB of the chirps ({legend})"]
    for row, cells in enumerate(grid):
        level = top - span * row / (PLOT_ROWS - 1)
        lines.append(f"{level:7.1f} |" + "".join(cells))
    lines.append(f"{'':8}{f_lo:<8.1f}{'frequency / Hz':^{columns - 16}}{f_hi:>8.1f}")
    return lines


def _value(value: float | None, unit: str, spec: str) -> str:
    return "-" if value is None else f"{format(value, spec)} {unit}"


def _wrapped(text: str, width: int) -> list[str]:
    lines, rest = [], text
    while len(rest) > width:
        cut = rest.rfind(" ", 0, width)
        cut = cut if cut > 0 else width
        lines.append(rest[:cut])
        rest = "  " + rest[cut:].lstrip()
    return [*lines, rest]


def building_frf(
    live: LiveSession, chirp: Chirp, start_t: float, now_t: float
) -> dict[str, Any] | None:
    """|G_DRV| of the chirp being swept, from its start to ``now_t``, over the band swept so far.

    Parameters
    ----------
    live
        The session's data so far.
    chirp
        The plan's chirp being swept.
    start_t, now_t
        Bus times of the chirp's start and of the latest sample, s.

    Returns
    -------
    dict or None
        ``amplitude_nm``, ``frequency_hz``, ``drv_db`` (up to one Welch segment's sweep below
        the frequency reached, where the estimate is whole) and ``to_hz`` (the frequency
        reached); None until two Welch segments of the sweep are in, or when the estimate fails
        (too little coherence yet, a gap).
    """
    resolution = live.resolution_hz
    tau = min(now_t - start_t, chirp.duration_s)
    rate = (chirp.f2_hz - chirp.f1_hz) / chirp.duration_s
    f_now = chirp.f1_hz + rate * tau
    # a bin is whole once the sweep has passed it by one Welch segment (1 / resolution s)
    band = (chirp.f1_hz + resolution, f_now - max(rate / resolution, resolution))
    if tau < 2.0 / resolution or band[1] - band[0] < 4 * resolution:
        return None
    run = ChirpRun(
        start_s=start_t - live.log_start_s,
        end_s=start_t + tau - live.log_start_s,
        amplitude_nm=chirp.amplitude_nm,
        f1_hz=chirp.f1_hz,
        f2_hz=f_now,
    )
    try:
        estimate = estimate_frf(live.test_data(), run, resolution, band)
    except (AnalysisError, ValueError):
        return None
    return {
        "amplitude_nm": chirp.amplitude_nm,
        "frequency_hz": estimate.frequency_hz.tolist(),
        "drv_db": estimate.drv_db.tolist(),
        "to_hz": f_now,
    }


class Monitor:
    """Subscribes to the daemon and the worker and keeps a :class:`MonitorState`.

    Parameters
    ----------
    pipeline
        The endpoints (``blocks``, ``replay``, ``results``) and CURVE keys of the configuration.
    """

    def __init__(self, pipeline: PipelineConfig) -> None:
        self.state = MonitorState()
        self._context = zmq.Context()
        self._security = Security(pipeline.keys, self._context)
        self._blocks = self._subscribe(endpoint(pipeline.blocks), "blocks")
        self._results = self._subscribe(endpoint(pipeline.results), "results")
        self._replay_endpoint = endpoint(pipeline.replay)
        self._req: zmq.Socket | None = None
        self._asked_at = -math.inf
        self._replayed = False
        self._log: EventLog | None = None
        self._live: LiveSession | None = None
        self._estimated_at = 0.0

    def _subscribe(self, address: str, name: str) -> zmq.Socket:
        socket = self._context.socket(zmq.SUB)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.SUBSCRIBE, b"")
        self._security.connect(socket, address, name)
        socket.connect(address)
        return socket

    def poll(self, timeout_s: float) -> None:
        """Take every message that arrives within ``timeout_s`` (and the replay's pages)."""
        self._ask_replay()
        poller = zmq.Poller()
        for socket in (self._blocks, self._results, self._req):
            if socket is not None:
                poller.register(socket, zmq.POLLIN)
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            ready = dict(poller.poll(max(1, int(left * 1000))))
            if ready.get(self._blocks):
                self._take(self._blocks.recv_multipart(), daemon=True)
            if ready.get(self._results):
                self._take(self._results.recv_multipart(), daemon=False)
            if self._req is not None and ready.get(self._req):
                poller.unregister(self._req)
                self._receive_replay(self._req.recv())
        self._update_building()

    def _take(self, frames: list[bytes], daemon: bool) -> None:
        try:
            document = json.loads(frames[-1])
        except ValueError:
            return
        if not isinstance(document, dict):
            return
        if daemon:
            self._event(document)
        else:
            self.state.apply_result(frames[0].decode(errors="replace"), document)

    def _event(self, event: dict[str, Any]) -> None:
        """A daemon event; a new session's first one starts the page afresh."""
        new = event.get("kind") == "session" and event.get("session") != self.state.session
        if new and self.state.session is not None:
            self.state = MonitorState()
            self._log = self._live = None
        self.state.apply_event(event)
        if event.get("kind") not in KINDS or not isinstance(event.get("seq"), int):
            return
        if self._log is None:  # also before the session event itself: the replay's order
            self._log = EventLog(str(event.get("session")))
        if str(event.get("session")) != self._log.session:
            return
        self._log.add(event)
        for ordered in self._log.take():  # the samples in seq order, as the worker keeps them
            if ordered["kind"] == "session":
                paths = ordered.get("interface") or {}
                try:
                    interface = load_interface(paths.get("dbc"), paths.get("signals"))
                except DtidError:
                    continue  # the page still shows the rest; only the FRF so far is lost
                self._live = LiveSession(ordered, interface)
            elif self._live is not None:
                self._live.apply(ordered)

    def _update_building(self) -> None:
        """Re-estimate the swept chirp's FRF so far, at most once a second."""
        state, live = self.state, self._live
        if state.phase != "chirp" or live is None or state.plan is None or state.chirp is None:
            return
        if state.last_t is None or state.phase_t is None:
            return
        if time.monotonic() - self._estimated_at < 1.0:
            return
        self._estimated_at = time.monotonic()
        chirp = state.plan.chirps[state.chirp]
        state.building = building_frf(live, chirp, state.phase_t, state.last_t)

    def _ask_replay(self) -> None:
        """Ask the daemon's replay for its kept events until it answers once, and again from the
        first one missing while later ones arrived (a subscriber joins a publisher late, so a
        monitor started before the daemon can miss the session's first events, which the
        replay, asked before there were any, did not hold); at most every
        :data:`REPLAY_RETRY_S`."""
        gap = self._log is not None and self._log.gap
        if self._replayed and not gap:
            return
        if time.monotonic() - self._asked_at < REPLAY_RETRY_S:
            return
        self._request(self._log.next_seq if gap and self._log is not None else 0)

    def _request(self, from_seq: int) -> None:
        """Send one request to the replay, on a new socket (a REQ socket whose request went
        unanswered cannot send again)."""
        if self._req is not None:
            self._req.close(linger=0)
        self._req = self._context.socket(zmq.REQ)
        self._req.setsockopt(zmq.LINGER, 0)
        self._security.connect(self._req, self._replay_endpoint, "replay")
        self._req.connect(self._replay_endpoint)
        with contextlib.suppress(zmq.Again):  # no peer (a failed CURVE handshake): asked again
            self._req.send(json.dumps({"from_seq": from_seq}).encode(), zmq.NOBLOCK)
        self._asked_at = time.monotonic()

    def _receive_replay(self, reply: bytes) -> None:
        self._replayed = True
        try:
            events = json.loads(reply)
        except ValueError:
            return
        if not isinstance(events, list):
            return
        for event in events:
            if isinstance(event, dict):
                self._event(event)
        seqs = [e["seq"] for e in events if isinstance(e, dict) and isinstance(e.get("seq"), int)]
        if len(events) >= REPLAY_PAGE and seqs:
            self._request(max(seqs) + 1)
        else:
            self._req.close(linger=0)  # type: ignore[union-attr]
            self._req = None

    def close(self) -> None:
        """Close the sockets."""
        for socket in (self._blocks, self._results, self._req):
            if socket is not None:
                socket.close(linger=0)
        self._security.close()
        self._context.term()


def run_monitor(
    pipeline: PipelineConfig,
    refresh_s: float = 0.5,
    until_finished: bool = False,
    out: TextIO = sys.stdout,
    width: Callable[[], int] = lambda: 100,
) -> int:
    """Redraw the page every ``refresh_s`` until interrupted (or, with ``until_finished``, until
    the test ended and the worker said its last word). Returns 0."""
    monitor = Monitor(pipeline)
    try:
        while True:
            monitor.poll(refresh_s)
            page = render(monitor.state, width())
            out.write("\x1b[H\x1b[2J" + "\n".join(page) + "\n")
            out.flush()
            if until_finished and monitor.state.finished:
                return 0
    finally:
        monitor.close()
