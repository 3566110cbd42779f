"""Whether a role the method reads crank-synchronously was sampled crank-synchronously.

The paper's signals come once per crank interval: the filtered engine speed every pi/2 (four
samples a revolution, section II-C) and the indicated mean torque once per working stroke (two a
revolution for the four-cylinder engine). Many production ECUs instead broadcast the engine speed
and a model torque in a time-periodic message (every 10 ms on the Hyundai/Kia EMS11 of
``../shared/realdata``). Read as if crank-synchronous, such a series puts the FRF on a wrong
grid and the model's sensor on the wrong samples: an identification of a 100 Hz speed
resampled from the reference vehicle's ended with a model that could not idle through any run.

Two figures tell the two apart, from the recording alone:

* the samples per revolution, 60 over the median of interval times speed (s * rpm); and
* how the interval follows the speed: crank-synchronous intervals shrink as the engine speeds up
  (the slope of log interval on log speed is -1), time-periodic ones do not (0). This also
  catches a periodic message whose rate happens to match the crank events at the idle speed
  (50 Hz at 750 rpm is four a revolution); it needs the speed to vary, as a chirp makes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dtid.dbc.roles import CRANK_RATE_TOLERANCE
from dtid.simulator.angle_grid import STEP_RAD, STEPS_PER_SPEED_SAMPLE, STEPS_PER_STROKE

SPEED_PER_REVOLUTION = 2 * math.pi / (STEPS_PER_SPEED_SAMPLE * STEP_RAD)
"""Filtered-speed samples per crank revolution (one every pi/2): 4."""
STROKES_PER_REVOLUTION = 2 * math.pi / (STEPS_PER_STROKE * STEP_RAD)
"""Mean-torque samples per crank revolution (one per working stroke): 2."""
RATE_TOLERANCE = CRANK_RATE_TOLERANCE
"""Relative departure of the samples per revolution from the expected beyond which a series is
not crank-synchronous (:data:`dtid.dbc.roles.CRANK_RATE_TOLERANCE`)."""
PERIODIC_SLOPE = -0.5
"""Slope of log interval on log speed above which the intervals do not follow the speed:
crank-synchronous sampling gives -1, time-periodic 0."""
MIN_SPEED_SPREAD = 0.003
"""Relative standard deviation of the speed below which the slope is not read (a steady idle
tells the two samplings apart by their rate only)."""
ENGINE_RPM = (300.0, 8000.0)
"""Where a running engine's speed lies, rpm: a speed role read outside it is most likely
another signal (a DBC that is not the vehicle's decodes another message's bytes)."""


@dataclass(frozen=True)
class CrankSampling:
    """How a series was sampled against the crank.

    Attributes
    ----------
    per_revolution
        Samples per crank revolution (the median interval's), 1.
    slope
        Slope of log interval on log engine speed, 1: -1 crank-synchronous, 0 time-periodic;
        None where the speed varied too little to read it.
    rate_hz
        Median sample rate, Hz.
    speed_rpm
        Median engine speed over the samples, rpm.
    """

    per_revolution: float
    slope: float | None
    rate_hz: float
    speed_rpm: float = float("nan")

    def problem(self, role: str, expected: float) -> str | None:
        """What is wrong with ``role``'s sampling for a series expected ``expected`` times a
        revolution, or None where it is crank-synchronous."""
        periodic = self.slope is not None and self.slope > PERIODIC_SLOPE
        if abs(self.per_revolution / expected - 1.0) <= RATE_TOLERANCE and not periodic:
            return None
        follows = (
            f"its interval {'does not follow' if periodic else 'follows'} the engine speed "
            f"(slope {self.slope:+.2f}; -1 for crank-synchronous samples, 0 for a time-periodic "
            "message)"
            if self.slope is not None
            else "the engine speed too steady to tell how its interval follows it"
        )
        scale = ""
        if role == "speed" and not periodic:  # crank-synchronous timing, values off?
            scale = (
                f" (or the speed's values are {expected / self.per_revolution:.3g} times what "
                "the samples' timing implies: check the `unit` and `scale` of the speed in the "
                "signal map; a speed in rad/s read as rpm gives 0.105)"
            )
        elif role == "mean_torque" and not periodic:  # once per stroke of another engine?
            scale = (
                f" (a four-stroke engine of {2 * self.per_revolution:.0f} cylinders reports "
                f"{self.per_revolution:.1f} strokes a revolution; the model's engine has "
                f"{2 * STROKES_PER_REVOLUTION:.0f})"
            )
        low, high = ENGINE_RPM
        if role == "speed" and periodic and not low <= self.speed_rpm <= high:
            scale = (
                f" (and it reads {self.speed_rpm:.0f} rpm, no running engine's speed: most "
                "likely another signal, decoded with a DBC that is not the vehicle's; give "
                "the vehicle's DBC with --dbc and its signal map with --signals)"
            )
        return (
            f"the {role} role comes {self.per_revolution:.1f} times a crank revolution "
            f"({self.rate_hz:.1f} Hz) where the method reads it {expected:.0f} times, and "
            f"{follows}: not the crank-synchronous signal the paper's test needs{scale}"
        )


def crank_sampling(
    times: np.ndarray, speed_times: np.ndarray, speed_rpm: np.ndarray
) -> CrankSampling | None:
    """How the samples at ``times`` (s) were taken against the crank, the engine speed given as
    samples ``speed_rpm`` at ``speed_times``; None for fewer than ten intervals.

    Parameters
    ----------
    times
        Sample times of the series, s, non-decreasing.
    speed_times, speed_rpm
        The engine speed's samples, s and rpm.
    """
    interval = np.diff(times)
    keep = interval > 0  # a frame logged twice
    if keep.sum() < 10 or len(speed_times) < 2:
        return None
    middle = 0.5 * (times[1:] + times[:-1])[keep]
    interval = interval[keep]
    speed = np.interp(middle, speed_times, speed_rpm)
    usable = speed > 0
    interval, speed = interval[usable], speed[usable]
    if len(interval) < 10:
        return None
    typical = float(np.median(interval))
    per_revolution = 60.0 / float(np.median(interval * speed))
    regular = (interval > 0.5 * typical) & (interval < 1.5 * typical)  # lost frames out
    x, y = np.log(speed[regular]), np.log(interval[regular])
    slope = None
    if len(x) >= 10 and np.std(x) > MIN_SPEED_SPREAD:
        slope = float(np.cov(x, y)[0, 1] / np.var(x, ddof=1))
    return CrankSampling(per_revolution, slope, 1.0 / typical, float(np.median(speed)))
