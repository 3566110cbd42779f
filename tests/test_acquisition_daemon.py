"""The acquisition daemon end to end on python-can's in-process virtual bus, with a fake ECU.

The fake ECU (:class:`FakeEcu`) sends the engine's speed, torque-request and mean-torque frames
through the product DBC at the crank-event rate of 1000 rpm, in bus time sped up like the daemon,
and keeps every frame it sent and every frame it received from the daemon. The daemon runs in the
test's own thread (its signal handlers need the main thread) or as ``python -m dtid.cli acquire``
in a subprocess that also runs a fake ECU (SIGTERM and SIGKILL cases).
"""

from __future__ import annotations

import errno
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path

import can
import numpy as np
import pytest
import zmq
from can.interfaces.virtual import channels as virtual_channels

import dtid.acquisition.daemon as daemon_module
from dtid.acquisition.config import (
    AcquisitionConfig,
    BusConfig,
    OutputConfig,
    PipelineConfig,
    SafetyConfig,
    TestPlan,
)
from dtid.acquisition.daemon import EXIT_ABORTED, EXIT_COMPLETED, Daemon
from dtid.acquisition.health import HealthCounts
from dtid.acquisition.logfile import read_log, read_log_checked
from dtid.acquisition.metadata import read_metadata
from dtid.acquisition.recorder import Recorder
from dtid.acquisition.sequence import ZERO_REQUESTS, ToolFrames
from dtid.acquisition.stream import REPLAY_PAGE, decode_event
from dtid.dbc.checksum import verify_checksum
from dtid.dbc.loader import load_interface
from dtid.dbc.tool_state import TOOL_ABORT
from dtid.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
INTERFACE = load_interface()
SPEED_ID, _ = INTERFACE.frame_key("speed")
REQUEST_ID, _ = INTERFACE.frame_key("test_torque")
HEARTBEAT_ID, _ = INTERFACE.frame_key("heartbeat")
ECU_IDS = {INTERFACE.frame_key(role)[0] for role in ("speed", "mean_torque", "torque_request")}
CRANK_EVENT_S = 0.015
"""Time between two speed frames at 1000 rpm (pi/2 of crank angle), s."""
TIME_FACTOR = 2.0
VEHICLE_TIMEOUT_S = 1.0
"""Bus time (0.5 s wall): long enough that a busy machine never stalls the fake ECU that long."""
SHORT_TEST = TestPlan(
    amplitudes_nm=(5.0, 10.0), validation_nm=2.0, duration_s=1.0, settle_s=0.3, pause_s=0.3
)


class FakeEcu(threading.Thread):
    """An engine ECU on a virtual bus: speed and torque frames at every crank event.

    Parameters
    ----------
    channel
        Virtual bus channel.
    speed
        Speed in rpm as a function of the ECU's bus time (s since it started) and of itself
        (its ``received`` frames tell what the tool asked for).
    silent_after_s
        Bus time after which it stops sending, s (a vehicle that stops answering).
    order
        Maps the list of crank-event indices about to be sent to what is actually sent (to lose,
        repeat or swap frames).
    """

    def __init__(
        self,
        channel: str,
        speed: Callable[[float, FakeEcu], float] = lambda tau, ecu: 1000.0,
        silent_after_s: float = float("inf"),
        order: Callable[[int], list[int]] = lambda index: [index],
        time_factor: float = TIME_FACTOR,
    ) -> None:
        super().__init__(daemon=True)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.channel = channel
        self.speed = speed
        self.silent_after_s = silent_after_s
        self.order = order
        self.time_factor = time_factor
        self.sent: list[can.Message] = []
        self.received: list[can.Message] = []
        self.stop = threading.Event()

    def enabled_requests(self) -> int:
        """Requests received so far with TestEnable = 1."""
        return sum(1 for f in self.received if f.arbitration_id == REQUEST_ID and f.data[3] & 1)

    def run(self) -> None:
        while len(virtual_channels.get(self.channel, ())) < 2 and not self.stop.is_set():
            time.sleep(0.001)  # wait for the daemon's bus, so that it sees every frame
        start = time.time()
        index = 0
        while not self.stop.is_set():
            deadline = start + index * CRANK_EVENT_S / self.time_factor
            time.sleep(max(0.0, deadline - time.time()))
            tau = (time.time() - start) * self.time_factor
            while (frame := self.bus.recv(0)) is not None:
                self.received.append(frame)
            if tau <= self.silent_after_s:
                rpm = self.speed(tau, self)
                for event in self.order(index):
                    self._send(INTERFACE.encode("speed", rpm, 0.0, counter=event % 65536))
                    self._send(INTERFACE.encode("torque_request", 20.0, 0.0, counter=event % 256))
                    if event % 2 == 0:
                        stroke = event // 2
                        self._send(
                            INTERFACE.encode(
                                "mean_torque", 20.0, 0.0, counter=stroke % 256, cylinder=stroke % 4
                            )
                        )
            index += 1
        self.bus.shutdown()

    def _send(self, frame: can.Message) -> None:
        self.bus.send(frame)
        self.sent.append(frame)


