"""Frequency responses of the crank-synchronous sensors and of the engine's torque hold.

Eq. (9): the speed sensor averages the angle-step speeds over N_win = 30 steps (half a
revolution) and reports rpm. Eq. (10): the mean torque arrives once per stroke and is held over
L = 2 speed samples. The engine itself delivers each stroke's mean torque over the whole stroke
(a continuous-time hold of one stroke period), which eq. (14) leaves in G_DRV; an analytic
transfer function compared with an estimated G_DRV must be multiplied by :func:`stroke_hold_gain`.
All speeds are the mean engine speed of the run, rpm; frequencies in Hz.
"""

from __future__ import annotations

import numpy as np

from dtid.simulator.angle_grid import (
    N_WIN,
    RPM_PER_RAD_S,
    STEPS_PER_SPEED_SAMPLE,
    STEPS_PER_STROKE,
    step_time,
)

HOLD_FACTOR = STEPS_PER_STROKE // STEPS_PER_SPEED_SAMPLE
"""L of eq. (10): speed samples per torque sample."""


def _dirichlet(omega_half_t: np.ndarray, n: int) -> np.ndarray:
    """|sin(n x) / (n sin x)|, with its limit 1 at x = 0."""
    x = np.asarray(omega_half_t, dtype=np.float64)
    num = np.sin(n * x)
    den = n * np.sin(x)
    small = np.abs(den) < 1e-12
    return np.abs(np.where(small, 1.0, num / np.where(small, 1.0, den)))


def speed_filter_gain(frequency_hz: np.ndarray, speed_rpm: float) -> np.ndarray:
    """|G_n| of eq. (9): moving average over N_win steps, rad/s -> rpm, rpm per rad/s."""
    half = np.pi * np.asarray(frequency_hz) * step_time(speed_rpm)
    return _dirichlet(half, N_WIN) * RPM_PER_RAD_S


def torque_hold_gain(frequency_hz: np.ndarray, speed_rpm: float) -> np.ndarray:
    """|G_p| of eq. (10): hold of the per-stroke torque over L = 2 speed samples, 1."""
    sample_time = STEPS_PER_SPEED_SAMPLE * step_time(speed_rpm)
    return _dirichlet(np.pi * np.asarray(frequency_hz) * sample_time, HOLD_FACTOR)


def stroke_hold_gain(frequency_hz: np.ndarray, speed_rpm: float) -> np.ndarray:
    """|sinc| of the engine's continuous hold of each stroke's torque over one stroke, 1."""
    stroke_time = STEPS_PER_STROKE * step_time(speed_rpm)
    return np.abs(np.sinc(np.asarray(frequency_hz) * stroke_time))
