"""ZeroMQ CURVE between daemon and worker: encryption and authentication off this machine.

The pipeline's default endpoints are ipc sockets in a private folder (:mod:`dtid.acquisition.ipc`)
and loopback TCP, which nobody off this machine reaches. A ``tcp://`` endpoint on any other
address (including the wildcards ``*`` and ``0.0.0.0``, which bind every interface) carries the
vehicle test to the network, so it requires CURVE: ``dtid keys DIR`` writes a key pair for the
binding side (the daemon's PUB and REP, the worker's result PUB: ``server``) and one for the
connecting side (``client``), and ``[pipeline] keys = "DIR"`` names the folder on both machines.
A binding socket then accepts only a client whose public key is in that folder (ZeroMQ's ZAP
handler, :class:`zmq.auth.thread.ThreadAuthenticator`), and all traffic is encrypted. With keys
configured, every TCP socket uses them, loopback included; ipc sockets never need them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from dtid.errors import ConfigError

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")
"""Hosts of a TCP endpoint that never leave this machine."""
SERVER, CLIENT = "server", "client"
"""Names of the two key pairs in a keys folder (``NAME.key`` and ``NAME.key_secret``)."""


def leaves_the_machine(endpoint: str) -> bool:
    """True for a ``tcp://`` endpoint on a host other than loopback (wildcards included)."""
    parts = urlsplit(endpoint)
    if parts.scheme != "tcp":
        return False
    host = parts.netloc.rpartition(":")[0]
    return host not in LOOPBACK_HOSTS


def create_keys(directory: Path) -> list[Path]:
    """Write the server and client key pairs into ``directory`` (made with mode 0700 when it
    does not exist; the secret keys get mode 0600 in any case).

    Raises
    ------
    ConfigError
        If the folder cannot be made or already holds keys (they are never overwritten).
    """
    if str(directory) in ("", "."):  # `dtid keys ""` wrote them into the working folder
        raise ConfigError("give the folder to write the keys to (a new one, e.g. keys/)")
    if directory.exists() and not directory.is_dir():
        raise ConfigError(f"{directory} is a file, not a folder: give a folder for the keys")
    existing = [directory / f"{n}.key{s}" for n in (SERVER, CLIENT) for s in ("", "_secret")]
    if any(path.exists() for path in existing):
        raise ConfigError(f"{directory} already holds keys; they are never overwritten")
    try:
        directory.mkdir(mode=0o700, parents=True, exist_ok=True)
        written = []
        for name in (SERVER, CLIENT):
            public, secret = zmq.auth.create_certificates(directory, name)
            os.chmod(secret, 0o600)
            written += [Path(public), Path(secret)]
    except OSError as error:
        raise ConfigError(f"cannot write keys to {directory}: {error.strerror or error}") from None
    return written


@dataclass(frozen=True)
class Curve:
    """The key pairs of a keys folder.

    Attributes
    ----------
    directory
        The folder; the public keys in it are the clients a server accepts.
    """

    directory: Path
    server_public: bytes
    server_secret: bytes | None
    client_public: bytes
    client_secret: bytes | None

    @classmethod
    def load(cls, directory: Path) -> Curve:
        """Read the folder ``dtid keys`` wrote (a machine may hold only the secret it needs).

        Raises
        ------
        ConfigError
            If a public key is missing or a file is not a ZeroMQ certificate.
        """
        keys = {}
        for name in (SERVER, CLIENT):
            try:
                public, _ = zmq.auth.load_certificate(directory / f"{name}.key")
                secret_file = directory / f"{name}.key_secret"
                secret = zmq.auth.load_certificate(secret_file)[1] if secret_file.exists() else None
            except (OSError, ValueError) as error:
                raise ConfigError(
                    f"[pipeline] keys = {str(directory)!r}: cannot read the {name} key ({error}); "
                    "write them with `dtid keys DIR`"
                ) from None
            keys[name] = (public, secret)
        return cls(directory, *keys[SERVER], *keys[CLIENT])


class Security:
    """How the sockets of one process are secured: CURVE when keys are given, and the rule
    that an endpoint leaving the machine needs them.

    Parameters
    ----------
    keys
        The keys folder, or None.
    context
        The ZeroMQ context whose sockets are secured (its ZAP handler is started on the first
        secured binding socket).
    """

    def __init__(self, keys: Path | None, context: zmq.Context) -> None:
        self.curve = Curve.load(keys) if keys else None
        self._context = context
        self._authenticator: ThreadAuthenticator | None = None

    def bind(self, socket: zmq.Socket, endpoint: str, what: str) -> None:
        """Secure a binding socket for ``endpoint`` (before binding it)."""
        curve = self._needed(endpoint, what)
        if curve is None:
            return
        if curve.server_secret is None:
            raise ConfigError(
                f"[pipeline] {what} = {endpoint!r} binds, but {curve.directory} holds no "
                "server.key_secret"
            )
        if self._authenticator is None:
            self._authenticator = ThreadAuthenticator(self._context)
            self._authenticator.start()
            self._authenticator.configure_curve(domain="*", location=str(curve.directory))
        socket.curve_secretkey = curve.server_secret
        socket.curve_publickey = curve.server_public
        socket.curve_server = True

    def connect(self, socket: zmq.Socket, endpoint: str, what: str) -> None:
        """Secure a connecting socket for ``endpoint`` (before connecting it)."""
        curve = self._needed(endpoint, what)
        if curve is None:
            return
        if curve.client_secret is None:
            raise ConfigError(
                f"[pipeline] {what} = {endpoint!r} connects, but {curve.directory} holds no "
                "client.key_secret"
            )
        socket.curve_secretkey = curve.client_secret
        socket.curve_publickey = curve.client_public
        socket.curve_serverkey = curve.server_public

    def close(self) -> None:
        """Stop the ZAP handler."""
        if self._authenticator is not None:
            self._authenticator.stop()
            self._authenticator = None

    def _needed(self, endpoint: str, what: str) -> Curve | None:
        if not endpoint.startswith("tcp://"):
            return None
        if self.curve is None and leaves_the_machine(endpoint):
            raise ConfigError(
                f"[pipeline] {what} = {endpoint!r} is reachable from other machines: it needs "
                "ZeroMQ CURVE keys (encryption and authentication). Write them with `dtid keys "
                'DIR`, give both machines the folder and set [pipeline] keys = "DIR"; or use '
                "an ipc:// or tcp://127.0.0.1 endpoint"
            )
        return self.curve
