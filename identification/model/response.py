"""The model side of the identification: |G_DRV| of simulated tests, estimated as measured.

Eq. (16) compares the measured |G_DRV| with the model's; following the reading notes the model's
is not an analytic transfer function but the simulated closed loop, driven by the same test
signals and passed through the same estimator
(:func:`dtid.identification.frf.spectra.cross_spectra`), so the estimator's own biases (the
engine's torque hold, Welch's sweep-rate bias) cancel.

"The same test signals" is taken literally: the model replays the recording's own test-torque
requests. Beyond the paper, the model predicts the *expected* response: with DMF free play the
response near the resonance jump is sensitive to the smallest perturbation, so one simulated run
is as much a random draw as the measured one. Each parameter set is therefore simulated in
``realizations`` runs with the cycle-to-cycle combustion variation measured on the vehicle (the
same draws for every set, so the objective stays deterministic), and the cross-spectra are
averaged over them before |G_DRV| is formed, as longer Welch averaging would.

A few realizations still leave the model's own draw in its |G_DRV|: an error common to every
recording it is compared with, which the search reads as a bias of the parameters. The
realizations therefore come in antithetic pairs, the second with the first's draws negated, so
that the variation's first-order effect on the averaged cross-spectra cancels exactly and only
the higher orders (the free play's) remain, at the same cost (four runs per parameter set).
Measured with ``benchmarks/information_bound.py --model-seed S`` on truth 3 of the accuracy trial
(sixteen recordings, linearised estimator at the truth): the predicted bias of the gear play
varied with the model's seed by 2.3 % RMS, of the DMF friction by 12 %, against 5.4 % and 38 %
with independent draws (``--plain``); on the whole curve the pairs gain less (0.050 against
0.057 dB RMS from the mean of 128 realizations on the reference), the free play's higher
orders staying.

What the draws do not average out is the firing phase. The engine takes its request once per
working stroke, so the chirp reaches the plant sampled at the firing frequency f_s; near f_s/3
its alias f_s - f falls on the free play's second harmonic 2f, and how the two add depends on
which samples the strokes took. At 1000 rpm and 10 N*m that makes a peak at 11 Hz that repeats
to 0.02 dB from one recording of a vehicle to the next, and a replay whose strokes take the
request a crank event off misses it by over a decibel. The model of a recording therefore
repeats it crank event by crank event (:mod:`dtid.identification.model.idle_loop`): each run is
replayed on its own from the stroke ``SETTLE_S`` before it, every model stroke takes the request the
vehicle's stroke at that crank angle took, and the model's FRF uses the test torque the vehicle's
ECU held at those crank events. Many parameter sets are simulated in one batched, parallel call.

Without a recording's loop (``loop`` None: the paper's setups, on the simulator's own data) the
model closes the loop with the simulator's own idle controller and replays the whole test from
its start, which reproduces a clean simulated recording exactly.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np

from dtid.identification.frf.closed_loop import (
    FrfEstimate,
    drivetrain_magnitude,
    engine_magnitude,
    request_magnitude,
)
from dtid.identification.frf.spectra import cross_spectra
from dtid.identification.model.idle_loop import SAMPLES_PER_STROKE, IdleLoop
from dtid.identification.samples.testdata import Series
from dtid.simulator.controller import IdleController
from dtid.simulator.kernel import STATUS_BUFFER_FULL
from dtid.simulator.mechanisms import EXTRA_INDEX, KERNEL_WIDTH, kernel_parameters
from dtid.simulator.parameters import INDEX
from dtid.simulator.simulate import BatchResult, SimulationOptions, replay_batch
from dtid.simulator.vehicle_data import VehicleData

SETTLE_S = 3.0
"""Idle before each run in the model's replay, s (the plan's settling time)."""
DRIVEN_MARGIN_S = 1.0
"""Simulated time past the recording's last crank event a driven replay may need (its speed a
little lower than the vehicle's), s; the drive's last request holds there. Whatever the model
does there cannot fail a run whose crank events it has already simulated: an idle loop that
hunts leaves its last request anywhere between its swings, and the engine may stall on it."""
DEFAULT_REALIZATIONS = 4
"""Runs per parameter set whose cross-spectra are averaged (see the module notes)."""


@dataclass(frozen=True)
class Replay:
    """One stretch of the recording the model simulates.

    Attributes
    ----------
    offset_s
        Where it starts, s (recording time); simulated time 0.
    requests
        The test-torque requests from then on (simulated time, s; N*m).
    end_s
        Simulated duration: past its last run, with room for slower speeds, s.
    runs
        Indices of the test's estimates it covers.
    start_event
        The recording's crank event at simulated time 0 (a stroke starts there), when the
        model drives its engine with the recording (:mod:`dtid.identification.model.idle_loop`);
        None when it closes the loop with the simulator's own idle controller.
    """

    offset_s: float
    requests: Series
    end_s: float
    runs: tuple[int, ...]
    start_event: int | None = None


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
    loop
        How the model drives its engine and follows the recorded speed
        (:mod:`dtid.identification.model.idle_loop`); None closes the loop with the simulator's own
        idle controller at ``setpoint_rpm`` instead (for tests the simulator made itself, such as
        the paper's setups, whose loop is then known).
    combustion_variation
        Relative cycle-to-cycle variation of each stroke's mean torque, as measured at idle.
    vehicle
        The vehicle's crank-train data (eqs. 4-5: their pulsation dithers the DMF's free play,
        so the model's needs to be the vehicle's) and speed sensor
        (:mod:`dtid.simulator.vehicle_data`).
    realizations
        Runs per parameter set; with no combustion variation one run is enough.
    seed
        Seed of the variation's draws (the same for every parameter set).
    input
        ``"torque"``: |G_DRV| of eq. (14), from the measured mean torque; ``"request"``: from the
        torque request T_ecu, the engine gain K included (setup 1).
    antithetic
        Pair the realizations antithetically (see the module notes); False draws each
        independently.
    recording_noise
        Draw the noise a recording has instead of the expected response's: the combustion
        variation without the torque sensor's noise, that noise on the modelled mean torque,
        and the speed sensor's on the modelled speed, each as the idle loop measured it (a
        single realization is then one recording of the model;
        :mod:`dtid.identification.diagnosis.mismatch` measures the scatter so). Where the model
        replays the recording's own variation w r (:attr:`IdleLoop.variation_nm`: r a stroke's
        measured residual, w = (v d)^2 / ((v d)^2 + s^2)), what is still random about a
        recording given w r is smaller: its crankshaft is excited by the variation's unknown
        rest, of variance left^2 (v d)^2 (left = :attr:`IdleLoop.variation_left`, left^2 =
        s^2 / ((v d)^2 + s^2)), and its measured torque departs from the model's by (1 - w) r,
        of variance left^2 s^2. A draw has the variation's rest and the sensor's noise, both
        times left. Its crankshaft then scatters as a recording's does, but its sensor
        reports its drawn variation too, which a recording's residual does not hold: the
        draws overstate the scatter of |G_ENG|, by 1/left in theory, 1.5-1.9 measured on the
        reference vehicle (tests/test_diagnosis.py), and the map is that much less sensitive
        to an engine-path mismatch. (Cutting the draws' torque noise to s^2 (2 left^2 - 1),
        which keeps their measured torque's scatter at left^2 s^2, left |G_DRV|'s below 2 Hz
        at half the recordings'.)
    replays
        What is simulated (derived).
    """

    requests: Series
    estimates: tuple[FrfEstimate, ...]
    setpoint_rpm: float
    loop: IdleLoop | None = None
    combustion_variation: float = 0.0
    vehicle: VehicleData = field(default_factory=VehicleData)
    realizations: int = DEFAULT_REALIZATIONS
    seed: int = 0
    input: str = "torque"
    antithetic: bool = True
    recording_noise: bool = False
    options: SimulationOptions = field(init=False)
    replays: tuple[Replay, ...] = field(init=False)

    def __post_init__(self) -> None:
        if self.loop is None:
            controller = IdleController(setpoint_rpm=self.setpoint_rpm)
        else:
            controller = self.loop.controller()
            if not self.loop.by_request:  # the measured strokes carry the variation
                object.__setattr__(self, "combustion_variation", 0.0)
        left = 1.0 if self.loop is None else self.loop.variation_left
        noise = {"combustion_variation": self.combustion_variation * left}
        if self.recording_noise and self.loop is not None and self.loop.by_request:
            separated = (self.loop.combustion_variation, self.loop.torque_noise_nm)
            if all(np.isfinite(separated)):
                noise = {
                    "combustion_variation": separated[0] * left,
                    "torque_noise_nm": separated[1] * left,
                }
            if np.isfinite(self.loop.speed_noise_rpm):
                noise["speed_noise_rpm"] = self.loop.speed_noise_rpm
        options = SimulationOptions.clean(
            **noise,
            controller=controller,
            engine=self.vehicle.engine,
            speed_average=self.vehicle.speed_average,
            integration=self.vehicle.integration,
        )
        object.__setattr__(self, "options", options)
        if self.loop is not None:  # each run from a stroke SETTLE_S before it
            replays = tuple(
                self._driven_replay(self.loop.start_event(e.run.start_s - SETTLE_S), (i,))
                for i, e in enumerate(self.estimates)
            )
        else:
            replays = (self._replay(0.0, tuple(range(len(self.estimates)))),)
        object.__setattr__(self, "replays", replays)
        if self.combustion_variation == 0:
            object.__setattr__(self, "realizations", 1)

    def streams(self) -> np.ndarray:
        """(realizations,) noise stream of each realization: antithetic pairs share one."""
        return (
            np.arange(self.realizations) // 2 if self.antithetic else np.arange(self.realizations)
        )

    def signs(self) -> np.ndarray:
        """(realizations,) sign of each realization's draws: -1 for the second of a pair."""
        if not self.antithetic:
            return np.ones(self.realizations)
        return np.where(np.arange(self.realizations) % 2 == 1, -1.0, 1.0)

    def _replay(self, offset_s: float, runs: tuple[int, ...]) -> Replay:
        keep = self.requests.t >= offset_s
        requests = Series(self.requests.t[keep] - offset_s, self.requests.value[keep])
        end = max(
            self.estimates[i].run.end_s + 0.1 * self.estimates[i].run.duration_s for i in runs
        )
        return Replay(offset_s, requests, end - offset_s, runs)

    def _driven_replay(self, start: int, runs: tuple[int, ...]) -> Replay:
        assert self.loop is not None
        offset = float(self.loop.t[start])
        replay = self._replay(offset, runs)  # no further than the recording, the drive held
        end_s = min(replay.end_s, self.loop.t[-1] - offset + DRIVEN_MARGIN_S)
        return dataclasses.replace(replay, end_s=end_s, start_event=start)

    def model_parameters(self, params: np.ndarray) -> np.ndarray:
        """The parameter sets as the model simulates them: with K = 1 where the drive is the
        measured torque, which already holds the engine's gain (1/g_T with a torque-sensor gain:
        the drive is then g_T times the torque delivered), its lag and its cylinders' spread;
        with the recording's measured engine lag where the request drives it and the sets give
        none (``[model] engine_lag = "measured"``: :attr:`IdleLoop.lag_s`)."""
        if self.loop is None:
            return params
        if self.loop.by_request:
            if self.loop.lag_s <= 0:
                return params
            params = kernel_parameters(params).copy()
            lagless = params[:, EXTRA_INDEX["tau_m"]] <= 0
            params[lagless, EXTRA_INDEX["tau_m"]] = self.loop.lag_s
            return params
        params = params.copy()
        params[:, INDEX["K"]] = 1.0
        if params.shape[1] == KERNEL_WIDTH:
            params[:, INDEX["K"]] = 1.0 / params[:, EXTRA_INDEX["g_T"]]
            params[:, EXTRA_INDEX["tau_m"]] = 0.0
            params[:, EXTRA_INDEX["share"]] = 0.0
        return params


