"""The test driver's live view (``dtid monitor``): a terminal page redrawn from the pipeline.

It subscribes to the daemon's event stream (and asks its replay for what came before, as the
worker does, so it can be started at any time) and to the worker's results, folds every message
into a :class:`MonitorState`, and redraws the page with plain text and ANSI cursor codes (no
curses: it works over SSH, in tmux and in a log). The page shows:

- the session, the phase and the test time left (bus time, from the plan);
- the latest engine speed, mean torque and test torque, and the chirp's swept frequency;
- the frame and error counters of the daemon's health events;
- |G_DRV| of every finished chirp as the worker publishes it, drawn as a character plot;
- the worker's stage (identifying, its search's progress), the identified parameters, the
  validation NRMSE and the diagnosis's verdict;
- how the test ended, with the abort's reason.

The view only reads: it sends nothing to the bus and changes nothing in the pipeline.
"""

from __future__ import annotations

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
from dtid.acquisition.plan import TestPlan
from dtid.acquisition.security import Security
from dtid.acquisition.stream import ABORT_REASONS, KINDS, REPLAY_PAGE
from dtid.errors import ConfigError
from dtid.identification.service.worker import endpoint

PLOT_ROWS = 9
"""Rows of the |G_DRV| character plot."""
PLOT_MARKS = "123456789"
"""Mark of the n-th chirp's curve."""
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
        )
    lines.append("")
    lines += _frf_plot(state.frfs, width)
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


def _frf_plot(frfs: list[dict[str, Any]], width: int) -> list[str]:
    """|G_DRV| of the finished chirps as a character plot, one mark per chirp."""
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
        mark = PLOT_MARKS[index % len(PLOT_MARKS)]
        for f_hz, db in zip(estimate["frequency_hz"], estimate["drv_db"], strict=True):
            if not math.isfinite(db):
                continue
            column = round((f_hz - f_lo) / max(f_hi - f_lo, 1e-9) * (columns - 1))
            row = round((top - db) / span * (PLOT_ROWS - 1))
            grid[row][column] = mark
    legend = ", ".join(
        f"{PLOT_MARKS[i % len(PLOT_MARKS)]} = {e['amplitude_nm']:g} N*m" for i, e in enumerate(frfs)
    )
    lines = [f"|G_DRV| / dB of the finished chirps ({legend})"]
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
        self._asked_at = 0.0
        self._replayed = False

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
        self.state.apply_event(event)

    def _ask_replay(self, from_seq: int = 0) -> None:
        """Ask the daemon's replay for its kept events, until it answers once."""
        if self._replayed and from_seq == 0:
            return
        if self._req is not None and time.monotonic() - self._asked_at < 2.0 and from_seq == 0:
            return
        if self._req is not None:
            self._req.close(linger=0)
        self._req = self._context.socket(zmq.REQ)
        self._req.setsockopt(zmq.LINGER, 0)
        self._security.connect(self._req, self._replay_endpoint, "replay")
        self._req.connect(self._replay_endpoint)
        self._req.send(json.dumps({"from_seq": from_seq}).encode())
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
            self._ask_replay(max(seqs) + 1)
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
