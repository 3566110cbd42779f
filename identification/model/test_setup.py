"""From recordings to what the identification needs: runs, FRFs, K, T_loss and the idle speed."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtid.errors import AnalysisError
from dtid.identification.frf.closed_loop import REQUEST_GAIN_RANGE, FrfEstimate, estimate_frf
from dtid.identification.frf.runs import ChirpRun, find_runs
from dtid.identification.model.combustion import stroke_variation
from dtid.identification.model.idle_loop import IdleLoop, idle_loop
from dtid.identification.model.response import ModelTest
from dtid.identification.samples.testdata import Series, TestData
from dtid.simulator.vehicle_data import VehicleData

logger = logging.getLogger(__name__)

MAX_WEIGHT_SAMPLES = 4.0
"""In the set-point's time mean a speed sample weighs at most this many median intervals."""
IDLE_MARGIN_S = 1.0
"""Idle samples closer than this to a chirp (or the recording's start) are not idle, s."""


@dataclass(frozen=True)
class MeasuredTest:
    """One recording's chirp runs with their FRFs, and what the model must repeat of it.

    Attributes
    ----------
    name
        The recording (for reports).
    data
        Its signals.
    estimates
        FRF of every chirp run that gives one, in time order.
    setpoint_rpm
        The idle set-point, rpm: the time-weighted mean of the filtered speed from the
        recording's first second to its end. An integrating idle controller makes that mean its
        set-point, chirps included (0.01 rpm on a simulated 192 s test). The recording's model
        does not use it: it follows the recorded speed (:mod:`dtid.identification.model.idle_loop`).
    idle_torque_nm
        Mean measured torque at idle outside the chirps, N*m: the loss torque T_loss.
    combustion_variation
        Relative standard deviation of each stroke's delivered torque, the cycle-to-cycle
        variation the model engine repeats: told apart from the torque sensor's noise where the
        recording holds the torque request (:func:`dtid.identification.model.combustion.
        variation_and_noise`); otherwise the idle scatter, sensor noise included (the model,
        then driven by the measured torque, adds none).
    loop
        The recording on its crank-event grid, as the model drives its engine
        (:mod:`dtid.identification.model.idle_loop`).
    """

    name: str
    data: TestData
    estimates: tuple[FrfEstimate, ...]
    setpoint_rpm: float
    idle_torque_nm: float
    combustion_variation: float
    loop: IdleLoop = dataclasses.field(repr=False)
    unusable: tuple[tuple[ChirpRun, str], ...] = ()
    """Chirp runs that cannot give an FRF (lost frames, too short), each with the reason."""
    vehicle: VehicleData = dataclasses.field(default_factory=VehicleData)
    """What the model knows of the vehicle besides its drivetrain: crank train and speed sensor
    (the reference's unless given: :mod:`dtid.simulator.vehicle_data`)."""

    @classmethod
    def from_data(
        cls,
        name: str,
        data: TestData,
        resolution_hz: float,
        vehicle: VehicleData | None = None,
    ) -> MeasuredTest:
        """Find the runs, estimate their FRFs and the idle operating point.

        ``vehicle`` is what the model knows of the vehicle besides its drivetrain (the
        reference engine and a tooth-timer speed sensor by default).

        A run that cannot give an FRF is kept in ``unusable`` with the reason:
        :func:`dtid.identification.search.runs.split_runs` leaves it out of the validation, or
        refuses if it was to identify. No run with an FRF at all is an error.
        """
        runs = find_runs(data.test_torque)
        if not runs:
            raise AnalysisError(f"{name}: no chirp in the test torque")
        estimates, unusable = _estimates(data, runs, resolution_hz)
        problem = _not_the_total_request(estimates)
        if problem is not None:
            logger.warning(
                "%s: %s; the request is left out: the measured torque drives the model, and K of "
                "eq. (3) needs --fix K=VALUE (or map the ECU's total request: docs/vehicle.md)",
                name,
                problem,
            )
            data = dataclasses.replace(data, torque_request=None)
            estimates, unusable = _estimates(data, runs, resolution_hz)
        if not estimates:
            raise AnalysisError(f"{name}: {unusable[0][1]}")
        torque = data.mean_torque.value[_idle(data.mean_torque.t, runs)]
        if len(torque) < 10:
            raise AnalysisError(
                f"{name}: fewer than 10 mean-torque samples at idle outside the chirps; the loss "
                "torque T_loss cannot be measured (record a few seconds of idle before the test)"
            )
        idle_torque = float(np.mean(torque))
        if idle_torque <= 0.0:
            raise AnalysisError(
                f"{name}: the mean torque at idle is {idle_torque:.2f} N*m, where the "
                "indicated mean torque of eq. (3) carries the engine's friction and accessory "
                "load at idle (10-20 N*m in a passenger car): this looks like a brake or net "
                "torque, which the model cannot drive its engine with; map the indicated mean "
                "torque, from the cylinder pressure (docs/vehicle.md)"
            )
        vehicle = vehicle or VehicleData()
        loop = idle_loop(data, measured_lag(estimates) if vehicle.engine_lag == "measured" else 0.0)
        separated = loop.by_request and np.isfinite(loop.combustion_variation)
        return cls(
            name,
            data,
            tuple(estimates),
            _time_mean(data.speed),
            idle_torque,
            loop.combustion_variation if separated else stroke_variation(torque),
            loop,
            tuple(unusable),
            vehicle,
        )

    def run_label(self, index: int) -> str:
        """How reports name the run ``estimates[index]``: "<recording> @ <amplitude> N*m", and
        where the recording holds more than one run at that amplitude (a test plan's repeats)
        its start as well, "... at 125 s", so that no two runs of a recording share a label."""
        run = self.estimates[index].run
        amplitude = f"{run.amplitude_nm:g}"
        label = f"{self.name} @ {amplitude} N*m"
        repeats = sum(f"{e.run.amplitude_nm:g}" == amplitude for e in self.estimates)
        return label if repeats == 1 else f"{label} at {run.start_s:.0f} s"

    @property
    def idle_speed_sd_rpm(self) -> float:
        """Standard deviation of the recorded speed at idle, rpm: from the recording's first
        second on, away from every chirp (usable or not). A steady idle scatters by the
        combustion variation and the sensor's noise; an idle loop that hunts (a limit cycle)
        by about as much as a chirp moves the speed, or more. NaN with fewer than two samples.
        """
        runs = [e.run for e in self.estimates] + [run for run, _ in self.unusable]
        values = self.data.speed.value[_idle(self.data.speed.t, runs)]
        return float(np.std(values)) if len(values) > 1 else float("nan")

    def model_test(self, indices: Sequence[int], realizations: int | None = None) -> ModelTest:
        """The model's repetition of this recording, estimating the runs given by index
        (:class:`dtid.identification.model.response.ModelTest`)."""
        extra = {} if realizations is None else {"realizations": realizations}
        return ModelTest(
            requests=self.data.test_torque,
            estimates=tuple(self.estimates[i] for i in indices),
            setpoint_rpm=self.setpoint_rpm,
            loop=self.loop,
            vehicle=self.vehicle,
            combustion_variation=self.combustion_variation,
            **extra,
        )


