"""The test plan: the chirps of paper eq. (11) at idle, and the requests that carry them.

One definition for every side of the test: the daemon's ``[test]`` section is a
:class:`TestPlan`, the daemon sends its requests (:func:`tool_requests`), and the simulator plays
the same plan (its kernel evaluates :func:`requested_test_torque`). The test torque is requested
by the tool over CAN at a fixed rate (``request_period_s``); the engine ECU holds the last request
it received. :func:`requested_test_torque` evaluates exactly that held value, so the simulator
and the frames written for the tool's messages agree sample for sample.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numba
import numpy as np

from dtid.acquisition.metadata import SCHEMA as METADATA_SCHEMA
from dtid.errors import ConfigError

MAX_TEST_S = 3600.0
"""Longest test a plan may describe, s: an hour at idle holds any chirp test worth running (the
paper's takes 3 minutes); a longer one is a slip of the unit (``--duration 1e6``), which the
simulator would otherwise compute for days."""

CHIRP_COLUMNS = ("start_s", "duration_s", "f1_hz", "f2_hz", "amplitude_nm")
"""Columns of the chirp schedule array the simulator kernel takes."""


@dataclass(frozen=True)
class Chirp:
    """One linear chirp of eq. (11): A sin(2 pi (f1 tau + (f2 - f1) tau^2 / (2 T_D))).

    Attributes
    ----------
    start_s
        Test time at which the chirp starts (tau = 0), s.
    duration_s
        T_D, s.
    f1_hz, f2_hz
        Start and end frequency, Hz.
    amplitude_nm
        A_test, N*m.
    """

    start_s: float
    duration_s: float
    f1_hz: float
    f2_hz: float
    amplitude_nm: float

    @property
    def end_s(self) -> float:
        """Test time at which the chirp ends, s."""
        return self.start_s + self.duration_s


@dataclass(frozen=True)
class TestPlan:
    """A chirp test at idle: settle, then one chirp per amplitude with a pause between them.

    The defaults are the paper's test: 5 and 10 N*m identify, then 2 N*m validates, each swept
    from 1 to 15 Hz, the band measurable at 1000 rpm below the 16.7 Hz Nyquist frequency of the
    once-per-stroke mean torque. 60 s per chirp gives about 15 Welch segments of 4 s (0.25 Hz
    resolution) per run. The 3 s pauses let the idle controller settle; the tool sends its
    request at 100 Hz, well above the band. The daemon's ``[test]`` section holds these fields.

    Attributes
    ----------
    amplitudes_nm
        A_test of the identification chirps, chirped in this order, N*m.
    validation_nm
        A_test of the validation chirp after them, N*m; 0 for none. (Which runs identify is
        the identification's choice: by default the two largest amplitudes.)
    f1_hz, f2_hz
        Chirp start and end frequency, Hz.
    duration_s
        T_D of each chirp, s.
    settle_s
        Time at idle before the first chirp, s.
    pause_s
        Time at idle between chirps and after the last one, s.
    request_period_s
        Period of the tool's test-torque request frames, s.
    """

    __test__ = False  # not a pytest test class, despite the name

    amplitudes_nm: tuple[float, ...] = (5.0, 10.0)
    validation_nm: float = 2.0
    f1_hz: float = 1.0
    f2_hz: float = 15.0
    duration_s: float = 60.0
    settle_s: float = 3.0
    pause_s: float = 3.0
    request_period_s: float = 0.01
    chirps: tuple[Chirp, ...] = field(init=False)

    def __post_init__(self) -> None:
        if not self.amplitudes_nm:
            raise ConfigError("a test plan needs at least one chirp amplitude")
        for name in ("f1_hz", "f2_hz", "duration_s", "request_period_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"test plan: {name} must be > 0, got {value}")
        for name in ("settle_s", "pause_s"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ConfigError(f"test plan: {name} must be >= 0, got {getattr(self, name)}")
        for amplitude in self.amplitudes_nm:
            if not (math.isfinite(amplitude) and amplitude > 0):
                raise ConfigError(f"test plan: chirp amplitudes must be > 0 N*m, got {amplitude}")
        if not (math.isfinite(self.validation_nm) and self.validation_nm >= 0):
            raise ConfigError(
                f"test plan: validation_nm must be >= 0 N*m (0: none), got {self.validation_nm}"
            )
        if self.f2_hz <= self.f1_hz:
            raise ConfigError(f"test plan: f2 ({self.f2_hz} Hz) must be above f1 ({self.f1_hz} Hz)")
        if self.f2_hz >= 0.5 / self.request_period_s:
            raise ConfigError(
                f"test plan: f2 = {self.f2_hz} Hz is not below the Nyquist frequency of a "
                f"request every {self.request_period_s} s"
            )
        if self.duration_s * self.f1_hz < 1:
            raise ConfigError(
                f"test plan: a chirp of {self.duration_s:g} s holds less than one period of its "
                f"start frequency {self.f1_hz:g} Hz; give a duration of at least "
                f"{1 / self.f1_hz:g} s (the paper's is 60 s)"
            )
        length = self.settle_s + len(self.levels) * (self.duration_s + self.pause_s)
        if length > MAX_TEST_S:
            raise ConfigError(
                f"test plan: its {len(self.levels)} chirps of {self.duration_s:g} s with their "
                f"pauses take {length:g} s, more than the {MAX_TEST_S:g} s a test at idle may "
                "(check the unit: durations are in seconds)"
            )
        chirps = []
        start = self.settle_s
        for amplitude in self.levels:
            chirps.append(Chirp(start, self.duration_s, self.f1_hz, self.f2_hz, float(amplitude)))
            start += self.duration_s + self.pause_s
        object.__setattr__(self, "chirps", tuple(chirps))

    def as_dict(self) -> dict[str, object]:
        """The plan's fields (the ``[test]`` keys; amplitudes as a list), for JSON."""
        return {
            f.name: list(getattr(self, f.name))
            if f.name == "amplitudes_nm"
            else getattr(self, f.name)
            for f in fields(self)
            if f.init
        }

    @property
    def levels(self) -> tuple[float, ...]:
        """The amplitude of every chirp in the order they run (the validation chirp last), N*m."""
        validation = (float(self.validation_nm),) if self.validation_nm else ()
        return tuple(float(a) for a in self.amplitudes_nm) + validation

    @property
    def end_s(self) -> float:
        """Duration of the whole test, s."""
        return self.chirps[-1].end_s + self.pause_s

    def schedule(self) -> np.ndarray:
        """Return the chirps as an array of shape (n, 5), columns :data:`CHIRP_COLUMNS`."""
        return np.array(
            [[c.start_s, c.duration_s, c.f1_hz, c.f2_hz, c.amplitude_nm] for c in self.chirps],
            dtype=np.float64,
        )


def in_rounds(amplitudes_nm: Sequence[float], repeats: int | Sequence[int]) -> tuple[float, ...]:
    """Chirp amplitudes of a test that repeats each level: in rounds, each round ascending
    (5, 10, 5, 10, 10 for levels 5 and 10 repeated 2 and 3 times), so a drift of the idle over
    the test spreads over every level alike, N*m.

    Raises
    ------
    ConfigError
        If ``repeats`` is not a positive integer or one per level.
    """
    levels = [float(a) for a in amplitudes_nm]
    counts = [repeats] * len(levels) if isinstance(repeats, int) else list(repeats)
    if len(counts) != len(levels) or not all(
        isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in counts
    ):
        raise ConfigError(
            f"repeats must be a positive integer or one per amplitude ({len(levels)}), got "
            f"{repeats!r}"
        )
    order = sorted(range(len(levels)), key=lambda i: levels[i])
    return tuple(levels[i] for r in range(max(counts)) for i in order if r < counts[i])


PLAN_FILE_KEYS = ("amplitudes_nm", "repeats", "duration_s", "f1_hz", "f2_hz", "validation_nm")
"""Keys of a plan file's ``plan`` entry (``dtid plan --json``) that the test takes; ``settle_s``
and ``pause_s`` are taken too when present."""


def plan_from_file(path: str | Path, request_period_s: float = 0.01) -> TestPlan:
    """The test plan of a ``dtid plan --json`` file (its ``plan`` entry).

    Raises
    ------
    ConfigError
        If the file cannot be read, is not JSON, or its ``plan`` lacks a key or holds a bad value.
    """
    return plan_from_document(_plan_document(path), f"plan file {path}", request_period_s)


def planned_setpoint(path: str | Path) -> float | None:
    """The idle speed a ``dtid plan --json`` file's prediction assumed (its plan's
    ``setpoint_rpm``), rpm; None where it names none.

    Raises
    ------
    ConfigError
        If the file cannot be read or is not JSON.
    """
    document = _plan_document(path)
    entry = document.get("plan") if isinstance(document, dict) else None
    value = entry.get("setpoint_rpm") if isinstance(entry, dict) else None
    return float(value) if isinstance(value, int | float) else None


def _plan_document(path: str | Path) -> object:
    """The JSON document of a plan file, or ConfigError naming why it cannot be read."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except OSError as error:
        raise ConfigError(f"cannot read the plan file {path}: {error.strerror}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"plan file {path} is not JSON: {error}") from None


def plan_from_document(document: object, where: str, request_period_s: float = 0.01) -> TestPlan:
    """The test plan of a ``dtid plan --json`` document (its ``plan`` entry); ``where`` names
    the document in messages.

    Raises
    ------
    ConfigError
        If the document has no ``plan`` entry, or it lacks a key or holds a bad value.
    """
    entry = document.get("plan") if isinstance(document, dict) else None
    if not isinstance(entry, dict):
        raise ConfigError(f"{where} has no 'plan' entry; write one with dtid plan --json")
    if document.get("schema") == METADATA_SCHEMA:
        raise ConfigError(
            f"{where} is a recording's metadata (the plan it was recorded with, without its "
            "repeats); give the file dtid plan --json wrote"
        )
    missing = [key for key in PLAN_FILE_KEYS if key not in entry]
    if missing:
        raise ConfigError(f"{where}: its plan has no {missing[0]!r}")
    if entry.get("sweep", "linear") != "linear":
        raise ConfigError(
            f"{where}: its plan's sweep is {entry['sweep']!r}; the test sweeps linearly "
            '(eq. 11): "linear"'
        )
    numbers = {}
    for key in ("duration_s", "f1_hz", "f2_hz", "validation_nm", "settle_s", "pause_s"):
        if key in entry:
            value = entry[key]
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(f"{where}: its plan's {key} is {value!r}, not a number")
            numbers[key] = float(value)
    try:
        amplitudes = in_rounds([float(a) for a in entry["amplitudes_nm"]], entry["repeats"])
        return TestPlan(amplitudes_nm=amplitudes, request_period_s=request_period_s, **numbers)
    except (TypeError, ValueError, ConfigError) as error:
        raise ConfigError(f"{where}: {error}") from None


@numba.njit(cache=True)
def requested_test_torque(t: float, schedule: np.ndarray, request_period: float) -> float:
    """Test torque the ECU holds at time ``t``: the chirp at the last request instant, N*m.

    Parameters
    ----------
    t
        Test time, s.
    schedule
        Chirp schedule, shape (n, 5), columns :data:`CHIRP_COLUMNS`.
    request_period
        Period of the tool's request frames, s; requests are sent at multiples of it.
    """
    t_request = math.floor(t / request_period + 1e-9) * request_period
    for row in range(schedule.shape[0]):
        tau = t_request - schedule[row, 0]
        duration = schedule[row, 1]
        if 0.0 <= tau < duration:
            f1 = schedule[row, 2]
            f2 = schedule[row, 3]
            phase = 2.0 * math.pi * (f1 * tau + (f2 - f1) * tau * tau / (2.0 * duration))
            return schedule[row, 4] * math.sin(phase)
    return 0.0


@numba.njit(cache=True)
def requested_test_torques(
    times: np.ndarray, schedule: np.ndarray, request_period: float
) -> np.ndarray:
    """:func:`requested_test_torque` at each of ``times`` (s), N*m."""
    out = np.empty(times.shape[0])
    for i in range(times.shape[0]):
        out[i] = requested_test_torque(times[i], schedule, request_period)
    return out


def tool_requests(plan: TestPlan) -> tuple[np.ndarray, np.ndarray]:
    """The tool's test-torque requests over the whole test: times, s, and values, N*m."""
    times = np.arange(0.0, plan.end_s, plan.request_period_s)
    return times, requested_test_torques(times, plan.schedule(), plan.request_period_s)
