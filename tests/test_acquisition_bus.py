"""Opening the bus (guard, errors, receive buffer), the bus clock, the event server, the CLI."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import zmq

from dtid.acquisition import netns
from dtid.acquisition.bus import SETUP_HINT, _size_receive_buffer, open_bus
from dtid.acquisition.clock import BusClock
from dtid.acquisition.config import BusConfig, PipelineConfig
from dtid.acquisition.server import EventServer
from dtid.acquisition.stream import REPLAY_PAGE
from dtid.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def test_multicast_outside_a_loopback_namespace_is_refused(monkeypatch) -> None:
    monkeypatch.setattr(netns, "network_interfaces", lambda: ["lo", "eth0"])
    with pytest.raises(ConfigError, match="eth0"):
        open_bus(BusConfig(interface="udp_multicast", channel="239.74.163.2"))


@pytest.mark.parametrize("channel", ["ff15::1", "10.0.0.1", "not-an-address"])
def test_multicast_needs_an_ipv4_group(monkeypatch, channel: str) -> None:
    monkeypatch.setattr(netns, "network_interfaces", lambda: ["lo"])
    with pytest.raises(ConfigError, match="IPv4 multicast group"):
        open_bus(BusConfig(interface="udp_multicast", channel=channel))


def test_unknown_interface_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="not available"):
        open_bus(BusConfig(interface="no-such-interface", channel="x"))


def test_absent_socketcan_channel_names_the_setup_script() -> None:
    with pytest.raises(ConfigError, match=SETUP_HINT.replace(".", r"\.")):
        open_bus(BusConfig(interface="socketcan", channel=f"dtid{uuid.uuid4().hex[:8]}"))


def test_virtual_bus_opens() -> None:
    bus = open_bus(BusConfig(interface="virtual", channel=f"dtid-{uuid.uuid4().hex}"))
    bus.shutdown()


def test_receive_buffer_is_sized_on_the_private_socket() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        fake = SimpleNamespace(_multicast=SimpleNamespace(_socket=sock))
        size = 1 << 20
        granted = _size_receive_buffer(fake, size)
        assert granted == sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        if os.geteuid() == 0:  # SO_RCVBUFFORCE passes the kernel's cap
            assert granted >= size


def test_bus_without_a_reachable_socket_still_opens() -> None:
    assert _size_receive_buffer(SimpleNamespace(), 1 << 20) is None


def test_clock_factor_one_keeps_timestamps_bit_for_bit() -> None:
    clock = BusClock(1.0, start_wall_s=1_700_000_000.123)
    wall = 1_700_000_001.987654321
    assert clock.to_bus(wall) == wall and clock.to_wall(wall) == wall


def test_clock_stretches_from_the_start() -> None:
    clock = BusClock(20.0, start_wall_s=1_700_000_000.0)
    assert clock.to_bus(1_700_000_000.0) == 1_700_000_000.0
    assert clock.to_bus(1_700_000_000.5) == pytest.approx(1_700_000_010.0, abs=1e-6)
    assert clock.to_wall(clock.to_bus(1_700_000_003.25)) == pytest.approx(1_700_000_003.25)


@pytest.mark.parametrize("factor", [0.0, -1.0, float("nan"), 21.0, 1e9])
def test_clock_refuses_a_factor_that_is_not_positive_or_beyond_keeping_pace(factor: float) -> None:
    with pytest.raises(ValueError, match=r"must lie in \(0, 20\]"):
        BusClock(factor)
    assert BusClock(20.0).time_factor == 20.0


@pytest.fixture
def pipeline() -> Iterator[PipelineConfig]:
    """Endpoints in a folder that does not exist yet (the server makes it)."""
    top = Path(tempfile.mkdtemp(prefix="dtid-test-", dir="/tmp"))
    ipc = top / "nested"
    yield PipelineConfig(blocks=f"ipc://{ipc}/blocks", replay=f"ipc://{ipc}/replay")
    shutil.rmtree(top, ignore_errors=True)


def replay(endpoint: str, request: bytes) -> object:
    context = zmq.Context.instance()
    socket_ = context.socket(zmq.REQ)
    socket_.connect(endpoint)
    try:
        socket_.send(request)
        assert socket_.poll(5000)
        return json.loads(socket_.recv())
    finally:
        socket_.close(0)


def test_events_are_numbered_kept_and_replayed(pipeline: PipelineConfig) -> None:
    server = EventServer(pipeline, "session-1")
    try:
        sent = [
            server.publish("session", {"log_path": "x.blf"}),
            server.publish("phase", {"phase": "settle"}),
            server.publish("end", {"status": "completed"}),
        ]
        assert [e["seq"] for e in sent] == [0, 1, 2]
        assert all(e["session"] == "session-1" for e in sent)
        assert replay(pipeline.replay, b'{"from_seq": 0}') == sent
        assert replay(pipeline.replay, b'{"from_seq": 2}') == sent[2:]
        assert replay(pipeline.replay, b'{"from_seq": 7}') == []
        assert "error" in replay(pipeline.replay, b'{"from": 1}')
        assert "error" in replay(pipeline.replay, b"not json")
    finally:
        server.close()


def test_the_replay_answers_in_pages(pipeline: PipelineConfig) -> None:
    """A long session is never one message: pages of REPLAY_PAGE events, the last one short."""
    server = EventServer(pipeline, "long")
    try:
        total = 2 * REPLAY_PAGE + 37
        for i in range(total):
            server.publish("phase", {"phase": "chirp", "t_s": float(i)})
        pages, start = [], 0
        while True:
            page = replay(pipeline.replay, json.dumps({"from_seq": start}).encode())
            pages.append(len(page))
            if len(page) < REPLAY_PAGE:
                break
            start = page[-1]["seq"] + 1
        assert pages == [REPLAY_PAGE, REPLAY_PAGE, 37]
    finally:
        server.close()


def test_endpoint_in_use_is_a_config_error(pipeline: PipelineConfig) -> None:
    context = zmq.Context.instance()
    blocker = context.socket(zmq.PUB)
    blocker.bind("tcp://127.0.0.1:*")
    endpoint = blocker.getsockopt_string(zmq.LAST_ENDPOINT)
    try:
        with pytest.raises(ConfigError, match="cannot bind"):
            EventServer(PipelineConfig(blocks=endpoint, replay=pipeline.replay), "s")
    finally:
        blocker.close(0)


def test_ipc_endpoint_of_a_running_server_is_not_taken_over(pipeline: PipelineConfig) -> None:
    server = EventServer(pipeline, "first")
    try:
        with pytest.raises(ConfigError, match="another process"):
            EventServer(pipeline, "second")
        assert server.publish("end", {})["seq"] == 0
        assert replay(pipeline.replay, b'{"from_seq": 0}')[0]["session"] == "first"
    finally:
        server.close()


def test_cli_bus_error_is_one_line_and_exit_2(tmp_path: Path) -> None:
    channel = f"dtid{uuid.uuid4().hex[:8]}"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "dtid.cli",
            "acquire",
            "--channel",
            channel,
            "--output",
            str(tmp_path),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and SETUP_HINT in lines[0]
    assert not any(tmp_path.iterdir())  # no session is made for a bus that does not open


def _hostile_requests(rng: np.random.Generator, n: int) -> list[bytes]:
    """Random bytes, JSON of every wrong shape, deep nesting, numbers out of range, huge."""
    shapes = [
        b"",
        b"null",
        b"[]",
        b'{"from_seq": "0"}',
        b'{"from_seq": 1.5}',
        b'{"from_seq": true}',
        b'{"from_seq": 0, "and": 1}',
        b'{"from_seq": -99999999999999999999999}',
        b'{"from_seq": 99999999999999999999999}',
        b"[" * 100_000,
        b'{"from_seq": ' + b"9" * 5000 + b"}",
        b'{"x": "' + b"a" * 200_000 + b'"}',
    ]
    requests = []
    for i in range(n):
        if i % 3 == 0:
            requests.append(shapes[i // 3 % len(shapes)])
        else:
            requests.append(
                rng.integers(0, 256, int(rng.integers(0, 64)), dtype=np.uint8).tobytes()
            )
    return requests


def test_hostile_replay_requests_get_an_error_and_the_replay_goes_on(
    pipeline: PipelineConfig,
) -> None:
    """10^4 fuzzed requests: each gets an answer, the replay thread lives on and still serves."""
    server = EventServer(pipeline, "s")
    context = zmq.Context.instance()
    socket_ = context.socket(zmq.REQ)
    socket_.connect(pipeline.replay)
    try:
        server.publish("phase", {"phase": "settle"})
        requests = _hostile_requests(np.random.default_rng(11), 10_000)
        answers = 0
        for request in requests:
            socket_.send(request)
            assert socket_.poll(5000), f"no answer to {request[:40]!r}"
            reply = json.loads(socket_.recv())
            answers += 1
            if not (isinstance(reply, list) or "error" in reply):
                raise AssertionError(f"{request[:40]!r} -> {reply!r}")
        assert answers == len(requests)
        assert server.refused > 9_000
        assert replay(pipeline.replay, b'{"from_seq": 0}')[0]["phase"] == "settle"
    finally:
        socket_.close(0)
        server.close()
