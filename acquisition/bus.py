"""Open the python-can bus of a test from ``[bus]``.

The multicast guard (:func:`dtid.acquisition.netns.check_bus_allowed`) runs first, so a
``udp_multicast`` bus is never opened outside a loopback-only network namespace. A bus that
cannot be opened (no such interface, ``vcan0`` absent, no permission) is a
:class:`dtid.errors.ConfigError` with the set-up hint.

Socket receive buffer: python-can does not size it, and its ``udp_multicast`` bus keeps the socket
in a private attribute (``bus._multicast._socket``; ``bus.socket`` on SocketCAN). When the socket
is found, ``SO_RCVBUF`` is set to ``receive_buffer_bytes`` and, where the kernel caps it at
``net.core.rmem_max``, ``SO_RCVBUFFORCE`` is tried (Linux, needs CAP_NET_ADMIN). Measured with
python-can 4.6.1 in a loopback-only namespace on this machine (``rmem_max`` 4 MiB, root): the
default buffer is 208 KiB; asking for the default 4 MiB gives 8 MiB as the kernel reports it (it
doubles the request for its own bookkeeping); asking for 64 MiB is capped to 8 MiB by SO_RCVBUF
and granted (128 MiB reported) by SO_RCVBUFFORCE. When the socket is not where python-can keeps
it, the bus still opens, with a warning.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import sys

import can

from dtid.acquisition.config import BusConfig
from dtid.acquisition.netns import MULTICAST_INTERFACES, check_bus_allowed
from dtid.errors import ConfigError

logger = logging.getLogger(__name__)

SO_RCVBUFFORCE = 33
"""Linux socket option (not in Python's :mod:`socket`): SO_RCVBUF above ``rmem_max``, root."""
SETUP_HINT = "deploy/setup-can.sh vcan"
"""The command that creates the virtual CAN interface on a laptop."""


def open_bus(config: BusConfig) -> can.BusABC:
    """Open the bus described by ``config``.

    Parameters
    ----------
    config
        Interface, channel, bit rate (bit/s), receive buffer (bytes) and further ``can.Bus``
        keyword arguments.

    Returns
    -------
    can.BusABC
        The open bus; the caller shuts it down.

    Raises
    ------
    ConfigError
        If the interface is unknown, a multicast bus is asked for outside a loopback-only network
        namespace or with a group that is not IPv4 multicast, or the bus cannot be opened.
    """
    check_bus_allowed(config.interface)
    if config.interface in MULTICAST_INTERFACES:
        _check_ipv4_group(config.channel)
    try:
        bus = can.Bus(
            interface=config.interface,
            channel=config.channel,
            bitrate=config.bitrate,
            **config.options,
        )
    except can.CanInterfaceNotImplementedError as error:
        raise ConfigError(
            f"[bus] interface '{config.interface}' is not available: {error}"
        ) from error
    except (can.CanError, OSError, ValueError, TypeError) as error:
        raise ConfigError(
            f"cannot open CAN bus {config.interface}/{config.channel}: {error}; on a laptop "
            f"create the virtual bus with `{SETUP_HINT}`, in a vehicle check the adapter and "
            "`ip link show`"
        ) from error
    _size_receive_buffer(bus, config.receive_buffer_bytes)
    return bus


def _check_ipv4_group(channel: str) -> None:
    try:
        group = ipaddress.ip_address(channel)
    except ValueError:
        group = None
    if group is None or group.version != 4 or not group.is_multicast:
        raise ConfigError(
            f"[bus] channel {channel!r}: udp_multicast needs an IPv4 multicast group "
            "(224.0.0.0/4, e.g. 239.74.163.2); IPv6 groups deliver nothing over loopback"
        )


def _bus_socket(bus: can.BusABC) -> socket.socket | None:
    """The receiving socket of a udp_multicast or SocketCAN bus (private in python-can)."""
    multicast = getattr(bus, "_multicast", None)
    candidate = getattr(multicast, "_socket", None) or getattr(bus, "socket", None)
    return candidate if isinstance(candidate, socket.socket) else None


def _size_receive_buffer(bus: can.BusABC, size: int) -> int | None:
    """Ask for a receive buffer of ``size`` bytes; return what the kernel reports, bytes."""
    sock = _bus_socket(bus)
    if sock is None:
        if bus.__class__.__name__ in ("UdpMulticastBus", "SocketcanBus"):
            logger.warning(
                "cannot reach the socket of the %s bus to size its receive buffer; bursts may "
                "drop frames (they are counted as lost)",
                bus.__class__.__name__,
            )
        return None
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    if granted < size and sys.platform == "linux":
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size)
        except OSError:  # not privileged: keep the capped size
            pass
        granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    level = logging.INFO if granted >= size else logging.WARNING
    logger.log(level, "socket receive buffer: asked %d bytes, kernel reports %d", size, granted)
    return granted