class Subscriber(threading.Thread):
    """Collect the daemon's PUB events; after the end event, ask the replay for everything."""

    def __init__(self, pipeline: PipelineConfig) -> None:
        super().__init__(daemon=True)
        self.pipeline = pipeline
        self.context = zmq.Context()
        self.sub = self.context.socket(zmq.SUB)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.sub.connect(pipeline.blocks)
        self.events: list[dict] = []
        self.replayed: list[dict] | None = None
        self.latencies: list[float] = []

    def run(self) -> None:
        while self.sub.poll(10_000):
            frames = self.sub.recv_multipart()
            event = decode_event(frames)
            assert frames[0] == event["kind"].encode()
            self.events.append(event)
            if event["kind"] == "end":
                break
        request = self.context.socket(zmq.REQ)
        request.connect(self.pipeline.replay)
        replayed: list[dict] = []
        while True:  # page by page, as the worker does
            request.send(json.dumps({"from_seq": len(replayed)}).encode())
            if not request.poll(5000):
                break
            page = json.loads(request.recv())
            replayed += page
            if len(page) < REPLAY_PAGE:
                self.replayed = replayed
                break
        request.close(0)
        self.sub.close(0)
        self.context.term()


IPC_DIRECTORIES: list[Path] = []
"""Folders of the ipc endpoints made by :func:`make_config`, removed after each test."""


@pytest.fixture(autouse=True)
def _remove_ipc_directories() -> Iterator[None]:
    yield
    while IPC_DIRECTORIES:
        shutil.rmtree(IPC_DIRECTORIES.pop(), ignore_errors=True)


def make_config(tmp_path: Path, **sections: object) -> AcquisitionConfig:
    """A short test on a fresh virtual channel, output under ``tmp_path``, endpoints in a short
    folder of /tmp (a Unix socket path has at most 107 bytes)."""
    ipc = Path(tempfile.mkdtemp(prefix="dtid-test-", dir="/tmp"))
    IPC_DIRECTORIES.append(ipc)
    config = AcquisitionConfig(
        bus=BusConfig(
            interface="virtual", channel=f"dtid-{uuid.uuid4().hex}", time_factor=TIME_FACTOR
        ),
        test=SHORT_TEST,
        safety=SafetyConfig(vehicle_timeout_s=VEHICLE_TIMEOUT_S),
        output=OutputConfig(directory=tmp_path / "runs", flush_period_s=0.1),
        pipeline=PipelineConfig(blocks=f"ipc://{ipc}/blocks", replay=f"ipc://{ipc}/replay"),
    )
    for section, changes in sections.items():
        config = config.with_changes(section, **changes)
    return config


