"""The identification worker (issue 4): event merging, live == replay == `dtid identify`, restart.

A simulated test (5 and 10 N*m identify, 2 N*m validates, 20 s chirps) is cut into the daemon's
events (dtid.acquisition.stream's contract) and served by a fake daemon over ipc: PUB of the events,
REP of the kept ones. The worker's results are compared with ``dtid identify`` and ``dtid frf``
on the log written from the same frames.
"""

from __future__ import annotations

import itertools
import json
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq
from json_schemas import validate

import dtid.identification.service.worker as worker_module
from dtid.acquisition.config import AcquisitionConfig, PipelineConfig
from dtid.acquisition.logfile import read_log, write_log
from dtid.acquisition.plan import TestPlan
from dtid.acquisition.stream import REPLAY_PAGE, encode_event, samples_roles
from dtid.cli import main
from dtid.dbc.loader import load_interface
from dtid.identification.pipeline import HOLD_OUT_S
from dtid.identification.samples.recording import load_recording
from dtid.identification.search.identify import SearchSettings
from dtid.identification.service.live import EventLog, LiveSession
from dtid.identification.service.worker import Worker, WorkerOptions, endpoint
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_frames import simulation_frames

ROOT = Path(__file__).resolve().parents[1]
BASE_S = 1_700_000_000.123456789
"""Bus time of the test's start: Unix-epoch timestamps, as the daemon records."""
BLOCK_S = 0.25
"""Bus time per samples event."""
BUDGET = SearchSettings(popsize=2, generations=2, polish_evaluations=20, seed=3).single_start()
BUDGET_ARGS = ["--seed", "3", "--generations", "2", "--popsize", "2", "--polish-evaluations", "20",
               "--single-start"]  # fmt: skip
"""The search is not these tests' subject: the smallest budget, alike in the worker and the
commands it is compared with."""
PLAN = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=2.0, duration_s=20.0)
SCREENED = ("gearbox_drag", "torque_lag")
"""The mechanisms the replayed worker's diagnosis considers: the screen sets them aside at once
on this clean plant (the whole library's diagnosis is tests/test_diagnosis.py's subject)."""


@dataclass
class SimulatedSession:
    """A session as the daemon would stream and log it."""

    events: list[dict[str, Any]]
    log_path: Path
    frames: int
    chirp_ends_s: list[float]


def _events(frames: Sequence, log_path: Path, session: str) -> SimulatedSession:
    interface = load_interface()
    plan = PLAN
    start = frames[0].timestamp
    times = np.array([f.timestamp for f in frames])
    marks = [(start, "settle", None, None)]
    for index, chirp in enumerate(plan.chirps):
        marks.append((BASE_S + chirp.start_s, "chirp", index, chirp.amplitude_nm))
        marks.append((BASE_S + chirp.end_s, "pause", None, None))
    marks.append((BASE_S + plan.end_s, "done", None, None))
    events: list[dict[str, Any]] = [
        {
            "kind": "session",
            "session": session,
            "seq": 0,
            "log_path": str(log_path),
            "log_start_s": start,
            "plan": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(PLAN).items()},
            "interface": {"dbc": None, "signals": None},
            "time_factor": 1.0,
        }
    ]

    def add(kind: str, **keys: Any) -> None:
        events.append({"kind": kind, "session": session, "seq": len(events), **keys})

    edges = np.arange(start, times[-1] + BLOCK_S, BLOCK_S)
    for lo, hi in itertools.pairwise(edges):
        # a phase is announced as soon as its time comes, before the frames of the block it
        # falls in: the worker must wait for the data itself
        while marks and marks[0][0] < hi:
            t, phase, chirp, amplitude = marks.pop(0)
            add("phase", phase=phase, t_s=t, chirp=chirp, amplitude_nm=amplitude)
        a, b = np.searchsorted(times, [lo, hi])
        chunk = frames[a:b]
        if chunk:
            roles = samples_roles(interface.decode(chunk))
            add("samples", roles=roles, frames=len(chunk), received_wall_s=time.time())
        if len(events) % 40 == 0:
            add("health", lost=0, duplicated=0, out_of_order=0, bad_frames=0, foreign_tx=0)
    for t, phase, chirp, amplitude in marks:
        add("phase", phase=phase, t_s=t, chirp=chirp, amplitude_nm=amplitude)
    add("end", status="completed", reason=None, t_s=float(times[-1]))
    ends = [c.end_s for c in plan.chirps]
    return SimulatedSession(events, log_path, len(frames), ends)


@pytest.fixture(scope="module")
def session(reference, tmp_path_factory: pytest.TempPathFactory) -> SimulatedSession:
    """The simulated session's events, and its log written from the same frames."""
    result = simulate(reference, PLAN, SimulationOptions(), seed=5)
    frames = simulation_frames(result, load_interface())
    for frame in frames:
        frame.timestamp += BASE_S
    log_path = tmp_path_factory.mktemp("session") / "test.blf"
    write_log(log_path, frames)
    return _events(frames, log_path, "s1")


HOLD_PAST_S = 1.0
"""Bus seconds past the identification's data (the last identifying chirp's end and
:data:`HOLD_OUT_S`) at which the live stream waits for the worker's ``identifying``."""
HOLD_TIMEOUT_S = 120.0
"""Wall seconds a held stream waits for its release at most (a worker that never releases it
fails its test instead of hanging it)."""


