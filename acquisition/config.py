"""Configuration of a vehicle test: bus, vehicle interface, test sequence, safety, pipeline.

One TOML file (``deploy/dtid.example.toml`` documents every key) configures ``dtid acquire``,
``dtid worker`` and ``dtid vehicle``; every section and key is optional and falls back to the
defaults below. An unknown section or key, or a value of the wrong type or range, is a
:class:`dtid.errors.ConfigError` naming it.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from dtid.acquisition.clock import MAX_TIME_FACTOR
from dtid.acquisition.plan import PLAN_FILE_KEYS, TestPlan, in_rounds, plan_from_file
from dtid.acquisition.recorder import SUFFIXES
from dtid.errors import ConfigError


def default_runtime_dir() -> Path:
    """Directory of the local (ipc) ZeroMQ endpoints: ``$XDG_RUNTIME_DIR/dtid`` or /tmp."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    return Path(runtime) / "dtid" if runtime else Path(f"/tmp/dtid-{os.getuid()}")


@dataclass(frozen=True)
class BusConfig:
    """The python-can bus.

    Attributes
    ----------
    interface, channel
        python-can interface and channel: ``socketcan``/``vcan0`` on a laptop, ``can0`` in a
        vehicle; ``udp_multicast`` with an IPv4 group only inside a private network namespace.
    bitrate
        Bit rate, bit/s (for interfaces that set it; SocketCAN takes it from ``ip link``).
    time_factor
        Bus time per wall time. 1 on a vehicle; > 1 only with a virtual vehicle run faster than
        real time (``dtid vehicle --speedup``): the daemon then stretches receive times by it, so
        the recording carries the test's own time base.
    receive_buffer_bytes
        Socket receive buffer asked for on interfaces that have one (udp_multicast), bytes.
    options
        Further keyword arguments of ``can.Bus`` (e.g. ``port`` of udp_multicast).
    """

    interface: str = "socketcan"
    channel: str = "vcan0"
    bitrate: int = 500_000
    time_factor: float = 1.0
    receive_buffer_bytes: int = 4 << 20
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class InterfaceConfig:
    """DBC and signal map; None selects the product's own."""

    dbc: Path | None = None
    signals: Path | None = None


@dataclass(frozen=True)
class SafetyConfig:
    """The safety envelope of the test (see deploy/OPERATOR-GUIDE.md).

    Attributes
    ----------
    max_amplitude_nm
        Largest test torque the daemon will ever request, N*m; a plan above it is refused.
    speed_window_rpm
        Abort when the filtered speed leaves the idle set-point (the mean speed over the settle
        phase) by more than this, rpm.
    vehicle_timeout_s
        Abort when no speed frame arrives for this long (bus time), s.
    """

    max_amplitude_nm: float = 20.0
    speed_window_rpm: float = 250.0
    vehicle_timeout_s: float = 0.2


@dataclass(frozen=True)
class OutputConfig:
    """Where a test's files go.

    Attributes
    ----------
    directory
        One sub-directory per test session is made here, holding the raw log and the results.
    log_format
        Extension of the raw CAN log: ``blf`` (default), ``asc``, ``log`` (candump) or ``mf4``
        (ASAM MDF 4, written from a crash-safe BLF journal when the session ends).
    flush_period_s
        Longest time (wall) a received frame may stay unwritten in the log, s.
    vehicle
        The vehicle's name or VIN, written into each session's metadata (``dtid batch`` groups
        a fleet's tests by it); empty: not said.
    """

    directory: Path = Path("dtid-runs")
    log_format: str = "blf"
    flush_period_s: float = 0.5
    vehicle: str = ""