def run_daemon(
    config: AcquisitionConfig,
    ecu: FakeEcu,
    linger_s: float = 0.0,
    report: Callable[[str], None] = lambda line: None,
):
    ecu.start()
    try:
        result = Daemon(config, linger_s=linger_s, wait_s=5.0, report=report).run()
    finally:
        ecu.stop.set()
        ecu.join()
    return result


def by_id(frames: list[can.Message], arbitration_id: int) -> list[can.Message]:
    return [f for f in frames if f.arbitration_id == arbitration_id]


@pytest.mark.parametrize("log_format", ["blf", "mf4"])
def test_completed_test_records_every_frame_and_streams_it(tmp_path: Path, log_format: str) -> None:
    """Also for an .mf4 log (written from its BLF journal at the end), with its metadata."""
    config = make_config(
        tmp_path, output={"log_format": log_format, "vehicle": "WVWZZZ1JZ3W000001"}
    )
    ecu = FakeEcu(config.bus.channel)
    subscriber = Subscriber(config.pipeline)
    subscriber.start()
    result = run_daemon(config, ecu, linger_s=1.0)
    subscriber.join(10)
    assert result.status == "completed" and result.reason is None
    assert result.exit_status == EXIT_COMPLETED

    log = read_log(result.log_path)
    received = [f for f in log if f.is_rx]
    sent = [f for f in log if not f.is_rx]
    # every ECU frame the daemon could have seen is in the log, in order, bit for bit
    ecu_frames = [(f.arbitration_id, bytes(f.data)) for f in ecu.sent]
    logged = [(f.arbitration_id, bytes(f.data)) for f in received]
    assert logged == ecu_frames[: len(logged)]
    plan = config.test
    assert subscriber.replayed is not None
    t_start = next(e["t_s"] for e in subscriber.replayed if e["kind"] == "phase")
    in_test = [t_start <= f.timestamp < t_start + plan.end_s for f in by_id(received, SPEED_ID)]
    assert sum(in_test) >= round(plan.end_s / CRANK_EVENT_S) - 3  # the whole test is there
    assert {f.arbitration_id for f in sent} == {REQUEST_ID, HEARTBEAT_ID}
    # the ECU received exactly the frames the log holds as sent
    assert [(f.arbitration_id, bytes(f.data)) for f in ecu.received] == [
        (f.arbitration_id, bytes(f.data)) for f in sent
    ]

    # the requests of the simulated test, frame for frame, with counter, checksum and enable
    requests = by_id(sent, REQUEST_ID)
    tool = ToolFrames(INTERFACE, plan)
    assert len(requests) == len(tool.request_times)
    decoded = INTERFACE.decode(requests)["test_torque"]
    assert decoded.extra["counter"].tolist() == [i % 16 for i in range(len(requests))]
    assert all(verify_checksum(f.data) for f in requests)
    assert decoded.extra["enable"].tolist() == tool.request_enable.tolist()
    assert int(tool.request_enable.sum()) > 0
    np.testing.assert_allclose(decoded.values, tool.request_values, atol=0.005)
    beats = INTERFACE.decode(by_id(sent, HEARTBEAT_ID))["heartbeat"]
    assert beats.values.tolist() == tool.heartbeat_states.tolist()

    events = subscriber.replayed
    assert events is not None
    assert [e["seq"] for e in events] == list(range(len(events)))
    assert events[0]["kind"] == "session" and events[-1]["kind"] == "end"
    assert events[0]["log_path"] == str(result.log_path)
    assert events[0]["log_start_s"] == pytest.approx(log[0].timestamp, abs=1e-6)
    assert events[0]["time_factor"] == TIME_FACTOR
    assert events[-1]["status"] == "completed"
    # what the PUB delivered is exactly what the replay returns
    received_events = subscriber.events
    first = received_events[0]["seq"]
    assert received_events == events[first:]
    # samples carry every recorded frame once, with the log's timestamps
    samples = [e for e in events if e["kind"] == "samples"]
    assert sum(e["frames"] for e in samples) == len(log)
    speed_t = [t for e in samples for t in e["roles"].get("speed", {}).get("t", [])]
    log_speed_t = [f.timestamp for f in log if f.arbitration_id == SPEED_ID]
    # BLF keeps ns; MF4 64-bit offsets from a start time, whose float sum keeps 0.24 us at 2026
    np.testing.assert_allclose(
        speed_t, log_speed_t, rtol=0, atol=2e-9 if log_format == "blf" else 5e-7
    )
    metadata = read_metadata(result.log_path)
    assert metadata is not None and metadata["source"] == "dtid acquire"
    assert metadata["vehicle"] == "WVWZZZ1JZ3W000001"
    assert metadata["outcome"]["status"] == "completed" and metadata["outcome"]["reason"] is None
    assert metadata["integrity"] == {"frames": len(log), "lost": 0, "closed": True, "failure": None}
    assert metadata["plan"] == config.test.as_dict()
    assert sorted(p.name for p in result.session_dir.iterdir()) == sorted(
        [result.log_path.name] + ([f"{result.log_path.name}.json"] if log_format == "blf" else [])
    )
    phases = [(e["phase"], e["chirp"]) for e in events if e["kind"] == "phase"]
    assert phases == [
        ("settle", None),
        ("chirp", 0),
        ("pause", None),
        ("chirp", 1),
        ("pause", None),
        ("chirp", 2),
        ("pause", None),
        ("done", None),
    ]
    health = [e for e in events if e["kind"] == "health"][-1]
    assert health["frames"] == len(log)
    assert (health["lost"], health["duplicated"], health["out_of_order"]) == (0, 0, 0)
    assert health["foreign_tx"] == 0 and health["bad_frames"] == 0