class ModelCurves(NamedTuple):
    """The model's frequency responses of one measured chirp run, for many parameter sets.

    Attributes
    ----------
    drv_db
        (n, bins) |G_DRV| of eq. (14), dB re 1 (rad/s)/(N*m).
    eng_db
        (n, bins) |G_ENG| of eq. (15), dB re 1: the model's mean torque per its torque request
        T_ecu. NaN where not asked for, and where the model's engine is not driven by a request
        (a recording without the ``torque_request`` role drives it with the measured torque,
        whose |G_ENG| the model would only repeat).
    """

    drv_db: np.ndarray
    eng_db: np.ndarray


def model_drv_db(params: np.ndarray, test: ModelTest) -> list[np.ndarray]:
    """Model |G_DRV| in dB for many parameter sets, per measured chirp run of the test.

    Parameters
    ----------
    params
        (n, 12) parameter sets ordered as :data:`dtid.simulator.parameters.NAMES`, SI units, or
        (n, :data:`dtid.simulator.mechanisms.KERNEL_WIDTH`) with the mechanisms' columns.
    test
        The test to repeat.

    Returns
    -------
    list of numpy.ndarray
        Per run, (n, len(frequency grid)) dB re 1 (rad/s)/(N*m); rows of parameter sets whose
        simulated engine could not idle through the run are NaN. Each row depends on its own
        parameter set only.
    """
    return [curves.drv_db for curves in model_curves(params, test, engine=False)]