@dataclass(frozen=True)
class PipelineConfig:
    """ZeroMQ endpoints between daemon and worker.

    Attributes
    ----------
    blocks
        Daemon PUB of the event stream (:mod:`dtid.acquisition.stream`).
    replay
        Daemon REP that hands out kept events from a sequence number on.
    results
        Worker PUB of progress, FRFs and results.
    block_period_s
        Longest time (wall) a decoded sample waits in the daemon before its block is sent, s.
    keys
        Folder of the ZeroMQ CURVE keys (``dtid keys DIR``), required by any ``tcp://``
        endpoint other than loopback (:mod:`dtid.acquisition.security`); None: none.
    """

    blocks: str = ""
    replay: str = ""
    results: str = ""
    block_period_s: float = 0.002
    keys: Path | None = None

    def __post_init__(self) -> None:
        runtime = default_runtime_dir()
        for name in ("blocks", "replay", "results"):
            if not getattr(self, name):
                object.__setattr__(self, name, f"ipc://{runtime}/{name}")


@dataclass(frozen=True)
class WorkerConfig:
    """What ``dtid worker`` does besides the identification.

    Attributes
    ----------
    diagnose
        After the validation chirp, diagnose the identified model (``dtid diagnose``: does it
        explain the recordings, and where not), publish the diagnosis on ``[pipeline] results``
        (topic ``diagnosis``) and write ``diagnosis.json`` beside the session's log.
    plan_follow_up
        After the identification, plan the follow-up test at the identified parameters with the
        session's runs counted in (``dtid plan --prior identification.json --after LOG``),
        publish it (topic ``plan``) and write ``follow-up.json`` beside the session's log: the
        precision the session reached and, unless that meets every target, the test that would
        (``[test] plan = "follow-up.json"`` runs it).
    """

    diagnose: bool = False
    plan_follow_up: bool = False


@dataclass(frozen=True)
class CampaignConfig:
    """The adaptive test (``[test] adaptive``, ``max_time_s``, ``targets``, ``replan_wait_s``).

    With ``adaptive = true`` ``dtid acquire`` runs the ``[test]`` plan as the first round of a
    campaign (:mod:`dtid.acquisition.campaign`); after each round the worker identifies every
    round so far together and plans the next at what it identified, and the daemon runs it,
    until the recorded runs meet the targets or the next round would exceed the time budget.

    Attributes
    ----------
    adaptive
        Run rounds until the targets are met (True) or one test only (False, the default).
    max_time_s
        Budget of the whole campaign's test time (bus time, every round's settle, chirps and
        pauses), s.
    targets
        Precision targets, % at 2 sigma, by parameter name, over the defaults of ``dtid plan``
        (0 drops one); empty: the defaults.
    replan_wait_s
        Longest wall time the daemon waits, engine at idle and no test torque, for the worker's
        plan of the next round, s.
    """

    adaptive: bool = False
    max_time_s: float = 1800.0
    targets: dict[str, float] = field(default_factory=dict)
    replan_wait_s: float = 3600.0


CAMPAIGN_KEYS = ("adaptive", "max_time_s", "targets", "replan_wait_s")
"""Keys of ``[test]`` that configure the campaign rather than one test's plan."""


@dataclass(frozen=True)
class AcquisitionConfig:
    """The whole configuration file."""

    bus: BusConfig = field(default_factory=BusConfig)
    vehicle_interface: InterfaceConfig = field(default_factory=InterfaceConfig)
    test: TestPlan = field(default_factory=TestPlan)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    worker: WorkerConfig = field(default_factory=WorkerConfig)
    campaign: CampaignConfig = field(default_factory=CampaignConfig)

    def __post_init__(self) -> None:
        _check(self)

    def with_changes(self, section: str, **changes: Any) -> AcquisitionConfig:
        """A copy with keys of one section replaced (for command-line overrides)."""
        return replace(self, **{section: replace(getattr(self, section), **changes)})


_SECTIONS = {
    "bus": BusConfig,
    "vehicle_interface": InterfaceConfig,
    "test": TestPlan,
    "safety": SafetyConfig,
    "output": OutputConfig,
    "pipeline": PipelineConfig,
    "worker": WorkerConfig,
}


def _convert(where: str, default: Any, value: Any, base: Path) -> Any:
    """Check a TOML value against the type of its default; resolve paths against ``base``."""
    if default is None or isinstance(default, Path):
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a file path, got {value!r}")
        return base / Path(value).expanduser() if value else None
    if isinstance(default, tuple):
        if not isinstance(value, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in value
        ):
            raise ConfigError(f"{where}: expected a list of numbers, got {value!r}")
        return tuple(float(v) for v in value)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if isinstance(default, float):
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if isinstance(default, int):
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if isinstance(default, dict):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return dict(value)
    if not isinstance(value, str):
        raise ConfigError(f"{where}: expected a string, got {value!r}")
    return value