def assert_zero_requests_end_the_log(log: list[can.Message]) -> None:
    """After the abort: the abort heartbeat, then the zero requests, counters still in step."""
    sent = [f for f in log if not f.is_rx]
    requests = by_id(sent, REQUEST_ID)
    decoded = INTERFACE.decode(requests)["test_torque"]
    assert decoded.extra["counter"].tolist() == [i % 16 for i in range(len(requests))]
    assert all(verify_checksum(f.data) for f in requests)
    tail = slice(len(requests) - ZERO_REQUESTS, None)
    assert decoded.extra["enable"][tail].tolist() == [0] * ZERO_REQUESTS
    assert decoded.values[tail].tolist() == [0.0] * ZERO_REQUESTS
    beats = INTERFACE.decode(by_id(sent, HEARTBEAT_ID))["heartbeat"]
    assert beats.values[-1] == TOOL_ABORT and TOOL_ABORT not in beats.values[:-1]
    assert sent[-1].arbitration_id == REQUEST_ID  # nothing after the zero requests


def test_speed_leaving_the_window_aborts_with_zero_requests(tmp_path: Path) -> None:
    config = make_config(tmp_path, safety={"speed_window_rpm": 100.0})

    def speed(tau: float, ecu: FakeEcu) -> float:
        return 1250.0 if ecu.enabled_requests() >= 20 else 1000.0

    ecu = FakeEcu(config.bus.channel, speed=speed)
    result = run_daemon(config, ecu)
    assert (result.status, result.reason) == ("aborted", "speed_window")
    assert result.exit_status == EXIT_ABORTED
    log = read_log(result.log_path)
    assert_zero_requests_end_the_log(log)
    # the vehicle got the zero requests too
    last = INTERFACE.decode(by_id(ecu.received, REQUEST_ID))["test_torque"]
    assert last.extra["enable"][-ZERO_REQUESTS:].tolist() == [0] * ZERO_REQUESTS


def test_speed_within_the_window_does_not_abort(tmp_path: Path) -> None:
    config = make_config(tmp_path, safety={"speed_window_rpm": 100.0})

    def speed(tau: float, ecu: FakeEcu) -> float:
        return 1080.0 if ecu.enabled_requests() >= 20 else 1000.0

    result = run_daemon(config, FakeEcu(config.bus.channel, speed=speed))
    assert (result.status, result.reason) == ("completed", None)