class FakeDaemon:
    """The daemon's side of the pipeline: PUB of events (paced), REP of the kept ones.

    Parameters
    ----------
    pipeline
        Endpoints.
    events
        The session's events, in seq order.
    bus_per_wall
        Pace: bus seconds streamed per wall second (samples events are 0.25 s of bus time).
    drop, duplicate
        Seqs not sent live (but kept), and seqs sent twice.
    hold_after_s
        Bus seconds from the log start past which the stream waits until :attr:`release` is
        set (at most :data:`HOLD_TIMEOUT_S` of wall time), then goes on at its pace: what the
        worker did with the data up to there is then the same on a quiet and a busy host.
    """

    def __init__(
        self,
        pipeline: PipelineConfig,
        events: list[dict[str, Any]],
        bus_per_wall: float = 1e9,
        drop: frozenset[int] = frozenset(),
        duplicate: frozenset[int] = frozenset(),
        page: int = REPLAY_PAGE,
        hold_after_s: float | None = None,
    ) -> None:
        self.pipeline, self.events, self.page = pipeline, events, page
        self.hold_after_s = hold_after_s
        self.release = threading.Event()
        self.bus_per_wall, self.drop, self.duplicate = bus_per_wall, drop, duplicate
        self.kept: list[dict[str, Any]] = []
        self.requests: list[int] = []
        self.replayed: set[int] = set()
        """The seqs its replay answers carried."""
        self.stop = threading.Event()
        self.done = threading.Event()
        self.go = threading.Event()
        self.context = zmq.Context()
        self.pub = self.context.socket(zmq.PUB)
        self.pub.bind(endpoint(pipeline.blocks, bind=True))
        self.rep = self.context.socket(zmq.REP)
        self.rep.bind(endpoint(pipeline.replay, bind=True))
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _serve_replay(self, timeout_ms: int) -> None:
        if self.rep.poll(timeout_ms):
            request = json.loads(self.rep.recv())
            self.requests.append(request["from_seq"])
            kept = [e for e in self.kept if e["seq"] >= request["from_seq"]][: self.page]
            self.replayed.update(e["seq"] for e in kept)
            self.rep.send(json.dumps(kept).encode())

    def _run(self) -> None:
        started, bus = None, self.events[0]["log_start_s"]
        for event in self.events:
            if self.stop.is_set():
                break
            while not self.go.is_set() and not self.stop.is_set():
                self._serve_replay(10)
            started = started or time.monotonic()
            bus = _bus_time(event) or bus
            if (
                self.hold_after_s is not None
                and bus - self.events[0]["log_start_s"] > self.hold_after_s
            ):
                held = time.monotonic()
                while not self.release.is_set() and time.monotonic() - held < HOLD_TIMEOUT_S:
                    self._serve_replay(10)
                started += time.monotonic() - held
                self.hold_after_s = None
            due = started + (bus - self.events[0]["log_start_s"]) / self.bus_per_wall
            while (wait := due - time.monotonic()) > 0 and not self.stop.is_set():
                self._serve_replay(max(1, int(wait * 1000)))
            self.kept.append(event)
            if event["seq"] not in self.drop:
                self.pub.send_multipart(encode_event(event))
            if event["seq"] in self.duplicate:
                self.pub.send_multipart(encode_event(event))
            self._serve_replay(0)
        self.done.set()
        while not self.stop.is_set():
            self._serve_replay(20)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.pub.close(linger=0)
        self.rep.close(linger=0)
        self.context.term()


def _bus_time(event: dict[str, Any]) -> float | None:
    """When the daemon sends an event: its time, or its last sample's."""
    if event["kind"] == "samples":
        return max((entry["t"][-1] for entry in event["roles"].values()), default=None)
    return event.get("t_s")


@pytest.fixture
def ipc_dir() -> Iterator[Path]:
    """A short folder for ipc endpoints (a Unix socket path has at most 107 bytes)."""
    folder = Path(tempfile.mkdtemp(prefix="dtidw-", dir="/tmp"))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def _pipeline(folder: Path) -> PipelineConfig:
    return PipelineConfig(
        **{name: f"ipc://{folder}/{name}" for name in ("blocks", "replay")},
        results=f"ipc://{folder}/results",
    )


def _config_file(folder: Path, pipeline: PipelineConfig) -> Path:
    path = folder / "dtid.toml"
    path.write_text(
        "[pipeline]\n"
        + "".join(
            f'{name} = "{getattr(pipeline, name)}"\n' for name in ("blocks", "replay", "results")
        )
    )
    return path


def _serve(
    pipeline: PipelineConfig,
    options: WorkerOptions,
    timeout_s: float = 60.0,
    listener: Callable[[str, dict[str, Any]], None] | None = None,
) -> tuple[int, list[tuple[str, dict[str, Any]]], Worker]:
    """Run a worker with --once in a thread; its messages and exit status. ``listener`` hears
    each message as it is published."""
    worker = Worker(pipeline, options)
    messages: list[tuple[str, dict[str, Any]]] = []
    worker.listeners.append(lambda topic, doc: messages.append((topic, doc)))
    if listener is not None:
        worker.listeners.append(listener)
    status: list[int] = []
    stop = threading.Event()
    thread = threading.Thread(target=lambda: status.append(worker.serve(once=True, stop=stop)))
    thread.start()
    thread.join(timeout_s)
    if thread.is_alive():
        stop.set()
        thread.join(5)
        pytest.fail(f"the worker did not finish within {timeout_s} s")
    return status[0], messages, worker


def _serve_unpaced(
    events: list[dict[str, Any]], folder: Path, json_path: Path | None = None
) -> tuple[int, list[tuple[str, dict[str, Any]]], Worker]:
    """:func:`_serve` on the events, sent at once; the result goes to ``json_path``
    (``folder/r.json`` by default)."""
    pipeline = _pipeline(folder)
    daemon = FakeDaemon(pipeline, events)
    daemon.go.set()
    options = WorkerOptions(
        settings=BUDGET, profile_points=0, json_path=json_path or folder / "r.json", plot=False
    )
    try:
        return _serve(pipeline, options)
    finally:
        daemon.close()


