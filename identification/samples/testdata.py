"""Time series of one chirp test, whatever it came from (a CAN recording or the simulator)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtid.errors import AnalysisError
from dtid.simulator.simulate import SimulationResult


@dataclass(frozen=True)
class Series:
    """Samples of one signal: times in s (non-decreasing) and values in the role's unit."""

    t: np.ndarray
    value: np.ndarray

    def __post_init__(self) -> None:
        if self.t.shape != self.value.shape or self.t.ndim != 1:
            raise ValueError("a series needs 1-D time and value arrays of equal length")

    def __len__(self) -> int:
        return len(self.t)

    def window(self, start_s: float, end_s: float) -> Series:
        """The samples with start_s <= t < end_s."""
        lo, hi = np.searchsorted(self.t, [start_s, end_s])
        return Series(self.t[lo:hi], self.value[lo:hi])

    def held(self, times: np.ndarray, before: float | None = None) -> np.ndarray:
        """The value last received at or before each of ``times`` (s), as a receiver holds it.

        Parameters
        ----------
        times
            Times to read the held value at, s.
        before
            The value before the first sample; None takes the first sample's.
        """
        index = np.searchsorted(self.t, times, side="right") - 1
        held = self.value[np.clip(index, 0, len(self) - 1)]
        return held if before is None else np.where(index >= 0, held, before)


@dataclass(frozen=True)
class TestData:
    """The signals the FRF needs, in canonical units.

    Attributes
    ----------
    speed
        Filtered engine speed n~, rpm, crank-synchronous (every pi/2).
    mean_torque
        Measured mean torque T~_m per working stroke, N*m, reported at the end of each stroke.
    test_torque
        Test torque request T_test (the excitation z), N*m.
    torque_request
        Total torque request T_ecu, N*m, or None when the recording lacks it (no G_ENG then).
    """

    __test__ = False  # not a pytest test class, despite the name

    speed: Series
    mean_torque: Series
    test_torque: Series
    torque_request: Series | None = None

    def require(self) -> None:
        """Raise AnalysisError if a signal the FRF needs is empty."""
        for name in ("speed", "mean_torque", "test_torque"):
            if len(getattr(self, name)) < 2:
                raise AnalysisError(f"the recording holds fewer than 2 samples of {name}")


def from_simulation(result: SimulationResult) -> TestData:
    """Build test data from a simulated test directly (no CAN in between)."""
    return TestData(
        speed=Series(result.speed_t, result.speed_rpm),
        mean_torque=Series(result.torque_t, result.mean_torque_nm),
        test_torque=Series(result.request_t, result.test_torque_nm),
        torque_request=Series(result.speed_t, result.torque_request_nm),
    )
