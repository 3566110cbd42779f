"""What one chirp at each amplitude tells about each parameter: eq. (17)'s linearised information.

Near its minimum eq. (17) is a weighted least-squares fit of the runs' |G_DRV| in dB, each run's
bins weighted by w = 1 / (spread * ||r||) (spread: the run's measured spread, the NRMSE's
denominator; ||r||: the norm of its residual at the optimum), so an estimate's error is, to
first order, A^-1 sum_runs w J^T r with A = sum_runs w J^T J, and its covariance the sandwich
A^-1 (sum_runs w^2 J^T Sigma J) A^-1 (Sigma: the run's residual covariance). Each amplitude's
J and Sigma are measured here once, at a prior, from the product's own simulator: a test
holding one 60 s chirp per candidate amplitude, simulated with several noise seeds (combustion
variation and sensor noise), each identified side by its own model seed, so Sigma holds the
recording's noise and the model's Monte Carlo scatter alike. J is
:func:`dtid.identification.search.sensitivity.jacobian`'s, averaged over the seeds; Sigma is the
seeds' residual at the prior, its variance smoothed over neighbouring bins and its correlation
between bins (the Welch segments overlap, the window leaks) pooled into one Toeplitz matrix.

Nothing here sees a recording: the figures are predictions for a vehicle like the prior, with the
reference idle loop, engine and noise (:class:`dtid.simulator.simulate.SimulationOptions`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import toeplitz
from scipy.ndimage import uniform_filter1d

from dtid.acquisition.plan import TestPlan
from dtid.errors import AnalysisError
from dtid.identification.frf.runs import ChirpRun
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.objective import Objective
from dtid.identification.search.parameterization import (
    THETA_NAMES,
    Parameterization,
    passenger_car_bounds,
    theta_from_parameters,
)
from dtid.identification.search.sensitivity import jacobian
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_data import VehicleData

RESOLUTION_HZ = 0.25
"""Welch resolution of the predicted identification, Hz (``dtid identify``'s default)."""
DEFAULT_SEEDS = 6
"""Noise seeds the information is averaged over: with the smoothing below, each bin's variance
rests on about 30 squared residuals (about +-25 % on it, +-13 % on a predicted standard
deviation)."""
SMOOTHING_BINS = 5
"""Width of the moving average over bins that smooths each run's residual variance."""
MAX_LAG_BINS = 8
"""Longest lag, bins, of the pooled residual correlation; it is cut at its first lag below
:data:`CORRELATION_FLOOR`."""
CORRELATION_FLOOR = 0.05


@dataclass(frozen=True)
class LevelInformation:
    """What one chirp at one amplitude contributes, measured at the prior.

    Attributes
    ----------
    amplitude_nm
        A_test, N*m.
    frequency_hz
        The run's bins, Hz.
    drv_db
        Measured |G_DRV| at the prior, mean over the seeds, dB (sets the run's spread).
    jacobian_db
        (bins, 10) sensitivity of the model's |G_DRV| to each setup-4 parameter, dB per SI unit
        (per :data:`dtid.identification.search.parameterization.THETA_UNITS`).
    sigma_db
        (bins,) standard deviation of the residual at the prior, dB, for the measured chirp.
    correlation
        Residual correlation between bins 0, 1, ... lags apart (1 at lag 0).
    speed_excursion_rpm
        Largest deviation of the engine speed from its idle mean during the chirp, rpm.
    coherence
        Median coherence of the run over its band (NaN when ``unusable``).
    unusable
        Why the chirp gave no FRF on a seed (the identification's refusal), or "" when it gave
        one on every seed; an unusable level carries no bins and no information, and the
        search leaves its amplitude out (:func:`dtid.identification.planning.design.recommend`).
    """

    amplitude_nm: float
    frequency_hz: np.ndarray
    drv_db: np.ndarray
    jacobian_db: np.ndarray
    sigma_db: np.ndarray
    correlation: np.ndarray
    speed_excursion_rpm: float
    coherence: float
    unusable: str = ""

    def covariance(self, rows: np.ndarray) -> np.ndarray:
        """Residual covariance of the bins selected by ``rows`` (a boolean mask), dB^2."""
        sigma = self.sigma_db[rows]
        lags = np.zeros(len(sigma))
        lags[: min(len(sigma), len(self.correlation))] = self.correlation[: len(sigma)]
        values, vectors = np.linalg.eigh(toeplitz(lags))  # a cut correlation may lose PSD
        correlation = (vectors * np.maximum(values, 0.0)) @ vectors.T
        return sigma[:, None] * correlation * sigma[None, :]


@dataclass(frozen=True)
class PlanInformation:
    """Every candidate amplitude's information at one prior.

    Attributes
    ----------
    prior
        The drivetrain the information is measured at.
    values
        Its setup-4 values, ordered as :data:`THETA_NAMES`, SI units.
    reference
        The measured chirps' plan (duration and band of each candidate amplitude's chirp).
    levels
        One per candidate amplitude, ascending.
    setpoint_rpm
        The idle speed measured in the simulated test, rpm.
    seeds
        Noise seeds averaged.
    notes
        What was changed of the prior to plan for it, one sentence each.
    around
        The same measured at vehicles the prior stands for
        (:mod:`dtid.identification.planning.spread`), at the same amplitudes; empty when the
        plan is for the prior alone.
    spread
        Their relative half-width around the prior by drivetrain parameter, 1 (empty: none).
    spread_correlated
        Whether they were drawn correlated, along the directions the recorded runs leave open
        (:func:`dtid.identification.planning.design.recorded_correlation`), not independently
        per parameter.
    """

    prior: DrivetrainParameters
    values: np.ndarray
    reference: TestPlan
    levels: tuple[LevelInformation, ...]
    setpoint_rpm: float
    seeds: int
    notes: tuple[str, ...] = ()
    around: tuple[PlanInformation, ...] = ()
    spread: dict[str, float] = dataclasses.field(default_factory=dict)
    spread_correlated: bool = False

    @property
    def vehicles(self) -> tuple[PlanInformation, ...]:
        """The prior's information and every vehicle's around it."""
        return (self, *self.around)

    @property
    def amplitudes_nm(self) -> tuple[float, ...]:
        """The candidate amplitudes, N*m."""
        return tuple(level.amplitude_nm for level in self.levels)


def measure_information(
    prior: DrivetrainParameters,
    amplitudes_nm: Sequence[float],
    reference: TestPlan | None = None,
    options: SimulationOptions | None = None,
    seeds: int = DEFAULT_SEEDS,
    vehicle: VehicleData | None = None,
) -> PlanInformation:
    """Measure each amplitude's linearised information at a prior (see the module notes).

    Parameters
    ----------
    prior
        Drivetrain parameters to linearise at.
    amplitudes_nm
        Candidate amplitudes, N*m; one chirp each, with ``reference``'s duration and band.
    reference
        Duration, band, settle and pause of the measured chirps (its amplitudes are replaced);
        the paper's 60 s chirp from 1 to 15 Hz by default.
    options
        The simulated vehicle's engine, idle loop and noise; the reference's by default.
    seeds
        Noise seeds to average over.
    vehicle
        What the model side knows of the vehicle (its engine and speed sensor; the reference's
        by default), as ``dtid identify --vehicle`` tells it.

    Returns
    -------
    PlanInformation
        An amplitude whose chirp gave no FRF on some seed (too little coherence at a small
        amplitude and a low idle, for example) is measured as an unusable level
        (:attr:`LevelInformation.unusable`), not refused: at a vehicle around a prior it says
        that this amplitude cannot serve the plan.

    Raises
    ------
    AnalysisError
        If no chirp of the simulated test gave an FRF.
    """
    amplitudes = tuple(sorted(float(a) for a in amplitudes_nm))
    plan = dataclasses.replace(reference or TestPlan(), amplitudes_nm=amplitudes, validation_nm=0.0)
    options = options or SimulationOptions()
    theta = theta_from_parameters(prior)
    values = np.array([theta[name] for name in THETA_NAMES])
    # the box the identification searches by default: the prior's +-100 % alone caps the mass
    # ratio x12 at 0.95, and a prior with J3 near 5 % of the inertia (vehicle_1 of
    # ../shared/independent, or a vehicle drawn around it) lay outside it: its finite
    # differences, clipped to the box, were 0/0
    par = Parameterization.around(prior, prior.T_loss, prior.K, bounds=passenger_car_bounds(prior))
    unit = par.unit(values[None])[0]
    span = par.upper - par.lower
    seen: list[list[dict[str, np.ndarray]]] = [[] for _ in amplitudes]  # per run, per seed
    unusable: dict[int, str] = {}
    excursions, coherences, setpoints = [], [], []
    for seed in range(seeds):
        result = simulate(prior, plan, options, seed=1000 + seed)
        try:
            test = MeasuredTest.from_data(
                f"seed {seed}", from_simulation(result), RESOLUTION_HZ, vehicle
            )
        except AnalysisError as error:
            raise AnalysisError(
                f"no chirp of the test simulated at the prior gave an FRF ({error}); "
                "the prior cannot be planned for"
            ) from error
        for run, why in test.unusable:
            unusable.setdefault(_nearest(amplitudes, run.amplitude_nm), why)
        index = [_nearest(amplitudes, e.run.amplitude_nm) for e in test.estimates]
        runs = list(range(len(test.estimates)))
        drv = [e.drv_db for e in test.estimates]
        objective = Objective(par, [test.model_test(runs)], [drv]).replacing(seed=seed)
        spreads = np.concatenate([np.full(len(d), np.linalg.norm(d - d.mean())) for d in drv])
        jac, res = jacobian(objective, unit)
        bounds = np.cumsum([0] + [len(d) for d in drv])
        for i, (k, estimate) in enumerate(zip(index, test.estimates, strict=True)):
            rows = slice(bounds[i], bounds[i + 1])
            seen[k].append(
                {
                    "bin": np.round(estimate.frequency_hz / RESOLUTION_HZ).astype(int),
                    "frequency": estimate.frequency_hz,
                    "jacobian": jac[rows] * spreads[rows, None] / span,  # dB per SI unit
                    "residual": -res[rows] * spreads[rows],  # measured minus model, dB
                    "drv": drv[i],
                }
            )
        idle = test.setpoint_rpm
        setpoints.append(idle)
        excursion = np.full(len(amplitudes), np.nan)
        coherence = np.full(len(amplitudes), np.nan)
        for run in [e.run for e in test.estimates] + [run for run, _ in test.unusable]:
            within = result.speed_rpm[_within(result.speed_t, run)]
            excursion[_nearest(amplitudes, run.amplitude_nm)] = np.max(np.abs(within - idle))
        coherence[index] = [np.median(e.coherence) for e in test.estimates]
        excursions.append(excursion)
        coherences.append(coherence)
    for k, per_seed in enumerate(seen):
        if len(per_seed) < seeds:
            unusable.setdefault(k, "the simulated test held no chirp run at this amplitude")
    levels = []
    for k, per_seed in enumerate(seen):
        if k in unusable:
            measured = np.array(excursions)[:, k]
            levels.append(
                LevelInformation(
                    amplitude_nm=amplitudes[k],
                    frequency_hz=np.zeros(0),
                    drv_db=np.zeros(0),
                    jacobian_db=np.zeros((0, len(THETA_NAMES))),
                    sigma_db=np.zeros(0),
                    correlation=np.ones(1),
                    speed_excursion_rpm=(
                        float(np.nanmax(measured)) if np.isfinite(measured).any() else np.nan
                    ),
                    coherence=np.nan,
                    unusable=unusable[k],
                )
            )
            continue
        # a seed's idle speed sets its frequency axis and its band's top: keep the common bins
        common = functools.reduce(np.intersect1d, [s["bin"] for s in per_seed])
        picked = [
            {key: value[np.isin(s["bin"], common)] for key, value in s.items()} for s in per_seed
        ]
        residual = np.array([s["residual"] for s in picked])
        levels.append(
            LevelInformation(
                amplitude_nm=amplitudes[k],
                frequency_hz=np.mean([s["frequency"] for s in picked], axis=0),
                drv_db=np.mean([s["drv"] for s in picked], axis=0),
                jacobian_db=np.mean([s["jacobian"] for s in picked], axis=0),
                sigma_db=np.sqrt(uniform_filter1d(np.mean(residual**2, axis=0), SMOOTHING_BINS)),
                correlation=pooled_correlation(residual),
                speed_excursion_rpm=float(np.max(np.array(excursions)[:, k])),
                coherence=float(np.median(np.array(coherences)[:, k])),
            )
        )
    return PlanInformation(
        prior=prior,
        values=values,
        reference=plan,
        levels=tuple(levels),
        setpoint_rpm=float(np.mean(setpoints)),
        seeds=seeds,
    )


def pooled_correlation(residuals: np.ndarray) -> np.ndarray:
    """Correlation of residuals between bins 0..:data:`MAX_LAG_BINS` apart, pooled over seeds.

    Parameters
    ----------
    residuals
        (seeds, bins) residuals of one run, dB.

    Returns
    -------
    numpy.ndarray
        Correlation at lags 0, 1, ..., cut (to zero) from its first lag below
        :data:`CORRELATION_FLOOR` (:meth:`LevelInformation.covariance` clips the Toeplitz
        matrix it makes to positive semi-definite).
    """
    z = residuals / np.maximum(np.sqrt(np.mean(residuals**2, axis=0)), 1e-12)
    n = z.shape[1]
    values = [1.0]
    for lag in range(1, min(MAX_LAG_BINS, n - 1) + 1):
        rho = float(np.mean(z[:, :-lag] * z[:, lag:]))
        if rho < CORRELATION_FLOOR:
            break
        values.append(rho)
    return np.array(values)


def _nearest(amplitudes: Sequence[float], amplitude: float) -> int:
    """Index of the simulated amplitude a run belongs to."""
    return int(np.argmin(np.abs(np.asarray(amplitudes) - amplitude)))


def _within(t: np.ndarray, run: ChirpRun) -> np.ndarray:
    return (t >= run.start_s) & (t <= run.end_s)
