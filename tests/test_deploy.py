"""deploy/: the example configuration, the systemd units, the CAN set-up script, the guide.

The example configuration must name every key of dtid.acquisition.config (so it cannot drift), the
units must start subcommands that exist with files the installation provides, and setup-can.sh
is run against a stand-in ``ip`` that keeps the interfaces' state in a JSON file.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from dataclasses import fields
from pathlib import Path, PurePosixPath

import pytest

from dtid.acquisition.config import (
    _SECTIONS,
    CAMPAIGN_KEYS,
    AcquisitionConfig,
    CampaignConfig,
    load_config,
)
from dtid.acquisition.stream import ABORT_REASONS
from dtid.cli import build_parser
from dtid.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy"
EXAMPLE = DEPLOY / "dtid.example.toml"
SETUP_CAN = DEPLOY / "setup-can.sh"
UNITS = {"acquire": DEPLOY / "systemd" / "dtid-acquire.service"}
UNITS["worker"] = DEPLOY / "systemd" / "dtid-worker.service"
INSTALLED_CONFIG = "/etc/dtid/dtid.toml"

SERVICE_KEYS = {
    ("output", "directory"): "/var/lib/dtid/runs",
    ("pipeline", "blocks"): "ipc:///run/dtid/blocks",
    ("pipeline", "replay"): "ipc:///run/dtid/replay",
    ("pipeline", "results"): "ipc:///run/dtid/results",
}
"""Keys the example sets for the systemd services instead of the built-in default."""


# --- the example configuration ----------------------------------------------------------------


def test_example_config_loads() -> None:
    config = load_config(EXAMPLE)
    assert isinstance(config, AcquisitionConfig)
    assert config.bus.interface == "socketcan"  # never multicast by default


def test_example_config_names_every_key_of_every_section() -> None:
    document = tomllib.loads(EXAMPLE.read_text())
    assert list(document) == list(_SECTIONS)
    for section, cls in _SECTIONS.items():
        named = set(document[section])
        known = {f.name for f in fields(cls) if f.init}
        if section == "test":  # the adaptive campaign's keys live in [test] too
            known |= set(CAMPAIGN_KEYS)
        assert named == known, f"[{section}] missing {known - named}, unknown {named - known}"


def test_example_config_shows_the_defaults() -> None:
    """Every value is the built-in default, except the keys the services need (said in the
    file's comments), so the example documents the defaults."""
    config = load_config(EXAMPLE)
    for section, cls in _SECTIONS.items():
        defaults = cls()
        for field in fields(cls):
            value = getattr(getattr(config, section), field.name)
            if (section, field.name) in SERVICE_KEYS:
                assert str(value) == SERVICE_KEYS[section, field.name]
            else:
                assert value == getattr(defaults, field.name), f"[{section}] {field.name}"
    assert config.campaign == CampaignConfig()


def test_example_config_comments_every_key() -> None:
    lines = EXAMPLE.read_text().splitlines()
    for number, line in enumerate(lines):
        if re.match(r"^[a-z_0-9]+ = ", line):
            assert "#" in line or lines[number - 1].startswith("#"), f"no comment for {line!r}"


# --- the systemd units ------------------------------------------------------------------------


def unit_entries(path: Path) -> list[tuple[str, str, str]]:
    """(section, key, value) of a unit file in order; keys may repeat (Environment=)."""
    entries, section = [], ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        entries.append((section, key.strip(), value.strip()))
    return entries


def unit_value(path: Path, key: str) -> str | None:
    values = [value for _, name, value in unit_entries(path) if name == key]
    return values[-1] if values else None


def exec_start(path: Path) -> list[str]:
    value = unit_value(path, "ExecStart")
    assert value, f"{path.name} has no ExecStart"
    return shlex.split(value)


def tmpfiles_dirs() -> set[str]:
    text = (DEPLOY / "systemd" / "dtid.tmpfiles").read_text()
    return {line.split()[1] for line in text.splitlines() if line.startswith("d ")}


@pytest.mark.parametrize("command", list(UNITS))
def test_unit_starts_dtid_with_the_installed_config(command: str) -> None:
    path = UNITS[command]
    argv = exec_start(path)
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert PurePosixPath(argv[0]).name in scripts  # the `dtid` entry point
    assert PurePosixPath(argv[0]).is_absolute()
    assert argv[1] == command
    assert argv[argv.index("--config") + 1] == INSTALLED_CONFIG


@pytest.mark.parametrize("command", list(UNITS))
def test_unit_subcommand_exists(command: str) -> None:
    parser = build_parser()
    subcommands = next(action.choices for action in parser._actions if action.dest == "command")
    assert command in subcommands, f"the unit runs `dtid {command}`, which dtid.cli lacks"
    # the unit's own arguments are accepted (with the example for the config not installed here)
    argv = [str(EXAMPLE) if a == INSTALLED_CONFIG else a for a in exec_start(UNITS[command])[1:]]
    args = parser.parse_args(argv)
    assert args.command == command


@pytest.mark.parametrize("command", list(UNITS))
def test_unit_files_and_folders_are_provided(command: str) -> None:
    path = UNITS[command]
    text = path.read_text()
    for reference in re.findall(r"deploy/[\w./-]+\w", text):
        assert (ROOT / reference).exists(), f"{path.name} names {reference}, which does not exist"
    user = unit_value(path, "User")
    sysusers = (DEPLOY / "systemd" / "dtid.sysusers").read_text()
    assert re.search(rf"^u\s+{user}\s", sysusers, re.MULTILINE), f"no sysusers entry for {user}"

    config = load_config(EXAMPLE)
    runtime = unit_value(path, "ReadWritePaths")
    assert runtime in tmpfiles_dirs()
    for name in ("blocks", "replay", "results"):
        endpoint = getattr(config.pipeline, name)
        assert endpoint.startswith(f"ipc://{runtime}/"), endpoint  # not /tmp: PrivateTmp
    state = Path("/var/lib") / unit_value(path, "StateDirectory")
    assert config.output.directory.is_relative_to(state)
    assert str(config.output.directory) in tmpfiles_dirs()


@pytest.mark.parametrize("command", list(UNITS))
def test_unit_hardening_keeps_can_and_numba_working(command: str) -> None:
    path = UNITS[command]
    assert unit_value(path, "PrivateNetwork") in (None, "no")  # SocketCAN is in the netns
    assert unit_value(path, "MemoryDenyWriteExecute") is None  # numba JIT
    assert unit_value(path, "ProcSubset") is None  # the multicast guard reads /proc/net/dev
    assert unit_value(path, "User") == "dtid" and unit_value(path, "NoNewPrivileges") == "yes"
    assert unit_value(path, "CapabilityBoundingSet") == ""
    assert unit_value(path, "ProtectSystem") == "strict"
    families = (unit_value(path, "RestrictAddressFamilies") or "").split()
    assert "AF_UNIX" in families  # ipc:// endpoints
    if command == "acquire":
        assert "AF_CAN" in families


def test_worker_restarts_and_acquire_runs_once_on_demand() -> None:
    worker, acquire = UNITS["worker"], UNITS["acquire"]
    assert unit_value(worker, "Restart") == "on-failure"
    assert unit_value(worker, "WantedBy") == "multi-user.target"
    assert unit_value(acquire, "Restart") == "no"
    assert unit_value(acquire, "WantedBy") is None  # never started at boot
    assert unit_value(acquire, "KillSignal") == "SIGTERM"  # the daemon's "signal" abort


def test_units_pass_systemd_analyze(tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed")
    copies = []
    for path in UNITS.values():  # ExecStart must exist for verify: stand in /bin/true
        copy = tmp_path / path.name
        copy.write_text(path.read_text().replace("/opt/dtid/bin/dtid", shutil.which("true")))
        copies.append(str(copy))
    result = subprocess.run(
        [analyze, "verify", *copies], capture_output=True, text=True, timeout=60, check=False
    )
    ours = [
        line
        for line in (result.stdout + result.stderr).splitlines()
        if any(Path(copy).name in line for copy in copies)
    ]
    assert result.returncode == 0 and not ours, result.stdout + result.stderr


# --- setup-can.sh -----------------------------------------------------------------------------

FAKE_IP = r"""
import json, os, sys
state_path = os.environ["FAKE_STATE"]
state = json.load(open(state_path))
with open(os.environ["FAKE_CALLS"], "a") as calls:
    calls.write(" ".join(sys.argv[1:]) + "\n")
args = [a for a in sys.argv[1:] if a not in ("-details", "-d")]
details = len(args) < len(sys.argv) - 1
if args[:3] == ["link", "show", "dev"]:
    link = state["links"].get(args[3])
    if link is None:
        sys.exit(f'Device "{args[3]}" does not exist.')
    flags = "NOARP,UP,LOWER_UP" if link["up"] else "NOARP"
    print(f"3: {args[3]}: <{flags}> mtu 16 qdisc noqueue state UNKNOWN mode DEFAULT")
    kind = "can" if link["type"] in ("can", "vcan") else "ether"
    print(f"    link/{kind}  promiscuity 0 minmtu 0 maxmtu 0")
    if details and link["type"] not in ("can", "vcan"):
        print(f"    {link['type']} numtxqueues 1")
    if details and link["type"] == "vcan":
        print("    vcan numtxqueues 1 numrxqueues 1")
    if details and link["type"] == "can":
        print(f"    can state ERROR-ACTIVE restart-ms {link.get('restart_ms', 0)}")
        if link.get("bitrate"):
            print(f"    bitrate {link['bitrate']} sample-point 0.875")
elif args[:3] == ["link", "add", "dev"] and args[4:] == ["type", "vcan"]:
    if not (state["vcan"] and state["vcan_loaded"]):
        sys.exit("Error: Unknown device type.")
    state["links"][args[3]] = {"type": "vcan", "up": False}
elif args[:3] == ["link", "set", "dev"] and args[4] in ("up", "down"):
    state["links"][args[3]]["up"] = args[4] == "up"
elif args[:3] == ["link", "set", "dev"] and args[4:6] == ["type", "can"]:
    link = state["links"][args[3]]
    if link["up"]:
        sys.exit("RTNETLINK answers: Device or resource busy")
    link["bitrate"] = int(args[args.index("bitrate") + 1])
    link["restart_ms"] = int(args[args.index("restart-ms") + 1])
else:
    sys.exit(f"fake ip: unexpected {args}")
json.dump(state, open(state_path, "w"))
"""

FAKE_MODPROBE = r"""
import json, os, sys
state = json.load(open(os.environ["FAKE_STATE"]))
with open(os.environ["FAKE_CALLS"], "a") as calls:
    calls.write("modprobe " + " ".join(sys.argv[1:]) + "\n")
if not state["vcan"]:
    sys.exit("modprobe: FATAL: Module vcan not found in directory /lib/modules/x")
state["vcan_loaded"] = True
json.dump(state, open(os.environ["FAKE_STATE"], "w"))
"""


class FakeHost:
    """setup-can.sh against stand-ins for ip, modprobe and id (the real ones are never run)."""

    def __init__(self, tmp_path: Path, links: dict, vcan: bool = True, uid: int = 0) -> None:
        self.bin = tmp_path / "bin"
        self.bin.mkdir()
        self.state = tmp_path / "state.json"
        self.calls = tmp_path / "calls"
        self.state.write_text(json.dumps({"links": links, "vcan": vcan, "vcan_loaded": False}))
        for name, body in (("ip", FAKE_IP), ("modprobe", FAKE_MODPROBE)):
            (self.bin / name).write_text(f"#!{sys.executable}\n{body}")
            (self.bin / name).chmod(0o755)
        (self.bin / "id").write_text(f"#!/bin/sh\necho {uid}\n")
        (self.bin / "id").chmod(0o755)

    def run(self, *args: str) -> subprocess.CompletedProcess[str]:
        self.calls.write_text("")
        env = {
            **os.environ,
            "PATH": f"{self.bin}:/usr/bin:/bin",
            "FAKE_STATE": str(self.state),
            "FAKE_CALLS": str(self.calls),
        }
        return subprocess.run(
            ["sh", str(SETUP_CAN), *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
            check=False,
        )

    def links(self) -> dict:
        return json.loads(self.state.read_text())["links"]

    def changes(self) -> list[str]:
        """The calls that change something (not `ip link show`)."""
        lines = self.calls.read_text().splitlines()
        return [line for line in lines if " show " not in f" {line} "]


def test_setup_can_is_shellcheck_clean_and_executable() -> None:
    assert os.access(SETUP_CAN, os.X_OK)
    assert subprocess.run(["sh", "-n", str(SETUP_CAN)], check=False).returncode == 0
    if shutil.which("shellcheck") is None:
        pytest.skip("shellcheck is not installed")
    result = subprocess.run(
        ["shellcheck", str(SETUP_CAN)], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stdout


def test_setup_vcan_creates_then_leaves_alone(tmp_path: Path) -> None:
    host = FakeHost(tmp_path, links={})
    result = host.run("vcan")
    assert result.returncode == 0, result.stderr
    assert host.links() == {"vcan0": {"type": "vcan", "up": True}}
    assert host.changes() == [
        "modprobe vcan",
        "link add dev vcan0 type vcan",
        "link set dev vcan0 up",
    ]
    assert "vcan0 is up" in result.stdout

    again = host.run("vcan", "vcan0")
    assert again.returncode == 0 and "already up" in again.stdout
    assert host.changes() == []


def test_setup_vcan_without_kernel_support_says_what_to_do(tmp_path: Path) -> None:
    host = FakeHost(tmp_path, links={}, vcan=False)
    result = host.run("vcan", "vcan1")
    assert result.returncode == 1
    message = result.stderr
    assert "cannot create vcan1" in message and "kernel seems to have no vcan" in message
    assert "linux-modules-extra" in message and "udp_multicast" in message


def test_setup_without_root_asks_for_sudo(tmp_path: Path) -> None:
    host = FakeHost(tmp_path, links={}, uid=1000)
    result = host.run("vcan")
    assert result.returncode == 1 and "needs root: sudo" in result.stderr
    assert host.changes() == []


def test_setup_can0_sets_the_bitrate_then_leaves_alone(tmp_path: Path) -> None:
    host = FakeHost(
        tmp_path, links={"can0": {"type": "can", "up": True, "bitrate": 250000, "restart_ms": 0}}
    )
    result = host.run("can0")
    assert result.returncode == 0, result.stderr
    assert host.changes() == [
        "link set dev can0 down",
        "link set dev can0 type can bitrate 500000 restart-ms 100",
        "link set dev can0 up",
    ]
    assert host.links()["can0"] == {"type": "can", "up": True, "bitrate": 500000, "restart_ms": 100}
    assert "can0 is up at 500000 bit/s" in result.stdout

    again = host.run("can0", "500000")
    assert again.returncode == 0 and "already up" in again.stdout
    assert host.changes() == []

    other = host.run("can0", "1000000")
    assert other.returncode == 0 and host.links()["can0"]["bitrate"] == 1000000


@pytest.mark.parametrize(
    ("args", "status", "message"),
    [
        ((), 2, "usage:"),
        (("eth0",), 2, "usage:"),
        (("vcan", "vcan0", "extra"), 2, "usage:"),
        (("can0",), 1, "no interface can0: is the CAN adapter plugged in"),
        (("can1", "fast"), 1, "bit rate must be a number in bit/s"),
        (("can2",), 1, "can2 is not a CAN interface"),
        (("vcan", "can1"), 1, "can1 exists but is not a vcan interface"),
    ],
)
def test_setup_can_refuses_clearly(
    tmp_path: Path, args: tuple[str, ...], status: int, message: str
) -> None:
    host = FakeHost(
        tmp_path,
        links={"can1": {"type": "can", "up": False}, "can2": {"type": "dummy", "up": True}},
    )
    result = host.run(*args)
    assert result.returncode == status
    assert message in result.stderr
    assert host.changes() == []


# --- documents --------------------------------------------------------------------------------


def test_deploy_readme_indexes_every_file() -> None:
    index = (DEPLOY / "README.md").read_text()
    for path in sorted(DEPLOY.rglob("*")):
        if path.is_file() and path.name != "README.md":
            assert str(path.relative_to(DEPLOY)) in index, f"deploy/README.md lacks {path.name}"


def test_operator_guide_covers_every_abort_reason_and_the_envelope() -> None:
    guide = (DEPLOY / "OPERATOR-GUIDE.md").read_text()
    for reason in ABORT_REASONS:
        assert f"`{reason}`" in guide, f"the guide does not explain the abort reason {reason}"
    for field in fields(_SECTIONS["safety"]):
        assert field.name in guide
    for needed in ("dtid identify", "setup-can.sh", "parking brake", "neutral"):
        assert needed in guide


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("[safety]\nvehicle_timeout_s = 200\n", "vehicle_timeout_s = 200 is above 2"),
        ("[bus]\ntime_factor = 10\n[safety]\nvehicle_timeout_s = 5\n", None),  # 0.5 s of wall
        ("[safety]\nspeed_window_rpm = 1e9\n", "speed_window_rpm = 1e+09 is above 500"),
        ("[output]\nflush_period_s = 1e9\n", "flush_period_s = 1e+09 is above 10"),
        ("[bus]\ntime_factor = 1e9\n", "time_factor = 1e+09 is above 20"),
        ("[bus]\nbitrate = -5\n", "bitrate must be > 0, got -5"),
        ("[bus]\nbitrate = 500000000\n", "above 8000000 bit/s"),
        ("[bus]\nreceive_buffer_bytes = -1\n", "receive_buffer_bytes must be > 0"),
        ("[pipeline]\nblock_period_s = 2\n", "block_period_s = 2 is above 1"),
    ],
)
def test_a_value_no_test_can_run_with_is_refused(
    text: str, why: str | None, tmp_path: Path
) -> None:
    """A vehicle timeout typed in ms (200) kept a dead vehicle's chirp going for 22 s, which
    then ended "completed"; a window of 1e9 rpm switched the speed check off, a flush period
    of 1e9 s the crash safety, a time factor of 1e9 made the vehicle compute days of bus time
    in one step Ctrl-C could not stop. All were taken without a word."""
    path = tmp_path / "dtid.toml"
    path.write_text(text)
    if why is None:
        assert load_config(path).safety.vehicle_timeout_s == 5
        return
    with pytest.raises(ConfigError, match=re.escape(why)):
        load_config(path)