def model_curves(params: np.ndarray, test: ModelTest, engine: bool = True) -> list[ModelCurves]:
    """Model |G_DRV| and |G_ENG| in dB for many parameter sets, per measured chirp run.

    The same simulations give both: |G_ENG| costs one more cross-spectrum per run.

    Parameters
    ----------
    params, test
        As :func:`model_drv_db`.
    engine
        Compute |G_ENG| too (NaN otherwise).

    Returns
    -------
    list of ModelCurves
        Per run of the test.
    """
    n_sets, m = params.shape[0], test.realizations
    params = test.model_parameters(params)
    out: list[ModelCurves] = [ModelCurves(np.empty(0), np.empty(0))] * len(test.estimates)
    engine = engine and test.input == "torque" and (test.loop is None or test.loop.by_request)
    for replay in test.replays:
        if replay.start_event is None:
            requests, reference, drive, offset = replay.requests, None, None, 0
        else:  # the drive holds the test torque already
            requests = Series(np.zeros(0), np.zeros(0))
            reference = test.loop.reference(replay.start_event)
            drive = test.loop.drive(replay.start_event)
            offset = test.loop.cylinder_offset(replay.start_event)
        batch = replay_batch(
            np.repeat(params, m, axis=0),
            requests.t,
            requests.value,
            np.ones(n_sets * m),
            replay.end_s,
            test.options,
            seed=test.seed,
            streams=np.tile(test.streams(), n_sets),
            signs=np.tile(test.signs(), n_sets),
            reference=reference,
            drive=drive,
            cylinder_offset=offset,
        )
        for i in replay.runs:
            out[i] = _run_curves(batch, replay, test.estimates[i], test, n_sets, engine)
    return out


