"""The model side of the identification: |G_DRV| of simulated tests, estimated as measured.

Eq. (16) compares the measured |G_DRV| with the model's; following the reading notes the model's
is not an analytic transfer function but the simulated closed loop, driven by the same test
signals and passed through the same estimator (:func:`identification.frf.cross_spectra`), so the
estimator's own biases (the engine's torque hold, Welch's sweep-rate bias) cancel.

"The same test signals" is taken literally: the model replays the recording's own test-torque
requests. Beyond the paper, the model predicts the *expected* response: with DMF free play the
response near the resonance jump is sensitive to the smallest perturbation (on the reference
vehicle a set-point 0.04 rpm off moves a single run's NRMSE by 0.08 at 10 N*m, where a 1 % change
of c12 moves it by 0.012), so one simulated run is as much a random draw as the measured one.
Each parameter set is therefore simulated in ``realizations``
runs with the cycle-to-cycle combustion variation measured on the vehicle (the same draws for
every set, so the objective stays deterministic), and the cross-spectra are averaged over them
before |G_DRV| is formed, as longer Welch averaging would. Since the state a chirp starts from is
averaged out too, the replay starts ``SETTLE_S`` before the first estimated run. Many parameter
sets are simulated in one batched, parallel call.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from identification.frf import (
    FrfEstimate,
    cross_spectra,
    drivetrain_magnitude,
    request_magnitude,
)
from identification.testdata import Series
from simulator.controller import IdleController
from simulator.simulate import BatchResult, SimulationOptions, replay_batch

SETTLE_S = 3.0
"""Idle before the first estimated run in the model's replay, s (the plan's settling time)."""
DEFAULT_REALIZATIONS = 4
"""Runs per parameter set whose cross-spectra are averaged (see the module notes)."""


@dataclass(frozen=True)
class ModelTest:
    """How the model repeats a measured chirp test.

    Attributes
    ----------
    requests
        The recording's test-torque requests (times from the recording's start, s; N*m).
    estimates
        The measured FRFs the model is compared with: each gives the run, the frequency grid, the
        number of crank events analysed and the Welch segment length, which the model's estimate
        uses exactly, so that it depends on its own parameter set only.
    setpoint_rpm
        Idle speed of the test, rpm.
    combustion_variation
        Relative cycle-to-cycle variation of each stroke's mean torque, as measured at idle.
    realizations
        Runs per parameter set; with no combustion variation one run is enough.
    seed
        Seed of the variation's draws (the same for every parameter set).
    input
        ``"torque"``: |G_DRV| of eq. (14), from the measured mean torque; ``"request"``: from the
        torque request T_ecu, the engine gain K included (setup 1).
    """

    requests: Series
    estimates: tuple[FrfEstimate, ...]
    setpoint_rpm: float
    combustion_variation: float = 0.0
    realizations: int = DEFAULT_REALIZATIONS
    seed: int = 0
    input: str = "torque"
    options: SimulationOptions = field(init=False)
    offset_s: float = field(init=False)
    replay: Series = field(init=False)

    def __post_init__(self) -> None:
        options = SimulationOptions.clean(
            combustion_variation=self.combustion_variation,
            controller=IdleController(setpoint_rpm=self.setpoint_rpm),
        )
        object.__setattr__(self, "options", options)
        offset = 0.0  # a deterministic replay keeps the whole history: it reproduces a run exactly
        if self.combustion_variation > 0:
            offset = max(0.0, min(e.run.start_s for e in self.estimates) - SETTLE_S)
        keep = self.requests.t >= offset
        replay = Series(self.requests.t[keep] - offset, self.requests.value[keep])
        object.__setattr__(self, "offset_s", offset)
        object.__setattr__(self, "replay", replay)
        if self.combustion_variation == 0:
            object.__setattr__(self, "realizations", 1)

    @property
    def end_s(self) -> float:
        """Simulated time of the replay: past the last run, with room for slower speeds, s."""
        return max(e.run.end_s + 0.1 * e.run.duration_s for e in self.estimates) - self.offset_s


def model_drv_db(params: np.ndarray, test: ModelTest) -> list[np.ndarray]:
    """Model |G_DRV| in dB for many parameter sets, per measured chirp run of the test.

    Parameters
    ----------
    params
        (n, 12) parameter sets ordered as :data:`simulator.parameters.NAMES`, SI units.
    test
        The test to repeat.

    Returns
    -------
    list of numpy.ndarray
        Per run, (n, len(frequency grid)) dB re 1 (rad/s)/(N*m); rows of parameter sets whose
        simulated engine could not idle through the run are NaN. Each row depends on its own
        parameter set only.
    """
    n_sets, m = params.shape[0], test.realizations
    batch = replay_batch(
        np.repeat(params, m, axis=0),
        test.replay.t,
        test.replay.value,
        np.ones(n_sets * m),
        test.end_s,
        test.options,
        seed=test.seed,
        streams=np.tile(np.arange(m), n_sets),
    )
    return [_run_db(batch, estimate, test, n_sets) for estimate in test.estimates]


def _run_db(batch: BatchResult, estimate: FrfEstimate, test: ModelTest, n_sets: int) -> np.ndarray:
    """|G_DRV| in dB of one run for every parameter set, on the measured grid."""
    requests, start_s = test.replay, estimate.run.start_s - test.offset_s
    n_jobs, length = len(batch.status), estimate.n_events
    y, x, z = (np.zeros((n_jobs, length)) for _ in range(3))
    from_request = test.input == "request"
    rate = np.ones(n_jobs)
    ok = np.zeros(n_jobs, dtype=bool)
    for job in np.flatnonzero(batch.status == 0):
        speed = batch.speed[job, : batch.n_speed[job]]
        torque = batch.torque[job, : batch.n_torque[job]]
        first = np.searchsorted(speed[:, 0], start_s)
        if first + length > len(speed):
            continue
        t = speed[first : first + length, 0]
        held_torque = np.clip(np.searchsorted(torque[:, 0], t, side="right") - 1, 0, None)
        held_request = np.searchsorted(requests.t, t, side="right") - 1
        y[job] = speed[first : first + length, 1]
        x[job] = speed[first : first + length, 2] if from_request else torque[held_torque, 1]
        z[job] = np.where(held_request >= 0, requests.value[held_request], 0.0)
        rate[job] = 1.0 / np.median(np.diff(t))
        ok[job] = True
    db = np.full((n_sets, len(estimate.frequency_hz)), np.nan)
    if not ok.any():
        return db
    unit_frequency, s_zy, s_zx = cross_spectra(z, y, x, 1.0, estimate.nperseg)
    m = test.realizations
    for row in range(n_sets):
        jobs = slice(row * m, (row + 1) * m)
        if not ok[jobs].all():
            continue  # a realisation that cannot idle fails the set
        rate_hz = rate[jobs].mean()  # the set's mean event rate sets its frequency axis
        frequency = unit_frequency * rate_hz
        response = request_magnitude if from_request else drivetrain_magnitude
        magnitude = response(
            frequency, s_zy[jobs].mean(axis=0), s_zx[jobs].mean(axis=0), y[jobs].mean()
        )
        db[row] = np.interp(estimate.frequency_hz, frequency, 20 * np.log10(magnitude))
    return db