def test_vehicle_that_stops_answering_aborts(tmp_path: Path) -> None:
    config = make_config(tmp_path)
    ecu = FakeEcu(config.bus.channel, silent_after_s=1.0)
    result = run_daemon(config, ecu)
    assert (result.status, result.reason) == ("aborted", "vehicle_timeout")
    assert_zero_requests_end_the_log(read_log(result.log_path))


def test_no_vehicle_at_all_aborts_after_the_wait(tmp_path: Path) -> None:
    config = make_config(tmp_path)
    result = Daemon(config, linger_s=0.0, wait_s=0.2).run()
    assert (result.status, result.reason) == ("aborted", "vehicle_timeout")
    log = read_log(result.log_path)  # the zero requests are the whole log
    assert [f.arbitration_id for f in log] == [HEARTBEAT_ID] + [REQUEST_ID] * ZERO_REQUESTS


def test_foreign_frame_on_the_tool_id_aborts(tmp_path: Path) -> None:
    config = make_config(tmp_path)
    intruder = can.Bus(interface="virtual", channel=config.bus.channel)
    foreign = INTERFACE.encode("test_torque", 7.0, 0.0, enable=1, counter=3)

    def speed(tau: float, ecu: FakeEcu) -> float:
        if tau > 0.5 and not ecu.foreign_sent:
            intruder.send(foreign)
            ecu.foreign_sent = True
        return 1000.0

    ecu = FakeEcu(config.bus.channel, speed=speed)
    ecu.foreign_sent = False
    try:
        result = run_daemon(config, ecu)
    finally:
        intruder.shutdown()
    assert (result.status, result.reason) == ("aborted", "foreign_tx")
    log = read_log(result.log_path)
    foreign_logged = [f for f in log if f.arbitration_id == REQUEST_ID and f.is_rx]
    assert [bytes(f.data) for f in foreign_logged] == [bytes(foreign.data)]
    assert_zero_requests_end_the_log(log)


def test_counter_faults_are_counted(tmp_path: Path) -> None:
    config = make_config(tmp_path)
    faults = {30: [], 40: [40, 40], 50: [51], 51: [50]}  # lost, duplicated, swapped
    ecu = FakeEcu(config.bus.channel, order=lambda index: faults.get(index, [index]))
    subscriber = Subscriber(config.pipeline)
    subscriber.start()
    lines: list[str] = []
    result = run_daemon(config, ecu, linger_s=1.0, report=lines.append)
    subscriber.join(10)
    assert result.status == "completed"
    assert subscriber.replayed is not None
    health = [e for e in subscriber.replayed if e["kind"] == "health"][-1]
    # speed and torque request: one each lost, duplicated, out of order; the mean torque (every
    # other event) loses stroke 15, repeats stroke 20 and gets stroke 25 in order
    assert (health["lost"], health["duplicated"], health["out_of_order"]) == (3, 3, 2)
    assert health["bad_frames"] == 0
    # the operator sees the same counts at the end of the test
    reported = [line for line in lines if line.startswith("health: ")]
    assert len(reported) == 1
    counts = json.loads(reported[0].removeprefix("health: "))
    assert counts == {k: v for k, v in health.items() if k in counts}
    assert set(counts) == set(asdict(HealthCounts()))


def test_bad_frames_are_counted(tmp_path: Path) -> None:
    config = make_config(tmp_path)
    noise = can.Bus(interface="virtual", channel=config.bus.channel)

    def speed(tau: float, ecu: FakeEcu) -> float:
        if tau > 0.5 and not ecu.noise_sent:
            noise.send(can.Message(arbitration_id=SPEED_ID, is_extended_id=False, data=b"\x01"))
            ecu.noise_sent = True
        return 1000.0

    ecu = FakeEcu(config.bus.channel, speed=speed)
    ecu.noise_sent = False
    subscriber = Subscriber(config.pipeline)
    subscriber.start()
    try:
        result = run_daemon(config, ecu, linger_s=1.0)
    finally:
        noise.shutdown()
    subscriber.join(10)
    assert result.status == "completed"
    assert subscriber.replayed is not None
    health = [e for e in subscriber.replayed if e["kind"] == "health"][-1]
    assert health["bad_frames"] == 1
    assert (health["lost"], health["duplicated"], health["out_of_order"]) == (0, 0, 0)


