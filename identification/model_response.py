"""The model side of the identification: |G_DRV| of simulated tests, estimated as measured.

Eq. (16) compares the measured |G_DRV| with the model's; following the reading notes the model's
is not an analytic transfer function but the simulated closed loop, driven by the same test
signals and passed through the same estimator (:func:`identification.frf.cross_spectra`), so the
estimator's own biases (the engine's torque hold, Welch's sweep-rate bias) cancel.

"The same test signals" is taken literally: the model replays the recording's own test-torque
requests over the recording's time line. With free play and friction the response near a
resonance depends on the state a chirp starts from, so a chirp simulated alone differs from the
same chirp run after another (measured on the reference vehicle: up to 2 dB at 10 N*m).
Many parameter sets are simulated in one batched, parallel call.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from identification.frf import FrfEstimate, cross_spectra, drivetrain_magnitude
from identification.testdata import Series
from simulator.controller import IdleController
from simulator.simulate import BatchResult, SimulationOptions, replay_batch


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
        Relative cycle-to-cycle variation of the mean torque of the model engine (0: the model
        predicts the expected response), with the same draws for every parameter set.
    seed
        Seed of those draws.
    """

    requests: Series
    estimates: tuple[FrfEstimate, ...]
    setpoint_rpm: float
    combustion_variation: float = 0.0
    seed: int = 0
    options: SimulationOptions = field(init=False)

    def __post_init__(self) -> None:
        options = SimulationOptions.clean(
            combustion_variation=self.combustion_variation,
            controller=IdleController(setpoint_rpm=self.setpoint_rpm),
        )
        object.__setattr__(self, "options", options)

    @property
    def end_s(self) -> float:
        """Simulated time needed: past the end of the last run, with room for slower speeds, s."""
        return max(e.run.end_s + 0.1 * e.run.duration_s for e in self.estimates)


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
    n_sets = params.shape[0]
    batch = replay_batch(
        params,
        test.requests.t,
        test.requests.value,
        np.ones(n_sets),
        test.end_s,
        test.options,
        seed=test.seed,
        streams=np.zeros(n_sets, dtype=np.int64),
    )
    return [_run_db(batch, estimate, test.requests) for estimate in test.estimates]


def _run_db(batch: BatchResult, estimate: FrfEstimate, requests: Series) -> np.ndarray:
    """|G_DRV| in dB of one run for every job of the batch, on the measured grid."""
    n_jobs, length = len(batch.status), estimate.n_events
    y, x, z = (np.zeros((n_jobs, length)) for _ in range(3))
    rate = np.ones(n_jobs)
    ok = np.zeros(n_jobs, dtype=bool)
    for job in np.flatnonzero(batch.status == 0):
        speed = batch.speed[job, : batch.n_speed[job]]
        torque = batch.torque[job, : batch.n_torque[job]]
        first = np.searchsorted(speed[:, 0], estimate.run.start_s)
        if first + length > len(speed):
            continue
        t = speed[first : first + length, 0]
        held_torque = np.clip(np.searchsorted(torque[:, 0], t, side="right") - 1, 0, None)
        held_request = np.searchsorted(requests.t, t, side="right") - 1
        y[job] = speed[first : first + length, 1]
        x[job] = torque[held_torque, 1]
        z[job] = np.where(held_request >= 0, requests.value[held_request], 0.0)
        rate[job] = 1.0 / np.median(np.diff(t))
        ok[job] = True
    db = np.full((n_jobs, len(estimate.frequency_hz)), np.nan)
    if not ok.any():
        return db
    unit_frequency, s_zy, s_zx = cross_spectra(z[ok], y[ok], x[ok], 1.0, estimate.nperseg)
    for row, job in enumerate(np.flatnonzero(ok)):
        frequency = unit_frequency * rate[job]  # each job's own event rate
        magnitude = drivetrain_magnitude(frequency, s_zy[row], s_zx[row], y[job].mean())
        db[job] = np.interp(estimate.frequency_hz, frequency, 20 * np.log10(magnitude))
    return db