def _run_curves(
    batch: BatchResult,
    replay: Replay,
    estimate: FrfEstimate,
    test: ModelTest,
    n_sets: int,
    engine: bool,
) -> ModelCurves:
    """|G_DRV| (and |G_ENG| if ``engine``) in dB of one run for every parameter set, on the
    measured grid."""
    requests, start_s = replay.requests, estimate.run.start_s - replay.offset_s
    n_jobs, length = len(batch.status), estimate.n_events
    y, x = (np.zeros((n_jobs, length)) for _ in range(2))
    u = np.zeros((n_jobs, length)) if engine else x  # the model's T_ecu
    from_request = test.input == "request"
    rate = np.ones(n_jobs)
    ok = np.zeros(n_jobs, dtype=bool)
    recorded_z = None
    if replay.start_event is not None:  # crank event by crank event (idle_loop's notes)
        loop = test.loop
        run_event = loop.event(float(loop.t[np.searchsorted(loop.t, estimate.run.start_s)]))
        recorded_z = loop.test_nm[run_event : run_event + length]
        recorded_u = loop.drive_nm[run_event : run_event + length]
        stroke_drive = loop.drive(replay.start_event)
        # every set repeats the recorded test torque: its segments transformed once, not per
        # set (the same spectra to the bit, a third fewer transforms: the dearer part of a call
        # where the segment's length is a prime, 227 events at 850 rpm)
        z = np.asarray(recorded_z, dtype=float)[None]
    else:
        z = np.zeros((n_jobs, length))
    # a run left the speed range after the run's window counts (see DRIVEN_MARGIN_S): the window
    # is checked below; a full buffer may have cut the torque's samples short
    jobs = np.flatnonzero((batch.status != STATUS_BUFFER_FULL) & (batch.n_torque > 0))
    if recorded_z is not None and len(recorded_z) < length:
        jobs = jobs[:0]
    if recorded_z is None:
        first = np.array(
            [np.searchsorted(batch.speed[j, : batch.n_speed[j], 0], start_s) for j in jobs],
            dtype=np.int64,
        )
    else:
        first = np.full(len(jobs), loop.model_event(run_event, replay.start_event))
    keep = first + length <= batch.n_speed[jobs]
    jobs, first = jobs[keep], first[keep]
    ok[jobs] = True
    window = first[:, None] + np.arange(length)  # each kept job's rows, (n_kept, length)
    t = batch.speed[jobs[:, None], window, 0]
    y[jobs] = batch.speed[jobs[:, None], window, 1]
    if from_request:
        x[jobs] = batch.speed[jobs[:, None], window, 2]
    else:
        x[jobs] = _held_torque(batch.torque, batch.n_torque, jobs, t)
    if engine:
        u[jobs] = batch.speed[jobs[:, None], window, 2]
    if engine and recorded_z is not None and len(jobs):
        # the kernel reports the request a stroke latches, the drive held over the stroke; the
        # vehicle's ECU held its request event by event: the model's T_ecu is that plus its own
        # tracking command (the kernel's report less the stroke's drive; the speed sample n ends
        # speed window n + 1, the next stroke is (n + 1) // SAMPLES_PER_STROKE)
        rows = np.arange(first[0], first[0] + length)
        stroke = np.minimum((rows + 1) // SAMPLES_PER_STROKE, len(stroke_drive) - 1)
        u[jobs] += recorded_u - stroke_drive[stroke]
    if recorded_z is None:
        held_request = np.searchsorted(requests.t, t, side="right") - 1
        z[jobs] = np.where(held_request >= 0, requests.value[held_request], 0.0)
    rate[jobs] = 1.0 / np.median(np.diff(t, axis=1), axis=1)
    db = np.full((n_sets, len(estimate.frequency_hz)), np.nan)
    eng_db = db.copy()
    if not ok.any():
        return ModelCurves(db, eng_db)
    unit_frequency, s_zy, s_zx = cross_spectra(z, y, x, 1.0, estimate.nperseg)
    if engine:
        s_zu = cross_spectra(z, u, x, 1.0, estimate.nperseg)[1]
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
        if engine:
            gain = engine_magnitude(
                frequency, s_zx[jobs].mean(axis=0), s_zu[jobs].mean(axis=0), y[jobs].mean()
            )
            eng_db[row] = np.interp(estimate.frequency_hz, frequency, 20 * np.log10(gain))
    return ModelCurves(db, eng_db)


@numba.njit(cache=True)
def _held_torque(
    torque: np.ndarray, n_torque: np.ndarray, jobs: np.ndarray, t: np.ndarray
) -> np.ndarray:
    """The mean torque each job's cylinder-pressure sensor last reported at each time of ``t``
    (the first report before it), N*m: ``torque`` and ``n_torque`` as
    :class:`dtid.simulator.simulate.BatchResult` gives them, ``t`` (len(jobs), n) increasing
    along each row, s. What ``np.searchsorted(side="right") - 1`` clipped at 0 indexes, in one
    pass per job."""
    held = np.empty(t.shape)
    for row in range(jobs.shape[0]):
        job, count = jobs[row], 0
        for k in range(t.shape[1]):
            while count < n_torque[job] and torque[job, count, 0] <= t[row, k]:
                count += 1
            held[row, k] = torque[job, max(count - 1, 0), 1]
    return held