SUBPROCESS = """
import sys
sys.path[:0] = [{root!r}, {tests!r}]
from test_acquisition_daemon import FakeEcu
from dtid.cli import main
ecu = FakeEcu({channel!r})
ecu.start()
status = main(["acquire", "--config", {config!r}, "--linger", "0"])
ecu.stop.set()
ecu.join()
sys.exit(status)
"""


def start_subprocess_daemon(tmp_path: Path) -> tuple[subprocess.Popen[str], str]:
    """``dtid acquire`` (the CLI's main) in a subprocess with a fake ECU on its virtual bus."""
    config = make_config(tmp_path)
    path = tmp_path / "dtid.toml"
    path.write_text(
        "[bus]\n"
        f'interface = "virtual"\nchannel = "{config.bus.channel}"\ntime_factor = {TIME_FACTOR}\n'
        "[test]\n"
        "amplitudes_nm = [5.0, 10.0]\nduration_s = 2.0\nsettle_s = 0.3\npause_s = 0.3\n"
        "[output]\n"
        f'directory = "{tmp_path / "runs"}"\nflush_period_s = 0.1\n'
        f"[safety]\nvehicle_timeout_s = {VEHICLE_TIMEOUT_S}\n"
        "[pipeline]\n"
        f'blocks = "{config.pipeline.blocks}"\nreplay = "{config.pipeline.replay}"\n'
    )
    script = SUBPROCESS.format(
        root=str(ROOT), tests=str(ROOT / "tests"), channel=config.bus.channel, config=str(path)
    )
    process = subprocess.Popen(
        [sys.executable, "-c", script],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines = []
    while True:
        ready, _, _ = select.select([process.stdout], [], [], 30)
        assert ready, f"no output from the daemon: {lines}"
        line = process.stdout.readline()
        assert line, f"daemon ended early: {lines} {process.stderr.read()}"
        lines.append(line)
        if "chirp 1 of" in line:
            break
    log_line = next(line for line in lines if line.startswith("log: "))
    return process, log_line[len("log: ") :].strip()


def test_sigterm_aborts_with_zero_requests(tmp_path: Path) -> None:
    process, log_path = start_subprocess_daemon(tmp_path)
    # the phase line comes from the daemon's loop, the requests from its sender thread: on a
    # busy host the first enabled request followed the line by more than the signal did (CI of
    # 2026-12-04); 0.3 s is 0.6 s of bus time into the 2 s chirp
    time.sleep(0.3)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=30)
    assert process.returncode == EXIT_ABORTED, err
    assert "end: aborted (signal" in out
    log = read_log(log_path)
    enabled = INTERFACE.decode(by_id(log, REQUEST_ID))["test_torque"].extra["enable"]
    assert enabled.max() == 1  # the signal came during the first chirp
    assert_zero_requests_end_the_log(log)


def test_log_survives_sigkill(tmp_path: Path) -> None:
    started = time.time()
    process, log_path = start_subprocess_daemon(tmp_path)
    time.sleep(0.5)  # several flush periods into the first chirp
    process.kill()
    process.communicate(timeout=30)
    assert process.returncode == -signal.SIGKILL
    log = read_log(log_path)
    assert log[0].timestamp >= started  # absolute times survive (the BLF header has the start)
    requests = INTERFACE.decode(by_id(log, REQUEST_ID))["test_torque"]
    assert requests.extra["enable"].max() == 1
    speed = INTERFACE.decode(log)["speed"]
    counters = speed.extra["counter"]
    assert counters.tolist() == list(range(counters[0], counters[0] + len(counters)))


