"""The daemon's side of the event stream (:mod:`dtid.acquisition.stream`): numbering, PUB and
replay.

Every event of a session gets the next ``seq`` (0, 1, 2, ... without gaps) and the session's
name, is published on the PUB socket (``[pipeline] blocks``) as ``[kind, JSON]`` and kept, as the
very bytes published, until the daemon exits. A REP socket (``[pipeline] replay``) served by its
own thread answers ``{"from_seq": N}`` with the JSON list of the kept events from N on (an empty
list when N is past the last). A request that is not such an object gets ``{"error": "..."}``.

Endpoints are ZeroMQ addresses: ``ipc://PATH`` (the default; the directory of PATH is created),
or ``tcp://HOST:PORT`` as configured.
"""

from __future__ import annotations

import json
import logging
import socket as socketlib
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import zmq

from dtid.acquisition.config import PipelineConfig
from dtid.acquisition.ipc import private_folder
from dtid.acquisition.security import Security
from dtid.acquisition.stream import KINDS, REPLAY_PAGE, encode_event
from dtid.errors import ConfigError

logger = logging.getLogger(__name__)

POLL_MS = 100
"""How often the replay thread looks whether it should stop, ms."""
SEND_HWM = 100_000
"""Events the PUB socket queues per subscriber before it drops (the replay still has them)."""


def bind(socket: zmq.Socket, endpoint: str, what: str, security: Security | None = None) -> None:
    """Bind a socket, creating the private folder of an ipc endpoint and securing a TCP one
    (:mod:`dtid.acquisition.security`).

    Raises
    ------
    ConfigError
        If the endpoint is malformed, in use, reachable from other machines without keys, or
        its folder is not safe.
    """
    try:
        if endpoint.startswith("ipc://"):
            path = Path(endpoint[len("ipc://") :])
            private_folder(path.parent)
            if _listening(path):
                raise ConfigError(
                    f"[pipeline] {what} = {endpoint!r}: cannot bind: another process (a daemon "
                    "still running?) serves it"
                )
        (security or Security(None, zmq.Context.instance())).bind(socket, endpoint, what)
        socket.bind(endpoint)
    except (OSError, zmq.ZMQError) as error:
        raise ConfigError(f"[pipeline] {what} = {endpoint!r}: cannot bind: {error}") from error


def _listening(path: Path) -> bool:
    """True when a process accepts connections on the Unix socket ``path``.

    ZeroMQ binds an ipc endpoint by replacing the socket file, silently taking it from a daemon
    that still runs; this asks first.
    """
    with socketlib.socket(socketlib.AF_UNIX, socketlib.SOCK_STREAM) as probe:
        try:
            probe.connect(str(path))
        except OSError:
            return False
    return True


MAX_REQUEST_BYTES = 1024
"""Longest replay request answered (a valid one has about 20 bytes); ZeroMQ drops a client whose
message exceeds 1 MiB before it reaches the server."""
LOGGED_REFUSALS = 20
"""Bad replay requests logged one by one; the rest are counted (``refused``)."""


def _short(error: BaseException) -> str:
    text = " ".join(str(error).split()) or type(error).__name__
    return text[:120]


class EventServer:
    """Number, publish and keep the events of one session; serve the replay.

    Parameters
    ----------
    pipeline
        ``[pipeline]`` of the configuration (``blocks`` and ``replay`` endpoints).
    session
        Name of the session, carried by every event.
    context
        ZeroMQ context; the process-wide one if omitted.

    Raises
    ------
    ConfigError
        If an endpoint cannot be bound.
    """

    def __init__(
        self, pipeline: PipelineConfig, session: str, context: zmq.Context | None = None
    ) -> None:
        self.session = session
        self._context = context or zmq.Context.instance()
        self._bodies: list[bytes] = []
        self._publisher = self._context.socket(zmq.PUB)
        self._publisher.setsockopt(zmq.SNDHWM, SEND_HWM)
        self._publisher.setsockopt(zmq.LINGER, 1000)
        replay = self._context.socket(zmq.REP)
        replay.setsockopt(zmq.LINGER, 0)
        replay.setsockopt(zmq.MAXMSGSIZE, 1 << 20)
        self.refused = 0
        """Bad replay requests answered with an error."""
        self._security = Security(pipeline.keys, self._context)
        try:
            bind(self._publisher, pipeline.blocks, "blocks", self._security)
            bind(replay, pipeline.replay, "replay", self._security)
        except ConfigError:
            self._publisher.close(0)
            replay.close(0)
            self._security.close()
            raise
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._serve, args=(replay,), name="dtid-replay", daemon=True
        )
        self._thread.start()

    @property
    def count(self) -> int:
        """Events published so far."""
        return len(self._bodies)

    def publish(self, kind: str, fields: Mapping[str, Any]) -> dict[str, Any]:
        """Publish an event of ``kind`` with ``fields``; return it with ``seq`` and ``session``."""
        if kind not in KINDS:
            raise ValueError(f"unknown event kind {kind!r}")
        event = {"kind": kind, "session": self.session, "seq": len(self._bodies), **fields}
        topic, body = encode_event(event)
        self._bodies.append(body)
        self._publisher.send_multipart([topic, body], copy=False)
        return event

    def replay(self, from_seq: int) -> bytes:
        """The JSON list of the kept events from ``from_seq`` on, at most
        :data:`dtid.acquisition.stream.REPLAY_PAGE` of them."""
        start = max(0, from_seq)
        return b"[" + b",".join(self._bodies[start : start + REPLAY_PAGE]) + b"]"

    def close(self) -> None:
        """Stop the replay and close both sockets (queued events still go out for 1 s)."""
        self._stop.set()
        self._thread.join()
        self._publisher.close()
        self._security.close()

    def _serve(self, replay: zmq.Socket) -> None:
        try:
            while not self._stop.is_set():
                if not replay.poll(POLL_MS):
                    continue
                request = replay.recv()
                replay.send(self._answer(request))
        finally:
            replay.close(0)

    def _answer(self, request: bytes) -> bytes:
        """The reply to one request: a page of events, or ``{"error": ...}`` for anything that
        is not ``{"from_seq": N}`` (never an exception: the replay thread must outlive a
        hostile client)."""
        try:
            if len(request) > MAX_REQUEST_BYTES:
                raise ValueError(f"request of {len(request)} bytes (at most {MAX_REQUEST_BYTES})")
            query = json.loads(request)
            if not isinstance(query, dict) or set(query) != {"from_seq"}:
                raise ValueError("the request is not an object with the one key from_seq")
            from_seq = query["from_seq"]
            if isinstance(from_seq, bool) or not isinstance(from_seq, int):
                raise TypeError("from_seq must be an integer")
        except (ValueError, TypeError, RecursionError) as error:
            self.refused += 1
            if self.refused <= LOGGED_REFUSALS:
                logger.warning("bad replay request %r: %s", request[:80], error)
            message = f'expected {{"from_seq": N}}: {_short(error)}'
            return json.dumps({"error": message}).encode()
        return self.replay(from_seq)