MAX_VEHICLE_TIMEOUT_WALL_S = 2.0
"""Longest ``[safety] vehicle_timeout_s`` in wall time (bus time over ``[bus] time_factor``), s:
a speed frame comes every crank event (15 ms at idle), and a daemon that goes on requesting test
torque for seconds from a vehicle it no longer hears is not in control (200, a timeout typed in
ms, kept a dead vehicle's chirp going for 22 s and ended "completed")."""
MAX_SPEED_WINDOW_RPM = 500.0
"""Widest ``[safety] speed_window_rpm``: half a 1000 rpm idle; a wider window lets the engine all
but stall, or run away, before the abort."""
MAX_FLUSH_PERIOD_S = 10.0
"""Longest ``[output] flush_period_s``: the frames a crash can cost."""
MAX_BLOCK_PERIOD_S = 1.0
"""Longest ``[pipeline] block_period_s``: the worker's and monitor's lag behind the bus."""
MAX_BITRATE = 8_000_000
"""Highest ``[bus] bitrate``, bit/s (CAN FD's data phase)."""


def _check(config: AcquisitionConfig) -> None:
    """Range checks that need more than a type."""
    positive = {
        "bus": ("time_factor",),
        "test": ("f1_hz", "f2_hz", "duration_s", "request_period_s"),
        "safety": ("max_amplitude_nm", "speed_window_rpm", "vehicle_timeout_s"),
        "output": ("flush_period_s",),
        "pipeline": ("block_period_s",),
    }
    for section, names in positive.items():
        for name in names:
            value = getattr(getattr(config, section), name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"[{section}] {name} must be > 0, got {value}")
    factor = config.bus.time_factor
    upper = {
        ("bus", "time_factor"): (MAX_TIME_FACTOR, "beyond, the host sets the test's timing"),
        ("safety", "vehicle_timeout_s"): (
            MAX_VEHICLE_TIMEOUT_WALL_S * factor,
            "check the unit: seconds of bus time",
        ),
        ("safety", "speed_window_rpm"): (MAX_SPEED_WINDOW_RPM, "a stall would pass unnoticed"),
        ("output", "flush_period_s"): (MAX_FLUSH_PERIOD_S, "a crash would cost that much"),
        ("pipeline", "block_period_s"): (MAX_BLOCK_PERIOD_S, "check the unit: seconds"),
    }
    for (section, name), (limit, why) in upper.items():
        value = getattr(getattr(config, section), name)
        if value > limit:
            raise ConfigError(f"[{section}] {name} = {value:g} is above {limit:g}: {why}")
    for name in ("bitrate", "receive_buffer_bytes"):
        if getattr(config.bus, name) <= 0:
            raise ConfigError(f"[bus] {name} must be > 0, got {getattr(config.bus, name)}")
    if config.bus.bitrate > MAX_BITRATE:
        raise ConfigError(
            f"[bus] bitrate = {config.bus.bitrate} is above {MAX_BITRATE} bit/s, CAN FD's fastest"
        )
    for name in ("max_time_s", "replan_wait_s"):
        value = getattr(config.campaign, name)
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"[test] {name} must be > 0, got {value}")
    for name, percent in config.campaign.targets.items():
        if not isinstance(percent, int | float) or isinstance(percent, bool) or percent < 0:
            raise ConfigError(f"[test] targets: {name} must be a percentage >= 0, got {percent!r}")
    formats = [suffix[1:] for suffix in SUFFIXES]
    if config.output.log_format not in formats:
        raise ConfigError(
            f"[output] log_format must be one of {', '.join(map(repr, formats))}, got "
            f"{config.output.log_format!r}"
        )
    test = config.test
    if not test.amplitudes_nm:
        raise ConfigError("[test] amplitudes_nm needs at least one amplitude")
    largest = max((*test.amplitudes_nm, test.validation_nm))
    if largest > config.safety.max_amplitude_nm:
        raise ConfigError(
            f"[test] amplitude {largest:g} N*m exceeds [safety] max_amplitude_nm = "
            f"{config.safety.max_amplitude_nm:g} N*m; lower the amplitude or, if the vehicle "
            "allows it, raise the cap"
        )


