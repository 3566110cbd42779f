"""The pipeline's ZeroMQ endpoints: the local (ipc) folder made private and checked before use.

Whoever can create the socket files of the pipeline can feed the worker or read the stream. A
predictable folder (``/tmp/dtid-UID`` without ``XDG_RUNTIME_DIR``) that another local user made
first would be theirs; so the folder is made with mode 0700 when missing, and an existing one is
used only when it is a real directory (not a symbolic link), owned by this user and writable by
no one else (neither its group nor every user). A shared folder the administrator made for both
services (``/run/dtid``, 0750, owned by the service user: deploy/systemd/dtid.tmpfiles) passes.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from urllib.parse import urlsplit

from dtid.errors import ConfigError


def private_folder(path: Path) -> Path:
    """Make ``path`` (mode 0700) or check that the existing one is safe; return it.

    Raises
    ------
    ConfigError
        If it cannot be made, is not a directory, is a symbolic link, belongs to another user
        or is writable by others; the message says how to fix it.
    """
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir(mode=0o700)
    except FileExistsError:
        pass
    except OSError as error:
        raise ConfigError(f"cannot make the ipc folder {path}: {error.strerror or error}") from None
    info = path.lstat()
    problem = None
    if stat.S_ISLNK(info.st_mode):
        problem = "is a symbolic link"
    elif not stat.S_ISDIR(info.st_mode):
        problem = "is not a directory"
    elif info.st_uid != os.geteuid():
        problem = f"belongs to user id {info.st_uid}, not to this user ({os.geteuid()})"
    elif info.st_mode & stat.S_IWOTH:
        problem = "is writable by every user"
    elif info.st_mode & stat.S_IWGRP:
        problem = "is writable by its group"
    if problem:
        raise ConfigError(
            f"the ipc folder {path} {problem}: another user could take over the pipeline's "
            "sockets; remove it or set [pipeline] endpoints in a folder of your own (or set "
            "XDG_RUNTIME_DIR)"
        )
    return path


def endpoint(address: str, bind: bool = False) -> str:
    """A ZeroMQ endpoint of the configuration, ready to use.

    ``ipc://`` endpoints get their folder made (when binding); a ``tcp://`` endpoint without a
    host (``tcp://:5555``) means loopback, 127.0.0.1, and so does a wildcard host (``*``,
    ``0.0.0.0``) to connect to; other transports are refused.
    """
    parts = urlsplit(address)
    if parts.scheme == "ipc":
        if bind:
            private_folder(Path(address[len("ipc://") :]).parent)
        return address
    if parts.scheme == "tcp":
        host, sep, port = parts.netloc.rpartition(":")
        if not sep or not port.isdigit():
            raise ConfigError(f"endpoint {address!r}: expected tcp://HOST:PORT")
        if not 1 <= int(port) <= 65535:  # ZeroMQ takes 99999 as 34463
            raise ConfigError(f"endpoint {address!r}: the port must lie in 1 .. 65535")
        if not host or (not bind and host in ("*", "0.0.0.0")):
            host = "127.0.0.1"
        return f"tcp://{host}:{port}"
    raise ConfigError(f"endpoint {address!r}: expected ipc://PATH or tcp://HOST:PORT")