def _without_wall_time(document: dict[str, Any]) -> dict[str, Any]:
    """The document less ``seconds``, the search's wall time (the one key that differs)."""
    return {k: v for k, v in document.items() if k != "seconds"}


# --- merging ------------------------------------------------------------------------------------


def test_event_log_orders_drops_duplicates_and_finds_gaps() -> None:
    log = EventLog("s")
    event = {"kind": "health", "session": "s"}
    assert log.add({**event, "seq": 0}) and log.add({**event, "seq": 2})
    assert [e["seq"] for e in log.take()] == [0]
    assert log.gap and log.next_seq == 1  # 1 is missing: ask the replay from 1
    assert not log.add({**event, "seq": 2}) and not log.add({**event, "seq": 0})
    assert log.duplicates == 2
    assert log.add({**event, "seq": 1})
    assert [e["seq"] for e in log.take()] == [1, 2]
    assert not log.gap and log.take() == []


def test_endpoints_are_local_unless_told() -> None:
    assert endpoint("tcp://:5555") == "tcp://127.0.0.1:5555"
    assert endpoint("tcp://10.0.0.2:5555") == "tcp://10.0.0.2:5555"
    assert endpoint("tcp://*:5555") == "tcp://127.0.0.1:5555"  # the daemon's, to connect to
    assert endpoint("tcp://*:5555", bind=True) == "tcp://*:5555"  # told: every interface
    assert endpoint("ipc:///run/dtid/results") == "ipc:///run/dtid/results"
    with pytest.raises(Exception, match="expected ipc"):
        endpoint("udp://1.2.3.4:5")
    with pytest.raises(Exception, match="HOST:PORT"):
        endpoint("tcp://localhost")
    with pytest.raises(Exception, match=r"port must lie in 1 \.\. 65535"):
        endpoint("tcp://127.0.0.1:99999")  # ZeroMQ listened on 34463 and said 99999


def test_samples_give_the_logs_recording_exactly(session: SimulatedSession) -> None:
    """The same code builds both: every role's times, values and extras are bit-identical."""
    interface = load_interface()
    live = LiveSession(session.events[0], interface)
    for event in session.events[1:]:
        live.apply(event)
    streamed, logged = live.recording(), load_recording(session.log_path, interface)
    assert set(streamed.roles) == set(logged.roles)
    for role, series in logged.roles.items():
        other = streamed.roles[role]
        assert len(series.timestamps) > 100
        np.testing.assert_array_equal(other.timestamps, series.timestamps)
        np.testing.assert_array_equal(other.values, series.values)
        assert set(other.extra) == set(series.extra)
        for key, column in series.extra.items():
            np.testing.assert_array_equal(other.extra[key], column)
    assert streamed.n_frames == logged.n_frames == session.frames
    assert [c.amplitude_nm for c in live.chirps.values()] == [5.0, 10.0, 2.0]
    assert all(c.end_s is not None for c in live.chirps.values())


# --- live == replay == dtid identify -----------------------------------------------------------