def test_endpoint_in_use_is_refused_before_any_session(tmp_path: Path) -> None:
    context = zmq.Context.instance()
    blocker = context.socket(zmq.PUB)
    blocker.bind("tcp://127.0.0.1:*")
    endpoint = blocker.getsockopt_string(zmq.LAST_ENDPOINT)
    config = make_config(tmp_path, pipeline={"blocks": endpoint})
    try:
        with pytest.raises(ConfigError, match="cannot bind"):
            Daemon(config, linger_s=0.0, wait_s=0.2).run()
    finally:
        blocker.close(0)
    assert list((tmp_path / "runs").iterdir()) == []


class _FullDisk:
    """A log file whose disk fills up: writes fail with ENOSPC after ``allowed`` of them."""

    def __init__(self, file: object, allowed: int) -> None:
        self._file, self._allowed = file, allowed

    def write(self, data: bytes) -> int:
        if self._allowed <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._allowed -= 1
        return self._file.write(data)

    def __getattr__(self, name: str) -> object:
        return getattr(self._file, name)


def test_a_full_disk_stops_the_test_with_zero_torque_and_keeps_the_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    class FillingRecorder(Recorder):
        def __init__(self, *args: object, **kwargs: object) -> None:
            super().__init__(*args, **kwargs)
            self._writer.file = _FullDisk(self._writer.file, allowed=20)

    monkeypatch.setattr(daemon_module, "Recorder", FillingRecorder)
    config = make_config(tmp_path)
    ecu = FakeEcu(config.bus.channel)
    lines: list[str] = []
    result = run_daemon(config, ecu, report=lines.append)
    assert (result.status, result.reason) == ("aborted", "log_write")
    assert result.exit_status == EXIT_ABORTED
    assert any("No space left on device" in line and "frames kept" in line for line in lines)
    # the vehicle got the zero requests
    last = INTERFACE.decode(by_id(ecu.received, REQUEST_ID))["test_torque"]
    assert last.extra["enable"][-ZERO_REQUESTS:].tolist() == [0] * ZERO_REQUESTS
    # what was written before is readable
    frames, integrity = read_log_checked(result.log_path)
    assert len(frames) > 0 and integrity.cut is not None