def _test_section(path: Path, values: dict[str, Any]) -> dict[str, Any]:
    """``[test]`` with its ``plan`` file and ``repeats`` resolved into :class:`TestPlan` keys.

    ``plan = "plan.json"`` takes the amplitudes, repeats, duration, band and validation chirp of
    a ``dtid plan --json`` file (those keys may then not be given as well); ``repeats`` (an
    integer, or one per amplitude) repeats ``amplitudes_nm`` in rounds
    (:func:`dtid.acquisition.plan.in_rounds`).
    """
    where = f"{path}: [test]"
    if "plan" in values:
        file = values.pop("plan")
        if not isinstance(file, str) or not file:
            raise ConfigError(f"{where} plan: expected the path of a dtid plan JSON file")
        clash = [key for key in (*PLAN_FILE_KEYS, "settle_s", "pause_s") if key in values]
        if clash:
            raise ConfigError(
                f"{where}: {clash[0]!r} and plan are both given; the plan file sets it "
                "(remove one of them)"
            )
        period = values.get("request_period_s", TestPlan().request_period_s)
        plan = plan_from_file(path.parent / Path(file).expanduser(), period)
        values.update(plan.as_dict())
    if "repeats" in values:
        repeats = values.pop("repeats")
        amplitudes = values.get("amplitudes_nm", list(TestPlan().amplitudes_nm))
        if not isinstance(amplitudes, list):
            raise ConfigError(f"{where} amplitudes_nm: expected a list of numbers")
        try:
            values["amplitudes_nm"] = list(in_rounds(amplitudes, repeats))
        except (ConfigError, TypeError, ValueError) as error:
            raise ConfigError(f"{where} {error}") from None
    return values


def load_config(path: str | os.PathLike[str] | None) -> AcquisitionConfig:
    """Read a configuration file; None gives the defaults.

    Relative paths in ``[vehicle_interface]`` and ``[output]`` are taken from the file's folder.

    Raises
    ------
    ConfigError
        If the file cannot be read or holds an unknown or invalid key.
    """
    if path is None:
        return AcquisitionConfig()
    path = Path(path)
    try:
        document = tomllib.loads(path.read_text())
    except OSError as error:
        raise ConfigError(f"cannot read configuration {path}: {error.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path} is not valid TOML: {error}") from None
    sections = {}
    if isinstance(document.get("test"), dict):
        test = dict(document["test"])
        campaign = {key: test.pop(key) for key in CAMPAIGN_KEYS if key in test}
        defaults = CampaignConfig()
        sections["campaign"] = CampaignConfig(
            **{
                key: _convert(f"{path}: [test] {key}", getattr(defaults, key), value, path.parent)
                for key, value in campaign.items()
            }
        )
        document["test"] = _test_section(path, test)
    for section, values in document.items():
        if section not in _SECTIONS:
            raise ConfigError(f"{path}: unknown section [{section}]; known: {', '.join(_SECTIONS)}")
        if not isinstance(values, dict):
            raise ConfigError(f"{path}: [{section}] must be a table")
        cls = _SECTIONS[section]
        defaults = cls()
        known = {f.name for f in fields(cls) if f.init}
        converted = {}
        for key, value in values.items():
            if key not in known:
                if section == "test":
                    known |= set(CAMPAIGN_KEYS)
                raise ConfigError(
                    f"{path}: unknown key '{key}' in [{section}]; known: {', '.join(sorted(known))}"
                )
            converted[key] = _convert(
                f"{path}: [{section}] {key}", getattr(defaults, key), value, path.parent
            )
        try:
            sections[section] = cls(**converted)
        except ConfigError as error:
            raise ConfigError(f"{path}: [{section}] {error}") from None
    return AcquisitionConfig(**sections)
