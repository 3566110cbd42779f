"""A private network namespace with only loopback, and the bus the HIL tests run on.

This machine's kernel has neither vcan nor AF_CAN, so the hardware-in-the-loop tests put their
processes on python-can's ``udp_multicast`` interface. Its frames are IP multicast datagrams, which
must never leave the machine: every process that opens such a bus runs inside a fresh network
namespace (``unshare --net``) whose only interface is loopback, set up as

    ip link set lo up
    ip link set lo multicast on
    ip route add 224.0.0.0/4 dev lo

and both the set-up (here) and the product (:func:`dtid.acquisition.netns.check_bus_allowed`) check
``/proc/net/dev`` before a bus is opened (``/sys/class/net`` does not reflect ``unshare -n``).
Known behaviour of that interface here: only an IPv4 group delivers over loopback (IPv6 groups
deliver nothing), a sender receives its own frames, and a burst overflows the default socket
receive buffer (1000 frames delivered 256), so the buffer is enlarged and losses are counted.

The bus comes from the environment variable ``DTID_HIL_BUS`` (``INTERFACE:CHANNEL``, default
``udp_multicast:239.74.163.2``; ``udp_multicast:GROUP:PORT`` sets the port). On a laptop with vcan,
``DTID_HIL_BUS=socketcan:vcan0`` runs the same tests on SocketCAN without a namespace.
"""

from __future__ import annotations

import functools
import ipaddress
import os
import shutil
import signal
import socket
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dtid.acquisition.netns import MULTICAST_INTERFACES, check_bus_allowed

ROOT = Path(__file__).resolve().parents[2]
"""The repository (its ``tests/`` folder is on the ``PYTHONPATH`` of every harness process)."""

HIL_BUS_ENV = "DTID_HIL_BUS"
DEFAULT_HIL_BUS = "udp_multicast:239.74.163.2"
RECEIVE_BUFFER_BYTES = 4 << 20
"""Receive buffer asked for on a udp_multicast bus, bytes (the default 208 KiB holds ~256)."""

SETUP_FAILED = 97
"""Exit status of a namespace whose set-up failed (before the command ran)."""

_SETUP = """\
fail() { echo "hil namespace: $*" >&2; exit 97; }
ip link set lo up || fail "ip link set lo up failed"
ip link set lo multicast on || fail "ip link set lo multicast on failed"
ip route add 224.0.0.0/4 dev lo || fail "ip route add 224.0.0.0/4 dev lo failed"
interfaces=$(tail -n +3 /proc/net/dev | cut -d: -f1 | tr -d ' ' | tr '\\n' ' ')
[ "$interfaces" = "lo " ] || fail "interfaces other than lo in the namespace: $interfaces"
exec "$@"
"""


def unshare_argv() -> list[str]:
    """The ``unshare`` prefix: a new network namespace (and, without root, a user namespace)."""
    if os.geteuid() == 0:
        return ["unshare", "--net", "--"]
    return ["unshare", "--map-root-user", "--net", "--"]