def test_a_removed_output_directory_stops_the_test_the_same_way(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    class VanishingRecorder(Recorder):
        def __init__(self, *args: object, **kwargs: object) -> None:
            super().__init__(*args, **kwargs)
            self._writer.file = _FullDisk(self._writer.file, allowed=6)
            self._writer.file.write = self._vanish  # type: ignore[method-assign]

        def _vanish(self, data: bytes) -> int:
            raise OSError(errno.ENOENT, "the output directory was removed")

    monkeypatch.setattr(daemon_module, "Recorder", VanishingRecorder)
    config = make_config(tmp_path)
    ecu = FakeEcu(config.bus.channel)
    result = run_daemon(config, ecu)
    assert (result.status, result.reason) == ("aborted", "log_write")
    last = INTERFACE.decode(by_id(ecu.received, REQUEST_ID))["test_torque"]
    assert last.extra["enable"][-ZERO_REQUESTS:].tolist() == [0] * ZERO_REQUESTS


@pytest.mark.parametrize("vehicle_factor", [TIME_FACTOR, 3 * TIME_FACTOR])
def test_a_speed_that_is_not_crank_synchronous_is_named_after_the_settle_phase(
    tmp_path: Path, vehicle_factor: float
) -> None:
    """A virtual vehicle run three times as fast as the daemon's [bus] time_factor: its speed
    frames came 12 times a revolution in the daemon's bus time; the test ran to "completed"
    and only `dtid identify` said, minutes later, that the recording could not be read. The
    daemon now says so when the settle phase ends (a warning: the frames are recorded all the
    same, and a signal map naming the right message may still read them)."""
    config = make_config(tmp_path, test={"settle_s": 2.0})  # 133 speed samples at 1000 rpm
    lines: list[str] = []
    ecu = FakeEcu(config.bus.channel, time_factor=vehicle_factor)
    run_daemon(config, ecu, report=lines.append)
    warnings = [line for line in lines if line.startswith("warning: the engine speed came")]
    if vehicle_factor == TIME_FACTOR:
        assert warnings == []
    else:
        (warning,) = warnings
        per_revolution = float(warning.split()[5])
        assert per_revolution == pytest.approx(12.0, rel=0.3), warning
        assert "[bus] time_factor (2)" in warning


def test_a_session_folder_removed_during_the_test_stops_it_and_is_written_back(
    tmp_path: Path,
) -> None:
    """The session folder removed at the first chirp (an operator's rm -rf): the daemon wrote on
    into a file without a name, said "completed" and left nothing on disk. Now the test stops
    (log_write, zero requests) and the log is back in its place with what it held."""
    config = make_config(tmp_path)
    ecu = FakeEcu(config.bus.channel)
    log: list[Path] = []

    def remove_at_the_first_chirp(line: str) -> None:
        if line.startswith("log: ") and not log:
            log.append(Path(line.removeprefix("log: ")))
        elif "chirp 1 of" in line:
            shutil.rmtree(log[0].parent)

    result = run_daemon(config, ecu, report=remove_at_the_first_chirp)
    assert (result.status, result.reason) == ("aborted", "log_write")
    last = INTERFACE.decode(by_id(ecu.received, REQUEST_ID))["test_torque"]
    assert last.extra["enable"][-ZERO_REQUESTS:].tolist() == [0] * ZERO_REQUESTS
    frames, _ = read_log_checked(result.log_path)
    metadata = read_metadata(result.log_path)
    assert metadata is not None and metadata["integrity"]["frames"] == len(frames) > 0
    assert "was removed while the test recorded it" in metadata["integrity"]["failure"]


@pytest.mark.parametrize(
    ("where", "error"),
    [
        ("send", can.CanOperationError("Transmit buffer full [Error Code 105]")),
        ("send", can.CanOperationError("bus-off")),
        ("recv", can.CanOperationError("Network is down [Error Code 100]")),
    ],
)
def test_a_bus_error_aborts_with_zero_requests_and_says_what_the_bus_reported(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str, error: can.CanError
) -> None:
    """A bus double raising python-can's errors mid-test: on sending, after 60 frames (for a
    full buffer, once; for bus-off, from then on but for the zero requests it lets through);
    on receiving, after 200 frames."""
    real_open = daemon_module.open_bus
    sends = {"n": 0, "refused": 0}

    def open_faulty(config: object) -> can.BusABC:
        bus = real_open(config)
        send, recv = bus.send, bus.recv
        received = {"n": 0}

        def faulty_send(frame: can.Message, timeout: float | None = None) -> None:
            sends["n"] += 1
            if where == "send" and sends["n"] == 60:
                sends["refused"] += 1
                raise error
            send(frame, timeout)

        def faulty_recv(timeout: float | None = None) -> can.Message | None:
            frame = recv(timeout)
            received["n"] += frame is not None
            if where == "recv" and received["n"] > 200:
                raise error
            return frame

        bus.send, bus.recv = faulty_send, faulty_recv
        return bus

    monkeypatch.setattr(daemon_module, "open_bus", open_faulty)
    config = make_config(tmp_path)
    ecu = FakeEcu(config.bus.channel)
    lines: list[str] = []
    result = run_daemon(config, ecu, report=lines.append)
    assert (result.status, result.reason) == ("aborted", "bus_error")
    assert any(line.startswith("bus: error while") and str(error) in line for line in lines)
    last = INTERFACE.decode(by_id(ecu.received, REQUEST_ID))["test_torque"]
    assert last.extra["enable"][-ZERO_REQUESTS:].tolist() == [0] * ZERO_REQUESTS
    assert read_log_checked(result.log_path)[0]
