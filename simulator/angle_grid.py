"""The crank-angle grid every piece of the plant and its sensors is sampled on (paper eq. 8).

The plant is integrated in the crank-angle domain with a fixed angle step, so everything that is
periodic in crank angle (the engine torque of eqs. 1-5) is a table lookup, and the crank-synchronous
sensors of section II-C fire on fixed step counts.
"""

import math

from dtid.dbc.roles import SPEED_SAMPLES_PER_REVOLUTION

STEP_RAD = math.pi / 30
"""Angle step phi_s of eq. (8), rad: 1 ms at 1000 rpm."""

N_CYL = 4
"""Cylinders of the four-stroke engine; one fires every pi of crank angle."""

STEPS_PER_CYCLE = 120
"""Steps in one working cycle of 4*pi rad."""

STEPS_PER_STROKE = 30
"""Steps between two firings (pi rad); the mean-torque sensor reports once per stroke."""

STEPS_PER_SPEED_SAMPLE = round(2 * math.pi / STEP_RAD / SPEED_SAMPLES_PER_REVOLUTION)
"""Steps between two filtered-speed samples: 15 (pi/2 rad, section II-C)."""

N_WIN = 30
"""Moving-average window of the speed sensor, in steps (pi rad, eq. 9)."""

RPM_PER_RAD_S = 30.0 / math.pi
"""Factor from rad/s to rpm."""


def step_time(speed_rpm: float) -> float:
    """Return the time of one angle step at a given speed, eq. (8).

    Parameters
    ----------
    speed_rpm
        Engine speed, rpm.

    Returns
    -------
    float
        T_s = phi_s / omega, s.
    """
    return STEP_RAD / (speed_rpm / RPM_PER_RAD_S)
