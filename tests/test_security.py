"""The pipeline off this machine: CURVE required, and with it only key holders get through."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
import zmq

from dtid.acquisition.config import PipelineConfig
from dtid.acquisition.security import Curve, Security, create_keys, leaves_the_machine
from dtid.acquisition.server import EventServer
from dtid.cli import main
from dtid.errors import ConfigError
from dtid.identification.service.worker import Worker, WorkerOptions


def _port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.parametrize(
    ("endpoint", "leaves"),
    [
        ("ipc:///run/dtid/blocks", False),
        ("tcp://127.0.0.1:5555", False),
        ("tcp://localhost:5555", False),
        ("tcp://*:5555", True),
        ("tcp://0.0.0.0:5555", True),
        ("tcp://10.0.0.7:5555", True),
    ],
)
def test_which_endpoints_leave_the_machine(endpoint: str, leaves: bool) -> None:
    assert leaves_the_machine(endpoint) == leaves


@pytest.mark.parametrize("what", ["daemon", "worker"])
def test_an_endpoint_off_the_machine_is_refused_without_keys(tmp_path: Path, what: str) -> None:
    wildcard = f"tcp://0.0.0.0:{_port()}"
    local = f"ipc://{tmp_path}/ipc/x"
    if what == "daemon":
        pipeline = PipelineConfig(blocks=wildcard, replay=local + "r", results=local)
        with pytest.raises(ConfigError, match=r"reachable from other machines.*dtid keys"):
            EventServer(pipeline, "s")
    else:
        pipeline = PipelineConfig(blocks=local, replay=local + "r", results=f"tcp://*:{_port()}")
        with pytest.raises(ConfigError, match="reachable from other machines"):
            Worker(pipeline, WorkerOptions()).serve(once=True)


def test_dtid_keys_writes_two_private_pairs_and_never_overwrites(tmp_path: Path) -> None:
    folder = tmp_path / "keys"
    assert main(["keys", str(folder)]) == 0
    assert oct(folder.stat().st_mode & 0o777) == "0o700"
    curve = Curve.load(folder)
    assert (
        curve.server_secret and curve.client_secret and curve.server_public != curve.client_public
    )
    assert (folder / "server.key_secret").stat().st_mode & 0o077 == 0
    assert main(["keys", str(folder)]) == 2  # refused: keys are never overwritten


def _replay(endpoint: str, security: Security | None, timeout_ms: int = 1500) -> list | None:
    context = zmq.Context.instance()
    request = context.socket(zmq.REQ)
    request.setsockopt(zmq.LINGER, 0)
    if security is not None:
        security.connect(request, endpoint, "replay")
    request.connect(endpoint)
    try:  # a failed CURVE handshake can leave no peer to send to: then nothing gets through
        request.send(json.dumps({"from_seq": 0}).encode(), zmq.NOBLOCK)
        return json.loads(request.recv()) if request.poll(timeout_ms) else None
    except zmq.Again:
        return None
    finally:
        request.close(0)


def test_with_keys_only_a_key_holder_gets_the_stream(tmp_path: Path) -> None:
    """The daemon's replay bound on every interface with CURVE (reached here on loopback): the
    worker's keys get the events; no keys, or another folder's keys, get nothing."""
    keys, strangers = tmp_path / "keys", tmp_path / "other"
    create_keys(keys)
    create_keys(strangers)
    port = _port()
    pipeline = PipelineConfig(
        blocks=f"tcp://0.0.0.0:{_port()}", replay=f"tcp://0.0.0.0:{port}", keys=keys
    )
    server = EventServer(pipeline, "curve")
    context = zmq.Context.instance()
    try:
        server.publish("phase", {"phase": "settle"})
        local = f"tcp://127.0.0.1:{port}"
        events = _replay(local, Security(keys, context))
        assert events == [{"kind": "phase", "session": "curve", "seq": 0, "phase": "settle"}]
        assert _replay(local, None) is None
        # a client with its own keys, trusting the right server key, is not let in either
        impostor = Curve.load(strangers)
        forged = Security(None, context)
        forged.curve = Curve(keys, Curve.load(keys).server_public, None, impostor.client_public,
                             impostor.client_secret)  # fmt: skip
        assert _replay(local, forged) is None
    finally:
        server.close()


def test_keys_go_into_a_folder_named_for_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`dtid keys ""` wrote the secret keys into the working folder; a file given as the folder
    said "File exists"."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match="give the folder to write the keys to"):
        create_keys(Path(""))
    (tmp_path / "afile").touch()
    with pytest.raises(ConfigError, match="afile is a file, not a folder"):
        create_keys(Path("afile"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
    written = create_keys(Path("keys"))
    assert (tmp_path / "keys").stat().st_mode & 0o777 == 0o700
    assert all(p.stat().st_mode & 0o777 == 0o600 for p in written if p.name.endswith("_secret"))
