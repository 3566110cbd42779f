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

from identification.frf import cross_spectra, drivetrain_magnitude
from identification.runs import ChirpRun
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
    runs
        The chirp runs to estimate, with the frequency grid of each measured estimate.
    frequency_hz
        Per run, the measured frequency grid, Hz (the model's |G_DRV| is interpolated onto it).
    setpoint_rpm
        Idle speed of the test, rpm.
    resolution_hz
        Welch resolution of the measured estimates, Hz.
    combustion_variation
        Relative cycle-to-cycle variation of the mean torque seen at idle in the recording; the
        model engine varies as much, with the same draws for every parameter set.
    seed
        Seed of those draws.
    """

    requests: Series
    runs: tuple[ChirpRun, ...]
    frequency_hz: tuple[np.ndarray, ...]
    setpoint_rpm: float
    resolution_hz: float
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
        """Simulated time needed: up to the end of the last run, s."""
        return max(run.end_s for run in self.runs) + 0.1


def model_drv_db(params: np.ndarray, test: ModelTest) -> list[np.ndarray]:
    """Model |G_DRV| in dB for many parameter sets, per chirp run of the test.

    Parameters
    ----------
    params
        (n, 12) parameter sets ordered as :data:`simulator.parameters.NAMES`, SI units.
    test
        The test to repeat.

    Returns
    -------
    list of numpy.ndarray
        Per run, (n, len(test.frequency_hz[r])) dB re 1 (rad/s)/(N*m); rows of parameter sets
        whose simulated engine could not idle are NaN.
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
    ok = np.flatnonzero(batch.status == 0)
    result = []
    for run, grid in zip(test.runs, test.frequency_hz, strict=True):
        db = np.full((n_sets, len(grid)), np.nan)
        if len(ok):
            db[ok] = _run_db(batch, ok, run, grid, test)
        result.append(db)
    return result


def _run_db(
    batch: BatchResult, jobs: np.ndarray, run: ChirpRun, grid: np.ndarray, test: ModelTest
) -> np.ndarray:
    """|G_DRV| in dB of one run for the given jobs, on the measured grid."""
    windows = []
    for job in jobs:
        speed = batch.speed[job, : batch.n_speed[job]]
        torque = batch.torque[job, : batch.n_torque[job]]
        lo, hi = np.searchsorted(speed[:, 0], [run.start_s, run.end_s])
        t = speed[lo:hi, 0]
        held_torque = np.clip(np.searchsorted(torque[:, 0], t, side="right") - 1, 0, None)
        held_request = np.searchsorted(test.requests.t, t, side="right") - 1
        z = np.where(held_request >= 0, test.requests.value[held_request], 0.0)
        windows.append((t, speed[lo:hi, 1], torque[held_torque, 1], z))
    length = min(len(w[0]) for w in windows)
    t, y, x, z = (np.stack([w[i][:length] for w in windows]) for i in range(4))
    rate = 1.0 / np.median(np.diff(t, axis=1), axis=1)
    common_rate = float(np.median(rate))
    nperseg = round(common_rate / test.resolution_hz)
    frequency, s_zy, s_zx = cross_spectra(z, y, x, common_rate, nperseg)
    magnitude = drivetrain_magnitude(frequency, s_zy, s_zx, y.mean(axis=1, keepdims=True))
    # each job's own event rate sets its frequency axis
    return np.stack(
        [
            np.interp(grid, frequency * job_rate / common_rate, 20 * np.log10(m))
            for m, job_rate in zip(magnitude, rate, strict=True)
        ]
    )
