"""Keep multicast CAN traffic on this machine: the network-namespace guard of udp_multicast.

python-can's ``udp_multicast`` interface sends every frame as an IP multicast datagram. On a
machine with a real network interface that traffic could leave it; the product opens such a bus
only inside a private network namespace whose only interface is loopback (``unshare -n``, as the
hardware-in-the-loop tests do), unless the configuration explicitly allows otherwise.
"""

from __future__ import annotations

from pathlib import Path

from dtid.errors import ConfigError

MULTICAST_INTERFACES = frozenset({"udp_multicast"})
"""python-can interfaces that put frames on an IP network."""

_NET_DEV = Path("/proc/net/dev")


def network_interfaces() -> list[str]:
    """Names of the network interfaces of this process's network namespace."""
    lines = _NET_DEV.read_text().splitlines()[2:]
    return [line.split(":", 1)[0].strip() for line in lines if ":" in line]


def only_loopback() -> bool:
    """True when this process's network namespace has no interface but ``lo``."""
    return network_interfaces() == ["lo"]


def check_bus_allowed(interface: str, allow_multicast_outside_namespace: bool = False) -> None:
    """Refuse a multicast bus outside a loopback-only network namespace.

    Raises
    ------
    ConfigError
        If ``interface`` sends IP multicast and the namespace has another interface than ``lo``.
    """
    if interface not in MULTICAST_INTERFACES or allow_multicast_outside_namespace:
        return
    others = [name for name in network_interfaces() if name != "lo"]
    if others:
        raise ConfigError(
            f"interface '{interface}' would send IP multicast on {', '.join(others)}; run it in a "
            "private network namespace with only loopback (e.g. `unshare -n`, see "
            "deploy/README.md) or use socketcan/vcan0"
        )