@pytest.fixture(scope="module")
def offline(session: SimulatedSession, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """`dtid identify` and `dtid frf` on the daemon's log, same seed and budget."""
    out = tmp_path_factory.mktemp("offline")
    log = str(session.log_path)
    assert main(["identify", log, "--json", str(out / "id.json"), "--profile-points", "0",
                 *BUDGET_ARGS]) == 0  # fmt: skip
    assert main(["frf", log, "--json", str(out / "frf.json")]) == 0
    return {
        "identify": json.loads((out / "id.json").read_text()),
        "frf": json.loads((out / "frf.json").read_text())["runs"],
    }


@pytest.fixture(scope="module")
def live_run(session: SimulatedSession, offline: dict) -> dict:
    """One worker on the paced stream (10x real time), some events lost or sent twice; the
    stream waits just past the identification's data (:data:`HOLD_PAST_S`) until the worker
    announces the identification."""
    folder = Path(tempfile.mkdtemp(prefix="dtidw-", dir="/tmp"))
    pipeline = _pipeline(folder)
    n = len(session.events)
    drop = frozenset({1, 7, n // 2, n // 2 + 1, n - 3})  # gaps, found and asked for
    duplicate = frozenset({3, n // 3})
    out = session.log_path.parent / "live"
    out.mkdir()
    hold_after_s = session.chirp_ends_s[1] + HOLD_OUT_S + HOLD_PAST_S
    daemon = FakeDaemon(
        pipeline,
        session.events,
        bus_per_wall=10.0,
        drop=drop,
        duplicate=duplicate,
        hold_after_s=hold_after_s,
    )

    def release(topic: str, doc: dict[str, Any]) -> None:
        if topic == "progress" and doc.get("stage") == "identifying":
            daemon.release.set()

    context = zmq.Context()
    listener = context.socket(zmq.SUB)
    listener.setsockopt(zmq.SUBSCRIBE, b"")
    listener.connect(pipeline.results)
    daemon.go.set()
    options = WorkerOptions(
        settings=BUDGET,
        profile_points=0,
        json_path=out / "identification.json",
        plot_path=out / "fig6.png",
    )
    try:
        status, messages, worker = _serve(pipeline, options, listener=release)
        received = []
        while listener.poll(200):
            topic, body = listener.recv_multipart()
            received.append((topic.decode(), json.loads(body)))
    finally:
        listener.close(linger=0)
        context.term()
        daemon.close()
        shutil.rmtree(folder, ignore_errors=True)
    return {
        "status": status,
        "messages": messages,
        "received": received,
        "out": out,
        "requests": daemon.requests,
        "replayed": daemon.replayed,
        "dropped": drop,
        "finished": worker.finished,
    }


def test_live_result_equals_dtid_identify_on_the_log(live_run: dict, offline: dict) -> None:
    assert live_run["status"] == 0 and live_run["finished"] == {"s1": "completed"}
    results = [doc for topic, doc in live_run["messages"] if topic == "result"]
    assert len(results) == 1
    live, replay = results[0], offline["identify"]
    assert _without_wall_time(live) == _without_wall_time(replay)
    assert set(live["nrmse"]["validation"]) == {f"{live_run['out'].parent}/test.blf @ 2 N*m"}
    assert len(live["nrmse"]["fit"]) == 2
    written = json.loads((live_run["out"] / "identification.json").read_text())
    assert written == live
    validate(written, "identification")
    assert (live_run["out"] / "fig6.png").stat().st_size > 10_000
    # the session's HTML report beside its log, from the live data and this result
    report = (live_run["out"].parent / "report.html").read_text()
    assert "while the session ran" in report and "id='fig-fit'" in report
    for name in ("c12", "d12", "eps12"):
        assert f"<td>{name}</td><td class='num'>{live['parameters'][name]:.4g}</td>" in report
    # the PUB carried the same result (the SUB joined before the worker published anything)
    assert [doc for topic, doc in live_run["received"] if topic == "result"] == [live]


def test_frfs_published_per_chirp_as_dtid_frf(live_run: dict, offline: dict) -> None:
    frfs = [doc for topic, doc in live_run["messages"] if topic == "frf"]
    assert [round(e["amplitude_nm"], 3) for e in frfs] == [5.0, 10.0, 2.0]
    assert frfs == offline["frf"]  # entry for entry, the same numbers as `dtid frf` on the log


def test_identifies_while_the_validation_chirp_is_recorded(
    live_run: dict, session: SimulatedSession
) -> None:
    progress = [doc for topic, doc in live_run["messages"] if topic == "progress"]
    stages = [p["stage"] for p in progress]
    assert stages.index("identifying") < stages.index("identified") < stages.index("validated")
    started = next(p for p in progress if p["stage"] == "identifying")
    a2_end = session.chirp_ends_s[1]
    # started once the data past A2 arrived, and with the stream held just past them (live_run),
    # before anything more came: on a quiet host and a busy one alike
    assert a2_end + HOLD_OUT_S <= started["data_s"] <= a2_end + HOLD_OUT_S + HOLD_PAST_S
    assert started["chirps"] == [5.0, 10.0]
    searching = [p["search"] for p in progress if "search" in p]
    assert searching and searching[-1]["stage"] in ("global", "local")
    identified = next(p for p in progress if p["stage"] == "identified")
    assert identified["seconds_after_chirp"] > 0
    assert stages[-1] == "done"
    # every event lost on the stream came with a replay answer: to a request from it, the
    # first missing (test_event_log_orders_drops_duplicates_and_finds_gaps), or to an earlier
    # one (on a busy host the worker's first request, from 0, may come after the daemon kept
    # event 1: which request answers which gap is the host's timing, not the worker's logic)
    assert live_run["dropped"] <= live_run["replayed"]


# --- aborted sessions -------------------------------------------------------------------------


def _aborted(session: SimulatedSession, at_s: float) -> list[dict[str, Any]]:
    """The session's events until bus time ``at_s`` (from the start), then an aborted end."""
    start = session.events[0]["log_start_s"]
    kept = []
    for event in session.events[:-1]:
        t = _bus_time(event)
        if t is not None and t - start > at_s:
            break
        kept.append(event)
    end = {"kind": "end", "session": "s1", "seq": len(kept), "status": "aborted"}
    return [*kept, {**end, "reason": "speed_window", "t_s": start + at_s}]


def test_aborted_before_the_identification_chirps_end(
    session: SimulatedSession, ipc_dir: Path
) -> None:
    """Aborted in A2: A1's FRF is published, no identification, no result file."""
    events = _aborted(session, session.chirp_ends_s[1] - 5.0)
    port = _free_port()
    pipeline = PipelineConfig(
        blocks=f"ipc://{ipc_dir}/blocks", replay=f"ipc://{ipc_dir}/replay", results=f"tcp://:{port}"
    )
    daemon = FakeDaemon(pipeline, events)
    daemon.go.set()
    out = ipc_dir / "out"
    options = WorkerOptions(settings=BUDGET, profile_points=0, json_path=out / "r.json")
    try:
        status, messages, worker = _serve(pipeline, options)
    finally:
        daemon.close()
    assert status == 0 and worker.finished == {"s1": "aborted"}
    assert [round(d["amplitude_nm"], 3) for t, d in messages if t == "frf"] == [5.0]
    assert not [d for t, d in messages if t == "result"] and not out.exists()
    last = messages[-1][1]
    assert last["stage"] == "aborted" and last["end"] == {
        "status": "aborted",
        "reason": "speed_window",
    }


def test_a_result_that_cannot_be_written_ends_once_with_status_2(
    session: SimulatedSession, ipc_dir: Path, tmp_path: Path
) -> None:
    """`dtid worker --once --json DIR/id.json` whose folder went away during the test had
    published its result, failed to write it, and exited 0: a script took it for done."""
    events = _aborted(session, session.chirp_ends_s[2] - 8.0)
    gone = tmp_path / "gone" / "id.json"  # `dtid worker` refuses this when read; a folder
    status, messages, worker = _serve_unpaced(events, ipc_dir, gone)  # removed meanwhile
    assert status == 2 and worker.unwritten == {"s1"}
    assert [d for t, d in messages if t == "result"]  # published all the same
    errors = [d["message"] for t, d in messages if t == "progress" and d["stage"] == "error"]
    assert any(str(gone) in message for message in errors), errors


def test_aborted_in_the_validation_chirp_identifies_without_validation(
    session: SimulatedSession, ipc_dir: Path, offline: dict
) -> None:
    events = _aborted(session, session.chirp_ends_s[2] - 8.0)
    status, messages, worker = _serve_unpaced(events, ipc_dir)
    assert status == 0 and worker.finished == {"s1": "aborted"}
    (result,) = [d for t, d in messages if t == "result"]
    assert result["nrmse"]["validation"] == {}
    # the identification held A3 out: the parameters are those of the whole log
    assert result["parameters"] == offline["identify"]["parameters"]
    assert result["nrmse"]["fit"] == offline["identify"]["nrmse"]["fit"]
    assert json.loads((ipc_dir / "r.json").read_text()) == result


def test_validation_chirp_with_lost_frames_leaves_the_identification_unvalidated(
    session: SimulatedSession, ipc_dir: Path, offline: dict
) -> None:
    """0.3 s of frames lost inside A3: its FRF is refused, the result stands without validation."""
    frames = read_log(session.log_path)
    hole = BASE_S + session.chirp_ends_s[2] - 8.0
    kept = [f for f in frames if not hole <= f.timestamp < hole + 0.3]
    events = _events(kept, session.log_path, "s1").events
    status, messages, worker = _serve_unpaced(events, ipc_dir)
    assert status == 0 and worker.finished == {"s1": "completed"}
    errors = [d["message"] for t, d in messages if t == "progress" and d["stage"] == "error"]
    assert any("frames were lost" in message for message in errors), errors
    (result,) = [d for t, d in messages if t == "result"]
    assert result["nrmse"]["validation"] == {}
    assert result["parameters"] == offline["identify"]["parameters"]
    assert json.loads((ipc_dir / "r.json").read_text()) == result


@dataclass
class Replayed:
    """What a worker started after the session ended sent and asked for."""

    requests: list[int]
    """The replay pages it asked for, by first seq."""
    messages: list[tuple[str, dict[str, Any]]]
    """Its published messages: (topic, document)."""


@pytest.fixture(scope="module")
def replayed(session: SimulatedSession) -> Iterator[Replayed]:
    """A worker started after the session ended, fed by the replay alone in pages of 40 events
    (so that the session takes several), diagnosing and planning the follow-up for one vehicle
    around the identified one (its files beside the log); run once for the tests that compare
    it with the commands."""
    folder = Path(tempfile.mkdtemp(prefix="dtidw-", dir="/tmp"))
    pipeline = _pipeline(folder)
    daemon = FakeDaemon(pipeline, session.events, page=40)
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(worker_module, "REPLAY_PAGE", 40)
            daemon.go.set()
            assert daemon.done.wait(10)
            options = WorkerOptions(
                settings=BUDGET,
                profile_points=0,
                diagnose=True,
                mechanisms=SCREENED,
                plan_follow_up=True,
                plan_vehicles=1,
            )
            status, messages, _ = _serve(pipeline, options, timeout_s=600.0)
    finally:
        daemon.close()
    assert status == 0
    yield Replayed(list(daemon.requests), messages)
    shutil.rmtree(folder, ignore_errors=True)


def test_replay_alone_gives_the_live_result(
    session: SimulatedSession, replayed: Replayed, offline: dict
) -> None:
    """A worker started after the session ended gets every event from the replay, page by page,
    identifies as `dtid identify` does on the log, and diagnoses and plans the follow-up beside
    its identification (compared with `dtid diagnose` and `dtid plan --after` by the slow tests
    below)."""
    requests, messages = replayed.requests, replayed.messages
    assert requests[0] == 0
    assert requests[: len(session.events) // 40 + 1] == list(range(0, len(session.events), 40))
    (result,) = [d for t, d in messages if t == "result"]
    assert _without_wall_time(result) == _without_wall_time(offline["identify"])
    folder = session.log_path.parent
    assert json.loads((folder / "identification.json").read_text()) == result
    assert (folder / "identification.png").stat().st_size > 10_000
    # [worker] diagnose: published, and written beside the log
    (diagnosis,) = [dict(d) for t, d in messages if t == "diagnosis"]
    assert diagnosis.pop("session") == "s1"
    written = json.loads((folder / "diagnosis.json").read_text())
    assert written == diagnosis
    validate(written, "diagnosis")
    assert written["adequate"] and written["verdict"]["mechanisms"] == []  # the paper's plant
    # [worker] plan_follow_up: the session's identifying runs counted in, its validation held out
    (plan,) = [dict(d) for t, d in messages if t == "plan"]
    assert plan.pop("session") == "s1"
    assert json.loads((folder / "follow-up.json").read_text()) == plan
    validate(plan, "plan")
    recorded = plan["recorded"]["runs"]
    assert sorted(round(r["amplitude_nm"]) for r in recorded) == [5, 10]
    assert plan["prior"]["c12"] == pytest.approx(result["parameters"]["c12"])
    assert "validation amplitude" in plan["information"]["excluded"]["2"]
    if plan["plan"] is not None:  # the follow-up adds to what the session reached
        for name, value in plan["predicted_precision"].items():
            assert value < plan["recorded"]["predicted_precision"][name], name


@pytest.mark.slow  # dtid diagnose beside the replayed worker (35 s)
def test_the_replayed_workers_diagnosis_is_dtid_diagnoses(
    session: SimulatedSession, replayed: Replayed
) -> None:
    """The worker's diagnosis is what `dtid diagnose --identification` gives on the log."""
    folder = session.log_path.parent
    written = json.loads((folder / "diagnosis.json").read_text())
    identification = folder / "identification.json"
    out = folder / "offline-diagnosis.json"
    command = ["diagnose", str(session.log_path), "--identification", str(identification)]
    assert main([*command, "--mechanisms", *SCREENED, "--json", str(out)]) == 0
    offline_diagnosis = json.loads(out.read_text())
    for key in ("adequate", "mismatch", "test", "hints"):
        assert written[key] == offline_diagnosis[key], key


@pytest.mark.slow  # dtid plan --after beside the replayed worker (35 s)
def test_the_replayed_workers_follow_up_is_dtid_plan_afters(
    session: SimulatedSession, replayed: Replayed
) -> None:
    """The worker's follow-up is `dtid plan --after`'s on the log, planned for a vehicle around
    the identified one too, each parameter within twice the precision reached (close, not
    equal: the log's set-point differs from the stream's in the last digits, and the friction's
    information moves with them)."""
    (plan,) = [d for t, d in replayed.messages if t == "plan"]
    folder = session.log_path.parent
    identification = folder / "identification.json"
    out = folder / "offline-plan.json"
    command = ["plan", "--prior", str(identification), "--after", str(session.log_path)]
    assert main([*command, "--spread-vehicles", "1", "--json", str(out)]) == 0
    offline = json.loads(out.read_text())
    assert plan["spread"]["vehicles"] == offline["spread"]["vehicles"] == 1
    widths = plan["spread"]["percent_by_parameter"]
    for name, reached in plan["recorded"]["predicted_precision"].items():
        if name in widths:  # reached: the worst of the identified and the drawn vehicle
            assert widths[name] <= min(200 * reached, 90.0) + 0.01, name
            assert widths[name] == pytest.approx(
                offline["spread"]["percent_by_parameter"][name], rel=0.15
            )
    assert [u["name"] for u in plan["unmet"]] == [u["name"] for u in offline["unmet"]]
    assert plan["test_time_s"] == pytest.approx(offline["test_time_s"], rel=0.1)


def test_campaign_round_identifies_with_the_earlier_rounds_and_plans_within_the_budget(
    session: SimulatedSession, ipc_dir: Path, offline: dict
) -> None:
    """A round of an adaptive campaign (dtid.acquisition.campaign): the worker identifies it
    together with the earlier round's log, validates on the earlier round's validation chirp
    (this round has none), and publishes the next round's plan within the budget left, with how
    far the parameters moved from what the earlier round identified (its files beside its log:
    here the same recording identified alone, so they agree)."""
    earlier = ipc_dir / "round1.blf"
    shutil.copyfile(session.log_path, earlier)
    (ipc_dir / "r.json").write_text(json.dumps(offline["identify"]))
    precision = {"J_sum": 0.01, "x1": 0.02, "c12": 0.03, "d12": 0.1, "Tc12": 0.5}
    recorded = {
        "recorded": {"predicted_precision": precision},
        "prior": reference_parameters().as_dict(),
    }
    (ipc_dir / "follow-up.json").write_text(json.dumps(recorded))
    events = [{**e, "session": "s2"} for e in session.events]
    events[0]["plan"] = {**events[0]["plan"], "validation_nm": 0.0}
    events[0]["campaign"] = {
        "id": "c",
        "round": 2,
        "logs": [str(earlier)],
        "identify_nm": [5.0, 10.0],
        "spent_s": 72.0,
        "test_time_s": 72.0,
        "max_time_s": 1000.0,
        "targets": {"eps23": 10.0},
    }
    pipeline = _pipeline(ipc_dir)
    daemon = FakeDaemon(pipeline, events)
    daemon.go.set()
    options = WorkerOptions(
        settings=BUDGET, profile_points=0, json_path=ipc_dir / "r.json", plan_vehicles=0
    )
    try:
        status, messages, _ = _serve(pipeline, options, timeout_s=120.0)
    finally:
        daemon.close()
    assert status == 0
    (result,) = [d for t, d in messages if t == "result"]
    assert sorted(result["idle_loop"]) == sorted([str(earlier), str(session.log_path)])
    assert list(result["nrmse"]["validation"]) == [f"{earlier} @ 2 N*m"]  # its own chirp
    (plan,) = [d for t, d in messages if t == "plan"]
    assert plan["session"] == "s2" and plan["limits"]["max_time_s"] == 1000.0 - 144.0
    assert plan["targets_percent"]["eps23"] == 10.0
    assert sorted(round(r["amplitude_nm"]) for r in plan["recorded"]["runs"]) == [5, 5, 10, 10]
    if plan["plan"] is not None:
        assert plan["test_time_s"] <= 1000.0 - 144.0
    validate({k: v for k, v in plan.items() if k != "session"}, "plan")
    assert plan["agreement"]["agree"], plan["agreement"]
    assert sorted(plan["agreement"]["z"]) == sorted(precision)
    assert set(plan["fit"]) == {"adequate", "global_p_value", "bands"}  # a campaign's plan


Reaction = Callable[[str, dict[str, Any], threading.Event], None]


def _worker_thread(
    pipeline: PipelineConfig, options: WorkerOptions, react: Reaction
) -> tuple[Worker, list[tuple[str, dict[str, Any]]], threading.Thread, threading.Event]:
    """A worker serving in a thread until its stop event is set: its messages, each also handed
    to ``react`` with the stop event."""
    worker = Worker(pipeline, options)
    messages: list[tuple[str, dict[str, Any]]] = []
    stop = threading.Event()

    def listen(topic: str, document: dict[str, Any]) -> None:
        messages.append((topic, document))
        react(topic, document, stop)

    worker.listeners.append(listen)
    thread = threading.Thread(target=worker.serve, kwargs={"stop": stop})
    thread.start()
    return worker, messages, thread, stop


def _stop_when_s1_is_done(topic: str, document: dict[str, Any], stop: threading.Event) -> None:
    if document.get("session") == "s1" and document.get("stage") == "done":
        stop.set()


def test_a_new_session_resets_the_worker(
    session: SimulatedSession, ipc_dir: Path, offline: dict
) -> None:
    """Session s0 breaks off without an end; s1 follows and is served from the start."""
    first = [{**event, "session": "s0"} for event in session.events[:40]]
    pipeline = _pipeline(ipc_dir)
    daemon = FakeDaemon(pipeline, first + session.events, bus_per_wall=200.0)
    options = WorkerOptions(
        settings=BUDGET, profile_points=0, json_path=ipc_dir / "r.json", plot=False
    )
    worker, messages, thread, stop = _worker_thread(pipeline, options, _stop_when_s1_is_done)
    daemon.go.set()
    try:
        thread.join(60)
        assert not thread.is_alive()
    finally:
        stop.set()
        daemon.close()
    assert worker.finished == {"s0": "aborted", "s1": "completed"}
    results = [d for t, d in messages if t == "result"]
    assert len(results) == 1
    assert _without_wall_time(results[0]) == _without_wall_time(offline["identify"])


def test_a_session_that_begins_while_the_last_is_diagnosed_is_served_at_once(
    session: SimulatedSession, ipc_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The diagnosis after a result runs beside the loop: while it is held, a new session's
    start is taken and announced, and the held session then ends with its diagnosis and report.
    (Until 2026-12-07 the loop computed the diagnosis and the follow-up plan itself and took no
    event for their minute.)"""
    from dtid.identification.diagnosis import diagnose as diagnose_module

    diagnosing, release = threading.Event(), threading.Event()
    real = diagnose_module.diagnose_report

    def held(report: Any, **kwargs: Any) -> Any:
        diagnosing.set()
        release.wait(60)  # bound: without it the test would wait forever on a blocked loop
        return real(report, **kwargs)

    monkeypatch.setattr(diagnose_module, "diagnose_report", held)
    pipeline = _pipeline(ipc_dir)
    daemon = FakeDaemon(pipeline, session.events, bus_per_wall=200.0)
    options = WorkerOptions(
        settings=BUDGET,
        profile_points=0,
        json_path=ipc_dir / "r.json",
        plot=False,
        diagnose=True,
        mechanisms=SCREENED,
    )

    def react(topic: str, document: dict[str, Any], stop: threading.Event) -> None:
        if document.get("session") == "s2" and document.get("stage") == "acquiring":
            release.set()
        _stop_when_s1_is_done(topic, document, stop)

    worker, messages, thread, stop = _worker_thread(pipeline, options, react)
    daemon.go.set()
    try:
        assert diagnosing.wait(120), "the worker never diagnosed"
        assert daemon.done.wait(30)  # the daemon's thread no longer sends: the PUB is free
        for event in session.events[:40]:
            daemon.pub.send_multipart(encode_event({**event, "session": "s2"}))
        thread.join(120)
        assert not thread.is_alive()
    finally:
        stop.set()
        release.set()
        thread.join(10)
        daemon.close()
    order = [(t, d.get("session"), d.get("stage")) for t, d in messages]
    assert ("progress", "s2", "acquiring") in order, "the new session was never taken"
    announced = order.index(("progress", "s2", "acquiring"))
    diagnosed = order.index(("diagnosis", "s1", None))
    assert announced < diagnosed, "the new session waited for the last one's diagnosis"
    (last,) = [d for t, d in messages if d.get("session") == "s1" and d.get("files")]
    assert last["stage"] == "validated"
    assert any(f.endswith("diagnosis.json") for f in last["files"])
    assert any(f.endswith("report.html") for f in last["files"])
    assert worker.finished == {"s1": "completed"}


class _Held:
    """A stand-in for a long computation of the worker's: it says it began, then waits until
    released (at most 120 s) and fails, for a test that stops the worker meanwhile."""

    def __init__(self) -> None:
        self.began, self.released = threading.Event(), threading.Event()

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        self.began.set()
        self.released.wait(120)
        raise AssertionError("a computation the stop no longer waited for")


def _stopped_while_held(
    session: SimulatedSession, ipc_dir: Path, options: WorkerOptions, held: _Held
) -> list[tuple[str, dict[str, Any]]]:
    """Serve the session; once ``held`` began, stop the worker: its messages, asserting that it
    returned while ``held`` was still held."""
    pipeline = _pipeline(ipc_dir)
    daemon = FakeDaemon(pipeline, session.events, bus_per_wall=200.0)
    _, messages, thread, stop = _worker_thread(pipeline, options, lambda *_: None)
    daemon.go.set()
    try:
        assert held.began.wait(120), "the worker never began the held computation"
        stop.set()
        thread.join(60)  # bound: what the stop waits for is well within it
        assert not thread.is_alive(), "the stop waited for the held computation"
        assert not held.released.is_set()
    finally:
        stop.set()
        held.released.set()
        thread.join(10)
        daemon.close()
    return messages


def test_a_stop_during_the_diagnosis_ends_the_worker_with_the_result_and_a_report(
    session: SimulatedSession, ipc_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A stop (SIGTERM from systemd, which kills after 90 s) does not wait for a diagnosis of
    minutes: after :data:`STOP_WAIT_S` the session's report is written with the result, an
    error says what was interrupted and how to finish it, and the worker returns while the
    diagnosis is still held."""
    from dtid.identification.diagnosis import diagnose as diagnose_module

    held = _Held()
    monkeypatch.setattr(diagnose_module, "diagnose_report", held)
    monkeypatch.setattr(worker_module, "STOP_WAIT_S", 0.5)
    json_path = ipc_dir / "r.json"
    options = WorkerOptions(
        settings=BUDGET, profile_points=0, json_path=json_path, plot=False, diagnose=True
    )
    messages = _stopped_while_held(session, ipc_dir, options, held)
    s1 = [d for t, d in messages if t == "progress" and d.get("session") == "s1"]
    (said,) = [d["message"] for d in s1 if d["stage"] == "error"]
    assert "stopped before the diagnosis" in said
    assert f"dtid diagnose {session.log_path} --identification {json_path}" in said
    (last,) = [d for d in s1 if d.get("files")]
    assert last["stage"] == "validated"
    assert str(json_path) in last["files"] and json.loads(json_path.read_text())["parameters"]
    assert any(f.endswith("report.html") for f in last["files"])
    assert not any(f.endswith("diagnosis.json") for f in last["files"])


def test_a_stop_during_the_identification_says_so_and_how_to_get_the_result(
    session: SimulatedSession, ipc_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A stop does not wait for a search of a minute or more: the session gets an error naming
    what was lost and the command that gives it, and the worker returns at once."""
    held = _Held()
    monkeypatch.setattr(worker_module, "identify_runs", held)
    json_path = ipc_dir / "r.json"
    options = WorkerOptions(settings=BUDGET, profile_points=0, json_path=json_path)
    messages = _stopped_while_held(session, ipc_dir, options, held)
    s1 = [d for t, d in messages if t == "progress" and d.get("session") == "s1"]
    assert s1[-1]["stage"] == "error"
    assert s1[-1]["message"].startswith("the worker was stopped during the identification")
    assert f"`dtid identify {session.log_path}`" in s1[-1]["message"]
    assert not [d for t, d in messages if t == "result"] and not json_path.exists()


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


# --- the command: restart, signals ------------------------------------------------------------


def _worker_process(config: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "dtid.cli", "worker", "--config", str(config), *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_worker_killed_mid_session_catches_up_to_the_same_result(
    session: SimulatedSession, ipc_dir: Path, offline: dict
) -> None:
    pipeline = _pipeline(ipc_dir)
    config = _config_file(ipc_dir, pipeline)
    daemon = FakeDaemon(pipeline, session.events, bus_per_wall=8.0)
    context = zmq.Context()
    listener = context.socket(zmq.SUB)
    listener.setsockopt(zmq.SUBSCRIBE, b"")
    listener.connect(pipeline.results)
    out = ipc_dir / "restart.json"
    args = ["--once", "--json", str(out), "--profile-points", "0", *BUDGET_ARGS]
    first = _worker_process(config, *args)
    second = None
    try:
        daemon.go.set()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # kill it once it has published A1's FRF
            if listener.poll(200) and listener.recv_multipart()[0] == b"frf":
                break
            assert first.poll() is None, first.communicate()
        else:
            pytest.fail("the first worker published no FRF")
        first.send_signal(signal.SIGKILL)
        first.wait(10)
        assert not daemon.done.is_set()  # killed mid-session
        second = _worker_process(config, *args)
        stdout, stderr = second.communicate(timeout=90)
    finally:
        for process in (first, second):
            if process is not None and process.poll() is None:
                process.kill()
        listener.close(linger=0)
        context.term()
        daemon.close()
    assert second.returncode == 0, stderr
    result = json.loads(out.read_text())
    assert _without_wall_time(result) == _without_wall_time(offline["identify"])
    assert "J_sum" in stdout


def test_worker_exits_cleanly_on_sigterm(ipc_dir: Path) -> None:
    pipeline = _pipeline(ipc_dir)
    process = _worker_process(_config_file(ipc_dir, pipeline))
    try:
        deadline = time.monotonic() + 30
        while not (ipc_dir / "results").exists() and time.monotonic() < deadline:
            time.sleep(0.1)  # bound: up and serving
        assert process.poll() is None
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, stderr


def test_worker_command_rejects_a_bad_budget(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["worker", "--once", "--generations", "0"]) == 2
    assert "--generations must be at least 1" in capsys.readouterr().err
    assert main(["worker", "--once", "--plan-vehicles", "-1"]) == 2
    assert "--plan-vehicles must be 0 or more" in capsys.readouterr().err


def test_config_default_endpoints_are_ipc() -> None:
    pipeline = AcquisitionConfig().pipeline
    assert all(getattr(pipeline, n).startswith("ipc://") for n in ("blocks", "replay", "results"))


def test_a_worker_stopped_before_its_one_session_ended_says_so(
    ipc_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """`dtid worker --once` stopped (Ctrl-C, SIGTERM) while it waited exited 0 without a word,
    as if its session had been served; it now exits 130 and says what it served."""

    def stopped(self: Worker, once: bool, stop: threading.Event) -> int:
        signal.getsignal(signal.SIGINT)(signal.SIGINT, None)  # the command's own handler
        assert stop.is_set()
        return 0

    monkeypatch.setattr(Worker, "serve", stopped)
    config = _config_file(ipc_dir, _pipeline(ipc_dir))
    assert main(["worker", "--config", str(config), "--once"]) == 130
    assert "worker stopped (sessions served: none)" in capsys.readouterr().err
    assert main(["worker", "--config", str(config)]) == 0  # a service stopped: nothing lost
