"""Idle-speed controller of Fig. 1: a PI controller on the filtered engine speed."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dtid.errors import ConfigError


@dataclass(frozen=True)
class IdleController:
    """PI idle-speed controller, run by the ECU at every filtered-speed sample (every pi/2).

    The gains put the loop's crossover near 1 Hz for the reference vehicle (total inertia
    0.28 kg*m^2: kp ~ J * 2 pi * 1 Hz = 1.76 N*m/(rad/s) = 0.18 N*m/rpm), well below the
    drivetrain modes, at the low end of the chirp band, as on a production ECU; the integral
    corner sits at 0.2 Hz (ki = kp * 2 pi * 0.2 Hz).

    Attributes
    ----------
    setpoint_rpm
        Idle speed set-point n_setpoint, rpm.
    kp_nm_per_rpm
        Proportional gain, N*m/rpm.
    ki_nm_per_rpm_s
        Integral gain, N*m/(rpm*s).
    request_min_nm, request_max_nm
        Limits of the controller's torque request, N*m (the integrator stops at them).
    closed_loop
        False opens the loop: the request stays at its feed-forward value (the loss torque over
        the engine gain), as for the analytic comparison of an open-loop plant.
    """

    setpoint_rpm: float = 1000.0
    kp_nm_per_rpm: float = 0.18
    ki_nm_per_rpm_s: float = 0.23
    request_min_nm: float = -20.0
    request_max_nm: float = 120.0
    closed_loop: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.setpoint_rpm) and 300 <= self.setpoint_rpm <= 3000):
            raise ConfigError(
                f"idle set-point {self.setpoint_rpm} rpm is outside 300..3000 rpm"
            )
        if self.kp_nm_per_rpm < 0 or self.ki_nm_per_rpm_s < 0:
            raise ConfigError("idle controller gains must be >= 0")
        if self.request_max_nm <= self.request_min_nm:
            raise ConfigError("idle controller: request_max_nm must exceed request_min_nm")

    def as_array(self) -> np.ndarray:
        """Return the settings as the float64 array the simulator kernel takes."""
        return np.array(
            [
                self.setpoint_rpm,
                self.kp_nm_per_rpm,
                self.ki_nm_per_rpm_s,
                self.request_min_nm,
                self.request_max_nm,
                1.0 if self.closed_loop else 0.0,
            ]
        )
