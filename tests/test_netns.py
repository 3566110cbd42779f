"""The multicast guard and the HIL harness's network namespace.

udp_multicast frames are IP datagrams: the product refuses that bus unless the process's network
namespace has only loopback, and the harness (tests/hil/namespace.py) makes such namespaces. The
exchange tests put two processes on one udp_multicast bus in one namespace (or on the bus that
``DTID_HIL_BUS`` names, e.g. ``socketcan:vcan0`` on a laptop) and count what arrives.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hil.namespace import (
    DEFAULT_HIL_BUS,
    ROOT,
    SETUP_FAILED,
    HilBus,
    bus_unavailable,
    hil_bus,
    namespace_unavailable,
    parse_hil_bus,
    run_in_namespace,
    run_scenario,
)

from dtid.acquisition import netns
from dtid.errors import ConfigError

EXCHANGE = ROOT / "tests" / "hil" / "scenarios" / "exchange.py"

NET_DEV_HEADER = (
    "Inter-|   Receive                                                |  Transmit\n"
    " face |bytes    packets errs drop fifo frame compressed multicast|bytes    packets errs "
    "drop fifo colls carrier compressed\n"
)


def fake_net_dev(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, *names: str) -> None:
    path = tmp_path / "dev"
    rows = "".join(f"{name:>6}: 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\n" for name in names)
    path.write_text(NET_DEV_HEADER + rows)
    monkeypatch.setattr(netns, "_NET_DEV", path)


def needs_namespace() -> None:
    reason = namespace_unavailable()
    if reason:
        pytest.skip(f"no private network namespace here: {reason}")


def exchange_bus() -> HilBus:
    bus = hil_bus()
    reason = bus_unavailable(bus)
    if reason:
        pytest.skip(reason)
    return bus


# --- the guard, on a fake /proc/net/dev -------------------------------------------------------


def test_guard_names_every_other_interface(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake_net_dev(tmp_path, monkeypatch, "lo", "eth0", "wlan0")
    assert netns.network_interfaces() == ["lo", "eth0", "wlan0"]
    assert not netns.only_loopback()
    with pytest.raises(ConfigError, match=r"multicast on eth0, wlan0; run it in a private network"):
        netns.check_bus_allowed("udp_multicast")
    netns.check_bus_allowed("udp_multicast", allow_multicast_outside_namespace=True)
    netns.check_bus_allowed("socketcan")  # not multicast: allowed anywhere


def test_guard_allows_multicast_with_only_loopback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fake_net_dev(tmp_path, monkeypatch, "lo")
    assert netns.only_loopback()
    netns.check_bus_allowed("udp_multicast")


# --- the guard in this process's own namespace ------------------------------------------------


def test_guard_refuses_multicast_in_this_namespace() -> None:
    others = [name for name in netns.network_interfaces() if name != "lo"]
    if not others:
        pytest.skip("this test process already runs in a loopback-only namespace")
    with pytest.raises(ConfigError) as caught:
        netns.check_bus_allowed("udp_multicast")
    message = str(caught.value)
    assert f"would send IP multicast on {', '.join(others)};" in message
    assert "unshare -n" in message


def test_harness_bus_refuses_to_open_outside_a_namespace() -> None:
    if netns.only_loopback():
        pytest.skip("this test process already runs in a loopback-only namespace")
    with pytest.raises(ConfigError, match="would send IP multicast"):
        parse_hil_bus(DEFAULT_HIL_BUS).open()


# --- the bus setting --------------------------------------------------------------------------


def test_hil_bus_setting() -> None:
    assert hil_bus({}) == HilBus("udp_multicast", "239.74.163.2")
    assert hil_bus({"DTID_HIL_BUS": "socketcan:vcan0"}) == HilBus("socketcan", "vcan0")
    bus = parse_hil_bus("udp_multicast:239.1.2.3:40000")
    assert bus.options == {"port": 40000} and bus.spec == "udp_multicast:239.1.2.3:40000"
    assert bus.needs_namespace and not HilBus("socketcan", "vcan0").needs_namespace
    assert bus.bus_settings() == {
        "interface": "udp_multicast",
        "channel": "239.1.2.3",
        "receive_buffer_bytes": 4 << 20,
        "options": {"port": 40000},
    }
    with pytest.raises(ValueError, match="IPv6 groups deliver nothing"):
        parse_hil_bus("udp_multicast:ff15::1")
    with pytest.raises(ValueError, match="IPv4 multicast group"):
        parse_hil_bus("udp_multicast:10.0.0.1")
    with pytest.raises(ValueError, match="port must be"):
        parse_hil_bus("udp_multicast:239.1.2.3:0")
    with pytest.raises(ValueError, match="expected INTERFACE:CHANNEL"):
        parse_hil_bus("vcan0")


# --- the namespace ----------------------------------------------------------------------------


@pytest.mark.hil
def test_namespace_has_only_loopback_and_the_guard_passes() -> None:
    needs_namespace()
    probe = (
        "import json\n"
        "from dtid.acquisition.netns import check_bus_allowed, network_interfaces\n"
        "check_bus_allowed('udp_multicast')\n"
        "print(json.dumps(network_interfaces()))\n"
    )
    result = run_in_namespace([sys.executable, "-c", probe], timeout=60)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == ["lo"]

    result = run_in_namespace(["sh", "-c", "ip -o link show lo; ip route show"], timeout=20)
    assert result.returncode == 0, result.stderr
    link, *routes = result.stdout.splitlines()
    assert "MULTICAST" in link and "UP" in link
    assert any(route.startswith("224.0.0.0/4 dev lo") for route in routes), routes


@pytest.mark.hil
def test_namespace_passes_status_and_kills_its_group_on_timeout(tmp_path: Path) -> None:
    needs_namespace()
    result = run_in_namespace(["sh", "-c", "echo out; echo err >&2; exit 3"], timeout=20)
    assert (result.returncode, result.stdout, result.stderr) == (3, "out\n", "err\n")
    assert result.returncode != SETUP_FAILED

    pid_file = tmp_path / "child.pid"
    with pytest.raises(subprocess.TimeoutExpired) as caught:  # not the sleep's 60 s
        run_in_namespace(
            ["sh", "-c", f"sleep 60 & echo $! > {pid_file}; echo started; wait"], timeout=6
        )
    assert "started" in (caught.value.output or "")
    child = int(pid_file.read_text())
    deadline = time.monotonic() + 30  # a bound on the wait, not a timing asserted
    while Path(f"/proc/{child}").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    stat = Path(f"/proc/{child}/stat")
    assert not stat.exists() or stat.read_text().split(")")[1].split()[0] == "Z", (
        "a background process of the namespace survived the timeout"
    )


# --- two processes on one bus -----------------------------------------------------------------


def exchange(bus: HilBus, *args: str) -> dict:
    result = run_scenario(EXCHANGE, *args, bus=bus, timeout=90)
    assert result.returncode == 0, result.stdout + result.stderr
    return json.loads(result.stdout.splitlines()[-1])


@pytest.mark.hil
def test_two_processes_exchange_paced_frames_without_loss() -> None:
    bus = exchange_bus()
    report = exchange(bus, "--frames", "200", "--period", "0.001")
    for name in ("a", "b"):
        peer = report[name]
        assert peer["sent"] == 200
        assert (peer["from_peer"], peer["lost"]) == (200, 0), report
        assert (peer["duplicated"], peer["out_of_order"]) == (0, 0), report
        if bus.needs_namespace:
            # udp_multicast loops every datagram back to its sender: the product must
            # tell its own frames from the vehicle's
            assert peer["echoes"] == 200, report
            assert peer["receive_buffer_bytes"] >= bus.receive_buffer_bytes, report


@pytest.mark.hil
def test_a_burst_fits_the_enlarged_receive_buffer() -> None:
    bus = exchange_bus()
    report = exchange(bus, "--frames", "1000", "--period", "0")
    for name in ("a", "b"):
        assert (report[name]["from_peer"], report[name]["lost"]) == (1000, 0), report


@pytest.mark.hil
def test_a_burst_overflows_the_default_receive_buffer_and_the_loss_is_counted() -> None:
    bus = exchange_bus()
    if not bus.needs_namespace:
        pytest.skip("the default-buffer overflow is a property of udp_multicast")
    report = exchange(bus, "--frames", "1000", "--period", "0", "--receive-buffer", "0")
    delivered = 0
    for name in ("a", "b"):
        peer = report[name]
        assert peer["from_peer"] + peer["lost"] == 1000
        assert peer["duplicated"] == 0
        delivered += peer["from_peer"] + peer["echoes"]
    # each socket holds a few hundred datagrams by default (256 of 1000 seen here), and
    # neither peer reads until all its own frames are sent
    assert delivered < 4000, report