def measured_lag(estimates: Sequence[FrfEstimate]) -> float:
    """The engine's lag behind its request, s: the median over the runs whose T/T_ecu shows one
    (:attr:`dtid.identification.frf.closed_loop.FrfEstimate.engine_lag`); 0 where none does."""
    lags = [lag.tau_s for e in estimates if (lag := e.engine_lag) is not None]
    return float(np.median(lags)) if lags else 0.0


def _time_mean(speed: Series) -> float:
    """Mean of the speed over time from the recording's first second on, each sample weighted by
    the time since the one before (as the controller's integral weights it; a gap of lost
    frames no more than a few samples' worth), rpm."""
    keep = speed.t > speed.t[0] + IDLE_MARGIN_S
    t, value = speed.t[keep], speed.value[keep]
    if len(t) < 2:
        return float(np.mean(speed.value))
    weight = np.diff(t)
    weight = np.minimum(weight, MAX_WEIGHT_SAMPLES * np.median(weight))
    return float(np.sum(value[1:] * weight) / np.sum(weight))


def _idle(t: np.ndarray, runs: Sequence[ChirpRun]) -> np.ndarray:
    """Samples at idle: after the recording's first second and away from every chirp."""
    idle = t > t[0] + IDLE_MARGIN_S
    for run in runs:
        idle &= (t < run.start_s - IDLE_MARGIN_S) | (t > run.end_s + IDLE_MARGIN_S)
    return idle


def _estimates(
    data: TestData, runs: Sequence[ChirpRun], resolution_hz: float
) -> tuple[list[FrfEstimate], list[tuple[ChirpRun, str]]]:
    """Each run's FRF, and the runs that cannot give one with the reason."""
    estimates, unusable = [], []
    for run in runs:
        try:
            estimates.append(estimate_frf(data, run, resolution_hz))
        except AnalysisError as error:
            unusable.append((run, str(error)))
    return estimates, unusable


def _not_the_total_request(estimates: Sequence[FrfEstimate]) -> str | None:
    """What to say where the torque request does not move with the test torque as the ECU's
    total request does (:data:`dtid.identification.frf.closed_loop.REQUEST_GAIN_RANGE`); None
    where it does or where there is none.

    Driven by a request without the chirp, the model's engine gets no test torque: the
    reference's test so recorded fitted at NRMSE 1.0-1.2 at its own truth, eq. (24) read K 6.4,
    and the only warning blamed an idle controller's derivative action.
    """
    gains = np.concatenate([e.request_gain for e in estimates]) if estimates else np.empty(0)
    gains = gains[np.isfinite(gains)]
    if len(gains) == 0:
        return None
    gain = float(np.median(gains))
    low, high = REQUEST_GAIN_RANGE
    if low <= gain <= high:
        return None
    return (
        f"the torque request moves {gain:.2f} N*m per N*m of test torque over the chirps, where "
        "the ECU's total request (its idle controller's plus the test torque) moves about 1: "
        "the mapped request leaves out the test torque (a base request), or it or the test "
        "torque is read in another unit"
    )
