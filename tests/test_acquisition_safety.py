"""The safety envelope: set-point from the settle phase, speed window, vehicle timeout."""

from __future__ import annotations

import numpy as np

from dtid.acquisition.config import SafetyConfig
from dtid.acquisition.safety import SafetyMonitor

CONFIG = SafetyConfig(speed_window_rpm=100.0, vehicle_timeout_s=0.2)
T0 = 1000.0


def monitor(settle_s: float = 1.0) -> SafetyMonitor:
    return SafetyMonitor(CONFIG, T0, settle_s)


def feed(safety: SafetyMonitor, times: list[float], rpm: list[float]) -> str | None:
    return safety.on_speed(np.asarray(times, dtype=float) + T0, np.asarray(rpm, dtype=float))


def test_setpoint_is_the_mean_over_the_settle_phase() -> None:
    safety = monitor()
    assert feed(safety, [0.1, 0.5, 0.9], [950.0, 1000.0, 1050.0]) is None
    assert safety.setpoint_rpm is None  # the settle phase is not over yet
    assert feed(safety, [1.1], [1000.0]) is None
    assert safety.setpoint_rpm == 1000.0


def test_speed_outside_the_window_aborts() -> None:
    safety = monitor()
    feed(safety, [0.5, 1.1, 1.2], [900.0, 900.0, 900.0])  # set-point 900
    assert feed(safety, [1.3, 1.4], [995.0, 995.0]) is None
    assert feed(safety, [1.5, 1.6], [1005.0, 1005.0]) == "speed_window"


def test_speed_below_the_window_aborts_in_the_same_block_as_the_settle_end() -> None:
    safety = monitor()
    assert feed(safety, [0.5, 0.9, 1.1, 1.2, 1.3], [1000.0, 1000.0, 880.0, 880.0, 880.0]) == (
        "speed_window"
    )


def test_one_corrupted_sample_does_not_abort() -> None:
    safety = monitor()
    feed(safety, [0.5, 1.1, 1.2], [1000.0, 1000.0, 1000.0])
    assert feed(safety, [1.3, 1.4, 1.5], [8000.0, 1000.0, 1000.0]) is None
    assert feed(safety, [1.6], [0.0]) is None


def test_speed_during_the_settle_phase_is_not_checked() -> None:
    safety = monitor()
    assert feed(safety, [0.1, 0.2, 0.3], [3000.0, 3000.0, 3000.0]) is None


def test_without_settle_phase_the_first_sample_is_the_setpoint() -> None:
    safety = monitor(settle_s=0.0)
    assert feed(safety, [0.1, 0.2, 0.3], [1000.0, 1050.0, 1090.0]) is None
    assert safety.setpoint_rpm == 1000.0
    assert feed(safety, [0.4, 0.5], [1150.0, 1150.0]) == "speed_window"


def test_vehicle_timeout_from_the_last_speed_sample() -> None:
    safety = monitor()
    assert safety.check_timeout(T0 + 0.15) is None
    assert safety.check_timeout(T0 + 0.25) == "vehicle_timeout"  # nothing since the start
    feed(safety, [0.3], [1000.0])
    assert safety.check_timeout(T0 + 0.45) is None
    assert safety.check_timeout(T0 + 0.55) == "vehicle_timeout"
