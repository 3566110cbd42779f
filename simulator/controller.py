"""Idle-speed controller of Fig. 1: a PI(D) controller on the filtered engine speed, with the
ECU's timing (how many speed samples its output and the stroke's latch lag)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dtid.errors import ConfigError
from dtid.simulator.kernel import N_RING


@dataclass(frozen=True)
class IdleController:
    """Idle-speed controller, run by the ECU at every filtered-speed sample (every pi/2).

    The product's own ECU (the defaults) is a PI whose gains put the loop's crossover near 1 Hz
    for the reference vehicle (total inertia 0.28 kg*m^2: kp ~ J * 2 pi * 1 Hz = 1.76
    N*m/(rad/s) = 0.18 N*m/rpm), well below the drivetrain modes, at the low end of the chirp
    band; the integral corner sits at 0.2 Hz (ki = kp * 2 pi * 0.2 Hz). Vehicles differ: other
    gains, a derivative term, an output that reaches the request some samples later, a stroke
    that latches an older or newer request. The identification assumes none of this of a
    recording (:mod:`dtid.identification.model.idle_loop`); the simulator draws it to make test
    vehicles.

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
    kd_nm_per_rpm_s
        Derivative gain on the measured speed, N*m/(rpm/s) (0: a PI).
    derivative_tau_s
        Time constant of the derivative's first-order filter, s.
    delay_samples
        Speed samples (pi/2 each) between the controller's computing an output and its reaching
        the torque request (0..7).
    latch_samples
        Which request a starting stroke takes: the one formed this many speed samples before
        the stroke's start (1, the product ECU: the request formed pi/2 before; 0: the one
        formed at the stroke's start; 0..7).
    error_tau_s
        Time constant of a first-order low-pass on the speed error the P and I terms act on, s
        (0: none).
    """

    setpoint_rpm: float = 1000.0
    kp_nm_per_rpm: float = 0.18
    ki_nm_per_rpm_s: float = 0.23
    request_min_nm: float = -20.0
    request_max_nm: float = 120.0
    closed_loop: bool = True
    kd_nm_per_rpm_s: float = 0.0
    derivative_tau_s: float = 0.02
    delay_samples: int = 0
    latch_samples: int = 1
    error_tau_s: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.setpoint_rpm) and 300 <= self.setpoint_rpm <= 3000):
            raise ConfigError(f"idle set-point {self.setpoint_rpm} rpm is outside 300..3000 rpm")
        if min(self.kp_nm_per_rpm, self.ki_nm_per_rpm_s, self.kd_nm_per_rpm_s) < 0:
            raise ConfigError("idle controller gains must be >= 0")
        if not self.derivative_tau_s > 0 or not self.error_tau_s >= 0:
            raise ConfigError("idle controller: derivative_tau_s must be > 0 and error_tau_s >= 0")
        for name in ("delay_samples", "latch_samples"):
            value = getattr(self, name)
            if not (isinstance(value, int) and 0 <= value < N_RING):
                raise ConfigError(
                    f"idle controller: {name} must be an integer in 0..{N_RING - 1}, got {value!r}"
                )
        if self.request_max_nm <= self.request_min_nm:
            raise ConfigError("idle controller: request_max_nm must exceed request_min_nm")

    def as_array(self) -> np.ndarray:
        """Return the settings as the float64 array the simulator kernel takes (``C_*``)."""
        return np.array(
            [
                self.setpoint_rpm,
                self.kp_nm_per_rpm,
                self.ki_nm_per_rpm_s,
                self.request_min_nm,
                self.request_max_nm,
                1.0 if self.closed_loop else 0.0,
                self.kd_nm_per_rpm_s,
                self.derivative_tau_s,
                float(self.delay_samples),
                float(self.latch_samples),
                self.error_tau_s,
            ]
        )

    def reference(self) -> np.ndarray:
        """The kernel's reference of a vehicle's own ECU: its set-point, rpm, throughout."""
        return np.array([self.setpoint_rpm])