def child_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment of a harness process: this one's, with tests/ on the path.

    Scenarios start the commands as ``python -m dtid.cli``: the installed package runs (the work
    tree after ``pip install -e .``), the same the tests import.
    """
    env = dict(os.environ)
    paths = [str(ROOT / "tests")]
    if env.get("PYTHONPATH"):
        paths.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(paths)
    env.update(extra or {})
    return env


def _run(
    argv: Sequence[str],
    *,
    timeout: float,
    env: Mapping[str, str] | None,
    cwd: Path | str | None,
    stdin: str | None,
) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` in its own process group; on timeout kill the whole group."""
    with subprocess.Popen(
        list(argv),
        stdin=subprocess.PIPE if stdin is not None else subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=child_env(env),
        cwd=cwd,
        start_new_session=True,
    ) as process:
        try:
            out, err = process.communicate(stdin, timeout=timeout)
        except subprocess.TimeoutExpired:
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            out, err = process.communicate()
            raise subprocess.TimeoutExpired(process.args, timeout, out, err) from None
        return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def run_in_namespace(
    argv: Sequence[str],
    *,
    timeout: float = 60.0,
    env: Mapping[str, str] | None = None,
    cwd: Path | str | None = None,
    stdin: str | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run a command inside a fresh network namespace whose only interface is loopback.

    Parameters
    ----------
    argv
        The command; it and every process it starts share the namespace, which disappears with
        the last of them.
    timeout
        Wall-clock limit, s: the command and all processes of its group are then killed and
        :class:`subprocess.TimeoutExpired` is raised with the output so far.
    env
        Variables added to this process's environment (the repository is put on ``PYTHONPATH``).
    cwd, stdin
        Working directory; text fed to the standard input.

    Returns
    -------
    subprocess.CompletedProcess
        With ``stdout`` and ``stderr`` as text; ``returncode`` :data:`SETUP_FAILED` when the
        namespace could not be set up (the reason is on ``stderr``).
    """
    command = [*unshare_argv(), "sh", "-c", _SETUP, "hil-namespace", *argv]
    return _run(command, timeout=timeout, env=env, cwd=cwd, stdin=stdin)


@functools.cache
def namespace_unavailable() -> str | None:
    """Why no loopback-only network namespace can be made here, or None when one can."""
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    for tool, package in (("unshare", "util-linux"), ("ip", "iproute2")):
        if shutil.which(tool) is None:
            return f"`{tool}` ({package}) is not installed"
    try:
        probe = run_in_namespace(["true"], timeout=20)
    except (OSError, subprocess.TimeoutExpired) as error:
        return f"cannot make a network namespace: {error}"
    if probe.returncode != 0:
        who = "" if os.geteuid() == 0 else " (not root, and no unprivileged user namespaces?)"
        return f"cannot make a network namespace{who}: {probe.stderr.strip()}"
    return None


@dataclass(frozen=True)
class HilBus:
    """The python-can bus of the HIL processes.

    Attributes
    ----------
    interface, channel
        python-can interface and channel (for udp_multicast: an IPv4 multicast group).
    options
        Further keyword arguments of ``can.Bus`` (udp_multicast: ``port``).
    receive_buffer_bytes
        Socket receive buffer asked for (udp_multicast), bytes; 0 keeps the system default.
    """

    interface: str
    channel: str
    options: dict[str, Any] = field(default_factory=dict)
    receive_buffer_bytes: int = RECEIVE_BUFFER_BYTES

    @property
    def needs_namespace(self) -> bool:
        """True when the bus sends IP multicast, so its processes must run in a namespace."""
        return self.interface in MULTICAST_INTERFACES

    @property
    def spec(self) -> str:
        """The ``DTID_HIL_BUS`` value that gives this bus."""
        port = self.options.get("port")
        return f"{self.interface}:{self.channel}" + (f":{port}" if port is not None else "")

    def bus_settings(self) -> dict[str, Any]:
        """The ``[bus]`` section of a scenario's configuration file (dtid.acquisition.config
        keys)."""
        return {
            "interface": self.interface,
            "channel": self.channel,
            "receive_buffer_bytes": self.receive_buffer_bytes,
            "options": dict(self.options),
        }

    def open(self) -> Any:
        """Open the bus in this process (refused for multicast outside a loopback namespace).

        Returns
        -------
        can.BusABC
            The bus; for udp_multicast with the receive buffer enlarged.
        """
        import can

        check_bus_allowed(self.interface)
        bus = can.Bus(interface=self.interface, channel=self.channel, **self.options)
        if self.needs_namespace and self.receive_buffer_bytes:
            set_receive_buffer(bus, self.receive_buffer_bytes)
        return bus


def parse_hil_bus(text: str) -> HilBus:
    """A :class:`HilBus` from ``INTERFACE:CHANNEL`` (udp_multicast: ``GROUP[:PORT]``).

    Raises
    ------
    ValueError
        If the text has no channel, or a udp_multicast group is not an IPv4 multicast address.
    """
    interface, _, rest = text.strip().partition(":")
    if not interface or not rest:
        raise ValueError(
            f"{HIL_BUS_ENV}={text!r}: expected INTERFACE:CHANNEL, e.g. {DEFAULT_HIL_BUS} or "
            "socketcan:vcan0"
        )
    if interface not in MULTICAST_INTERFACES:
        return HilBus(interface, rest)
    group, _, port = rest.partition(":")
    try:
        address = ipaddress.ip_address(group)
    except ValueError:
        address = None
    if address is None or address.version != 4 or not address.is_multicast:
        raise ValueError(
            f"{HIL_BUS_ENV}={text!r}: udp_multicast needs an IPv4 multicast group (224.0.0.0/4, "
            "e.g. 239.74.163.2); IPv6 groups deliver nothing over loopback here"
        )
    options: dict[str, Any] = {}
    if port:
        if not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"{HIL_BUS_ENV}={text!r}: port must be 1-65535")
        options["port"] = int(port)
    return HilBus(interface, group, options)


def hil_bus(environ: Mapping[str, str] | None = None) -> HilBus:
    """The bus chosen by ``DTID_HIL_BUS`` (default :data:`DEFAULT_HIL_BUS`)."""
    environ = os.environ if environ is None else environ
    return parse_hil_bus(environ.get(HIL_BUS_ENV) or DEFAULT_HIL_BUS)


def bus_unavailable(bus: HilBus) -> str | None:
    """Why the HIL tests cannot run on ``bus`` here (a pytest skip reason), or None."""
    if bus.needs_namespace:
        reason = namespace_unavailable()
        if reason:
            return f"{bus.interface} needs a private network namespace: {reason}"
        try:
            import msgpack  # noqa: F401  (python-can's udp_multicast serialises with it)
        except ImportError:
            return "udp_multicast needs msgpack: pip install '.[test]'"
        return None
    if bus.interface == "socketcan" and not Path("/sys/class/net", bus.channel).exists():
        return (
            f"no SocketCAN interface {bus.channel}: run `sudo deploy/setup-can.sh vcan "
            f"{bus.channel}` or unset {HIL_BUS_ENV}"
        )
    return None


def receive_buffer_size(bus: Any) -> int:
    """The socket receive buffer of a bus as the kernel reports it (twice the usable size), or 0
    when the bus has no socket."""
    fd = bus.fileno()
    if fd < 0:
        return 0
    with socket.socket(fileno=os.dup(fd)) as sock:
        return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def set_receive_buffer(bus: Any, nbytes: int) -> int:
    """Ask for a socket receive buffer of ``nbytes`` on a bus; return what the kernel granted.

    As root ``SO_RCVBUFFORCE`` passes over ``net.core.rmem_max``. The kernel reports twice the
    usable size (bookkeeping included). 0 when the bus has no socket.
    """
    fd = bus.fileno()
    if fd < 0:
        return 0
    with socket.socket(fileno=os.dup(fd)) as sock:
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUFFORCE, nbytes)
        except (OSError, AttributeError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, nbytes)
        return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def run_on_bus(
    argv: Sequence[str],
    bus: HilBus,
    *,
    timeout: float = 60.0,
    env: Mapping[str, str] | None = None,
    cwd: Path | str | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run a command with access to ``bus``: in a namespace for multicast, else directly.

    ``DTID_HIL_BUS`` is set for the command (and what it starts) to ``bus``.
    """
    env = {**(env or {}), HIL_BUS_ENV: bus.spec}
    if bus.needs_namespace:
        return run_in_namespace(argv, timeout=timeout, env=env, cwd=cwd)
    return _run(argv, timeout=timeout, env=env, cwd=cwd, stdin=None)


def run_scenario(
    script: Path | str,
    *args: str,
    bus: HilBus,
    timeout: float = 120.0,
    env: Mapping[str, str] | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run a Python scenario script (tests/hil/scenarios/) with access to ``bus``.

    The script and every process it starts (:class:`hil.processes.Processes`) share one
    namespace, so they share one bus.
    """
    return run_on_bus([sys.executable, str(script), *args], bus, timeout=timeout, env=env, cwd=ROOT)
