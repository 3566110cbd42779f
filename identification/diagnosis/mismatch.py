"""Where an identified model misses the recordings: standardised residuals, a mismatch map over
frequency and amplitude, and one global adequacy test.

For every analysed chirp run (identifying and validating alike) the residual is the measured
|G_DRV| minus the identified model's, in dB, bin by bin, and likewise |G_ENG| (eq. 15: the mean
torque per requested torque) where the recording carries the ECU's torque request: an
engine-side effect (a torque lag, a sensor gain) shows there, a drivetrain one in |G_DRV|. The
model's |G_ENG| comes from the same simulations as its |G_DRV| (its mean torque against the
request its ECU held). Its level is K, which eq. (24) reads off the measured |G_ENG| itself but
which the model's strokes scale by a transfer of the vehicle's timing (eq. 24 is 1-4 % off on
some ECUs, :func:`dtid.identification.model.idle_loop.stroke_gain`), so |G_ENG| is compared in
shape: the model's curves move by the one level that fits all runs best (``level_db``,
reported: the K the model's own |G_ENG| asks for, against the identification's), and an
engine path that differs over frequency (a torque lag) stays.

Each residual is standardised by the scatter a recording of the model itself would show there,
measured rather than assumed: the model repeats the recording ``draws`` times, each time as one
recording (one realization, its own draws of the combustion variation and the sensors' noise as
measured on the vehicle), and the spread of those curves around their mean is the bin's measurement
scatter. The model's own curve (the mean of its antithetic realizations) carries part of that
scatter as well, 1/``realizations`` of its variance, which is added. The coherence formula of
Bendat and Piersol (random error of |H| from gamma^2 and the number of averages) is not used: in a
chirp each bin is seen by about two Welch segments, far from the many averages of stationary noise
it assumes; the recorded coherence is reported per band instead.

Neighbouring bins are correlated (Hann window, half overlap, and the sweep itself). Their
correlation is measured on the same draws (lag-one autocorrelation of the standardised deviations
over frequency, pooled over runs, separately for each FRF, whose noise differs) and gives the
effective number of independent bins, M_eff = N (1 - rho) / (1 + rho), summed over both. The
bins' p-values (Student's t with the scatter's degrees of freedom) are compared with Sidak's
threshold over M_eff tests. A band is a run of neighbouring bins whose residual has one sign
and |z| >= ``EDGE_Z``, holding at least one bin past the threshold; its p-value is family-wise
adjusted.

A bin-wise maximum is weak against a deviation spread smoothly over a whole band, each bin within
its scatter (a torque lag tilts |G_ENG| by a few dB over 1.5-14.5 Hz). So each run's residual is
also tested for a smooth trend (:func:`trend_test`: its projection on Legendre polynomials of
degree 0 to 3 over the band, against the covariance the bins' measured correlation gives it,
chi-square), Sidak over the runs; a significant trend is a band of kind ``trend`` over the whole
run. The two tests share the family-wise error rate ``family_error`` (1 %, Bonferroni: half
each). The global test is both statistics over every run and both FRFs: no band, no mismatch,
and the answer is "the model explains these recordings".
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import stats

from dtid.errors import AnalysisError, DtidError
from dtid.identification.diagnosis.bin_statistics import (
    bin_autocorrelation,
    family_p_value,
    neighbour_correlation,
    sidak,
    trend_test,
)
from dtid.identification.frf.closed_loop import FrfEstimate
from dtid.identification.model.response import model_curves
from dtid.identification.pipeline import IdentificationReport, RunSelection
from dtid.simulator.parameters import DrivetrainParameters

logger = logging.getLogger(__name__)

FAMILY_ERROR = 0.01
"""Family-wise error rate of the mismatch map (the chance of any band on a model that is right)."""
EDGE_Z = 2.0
"""|z| at which a band's neighbouring bins still belong to it."""
DRAWS = 16
"""Recordings of the model drawn to measure each bin's scatter."""
SMOOTH_BINS = 5
"""Bins over which each bin's scatter variance is averaged (steadies it, adds freedom)."""
NO_SCATTER_DB = 1e-6
"""A model whose draws scatter less than this (dB) draws no noise (rounding aside)."""
ROUGH_SCALE = 10.0
"""Scatter scale (:func:`scatter_scale`) beyond which the model's draws stand for little of a
recording's noise, so the map's scatter keeps the draws' shape and not the recording's: the
independent recordings' scales are 1.6-2.2; vehicle 34's |G_ENG|, whose model drew no torque
noise before the combustion line's fallback (docs/diagnosis.md), had 1047 and a band where the
recording was merely noisy."""
DRAW_SEED = 7_000
"""First seed of the draws (apart from the identification's model seeds)."""
FRFS = ("drv", "eng")
"""The frequency responses the map compares: |G_DRV| (eq. 14) and |G_ENG| (eq. 15)."""
FAMILIES = 2
"""Tests sharing the family-wise error (Bonferroni): the bins' largest |z| and the runs' smooth
trends, each at ``family_error / FAMILIES``."""
TREND_LAGS = 12
"""Lags (bins) over which the trend test measures the bins' correlation; beyond, none."""
TREND_WINDOW = 0.25
"""Width of the running mean a trend band reports its excess from, as a share of the run's
bins (:func:`trend_db`)."""


@dataclass(frozen=True)
class RunResidual:
    """Measured minus model |G_DRV| of one chirp run, and its standardisation.

    Attributes
    ----------
    label
        ``recording @ A N*m``.
    role
        ``fit`` (an identifying run) or ``validation``.
    frf
        ``drv`` (|G_DRV|) or ``eng`` (|G_ENG|).
    amplitude_nm
        The chirp's amplitude, N*m.
    frequency_hz
        Bins, Hz.
    measured_db, model_db
        |G_DRV|, dB re 1 (rad/s)/(N*m), or |G_ENG|, dB re 1.
    scatter_db
        Standard deviation of a recording's curve about the model's, dB.
    z
        (measured - model) / scatter.
    coherence
        The recording's coherence per bin.
    """

    label: str
    role: str
    frf: str
    amplitude_nm: float
    frequency_hz: np.ndarray
    measured_db: np.ndarray
    model_db: np.ndarray
    scatter_db: np.ndarray
    z: np.ndarray
    coherence: np.ndarray

    @property
    def residual_db(self) -> np.ndarray:
        """Measured minus model, dB."""
        return self.measured_db - self.model_db


@dataclass(frozen=True)
class MismatchBand:
    """A band where the model misses a run significantly.

    Attributes
    ----------
    frf
        ``drv`` or ``eng``.
    label, role, amplitude_nm
        The run's.
    f_lo_hz, f_hi_hz
        The band, Hz.
    excess_db
        Measured minus model at the band's most significant bin, dB (positive: the vehicle
        responds more).
    p_value
        Family-wise adjusted p-value of that bin.
    peak_hz
        Frequency of that bin, Hz.
    coherence
        The recording's median coherence over the band.
    kind
        ``bins`` (neighbouring bins past the threshold) or ``trend`` (the run's smooth trend
        over its whole band, :func:`trend_test`; excess and peak where the residual's running
        mean, :func:`trend_db`, is largest).
    """

    frf: str
    label: str
    role: str
    amplitude_nm: float
    f_lo_hz: float
    f_hi_hz: float
    excess_db: float
    p_value: float
    peak_hz: float
    coherence: float
    kind: str = "bins"

    def as_dict(self) -> dict[str, object]:
        """The band as in the diagnosis JSON's ``mismatch`` list."""
        return {
            "frf": self.frf,
            "amplitude_nm": self.amplitude_nm,
            "f_lo_hz": self.f_lo_hz,
            "f_hi_hz": self.f_hi_hz,
            "excess_db": self.excess_db,
            "p_value": self.p_value,
            "peak_hz": self.peak_hz,
            "run": self.label,
            "role": self.role,
            "coherence": self.coherence,
            "kind": self.kind,
        }


@dataclass(frozen=True)
class MismatchMap:
    """The mismatch map of one model against its recordings.

    Attributes
    ----------
    residuals
        Every analysed run's residual.
    bands
        The significant bands, most significant first.
    drv
        |G_DRV|'s noise figures (scatter scale, bin correlation, M_eff, degrees of freedom,
        threshold).
    effective_bins
        M_eff over all runs and both FRFs.
    global_p_value
        Family-wise p-value of the most significant bin or trend: below ``family_error`` iff
        any band.
    family_error
        The family-wise error rate.
    engine
        |G_ENG|'s noise figures, with the level moved onto the model's curves (None: no run has
        |G_ENG|).
    """

    residuals: tuple[RunResidual, ...]
    bands: tuple[MismatchBand, ...]
    drv: NoiseFigures
    effective_bins: float
    global_p_value: float
    family_error: float = FAMILY_ERROR
    engine: NoiseFigures | None = None

    @property
    def adequate(self) -> bool:
        """True when nothing is significant: the model explains the recordings."""
        return not self.bands

    def noise_warnings(self) -> list[str]:
        """What to say of an FRF whose scatter scale passes :data:`ROUGH_SCALE`: the map's
        bands there may be the recording's own noise."""
        figures = {"drv": self.drv, "eng": self.engine}
        return [
            f"the recordings' |G_{frf.upper()}| residuals are {f.scatter_scale:.0f} times rougher "
            "over frequency than the model's own draws of them: the noise the model repeats (the "
            "combustion variation and the torque sensor's noise read at idle, the identification "
            "JSON's idle_loop) stands for little of this recording's, so the map's scatter keeps "
            "the draws' shape and may put a band where the recording is merely noisy; where the "
            "vehicle's indicating system gives the COV of IMEP, identify again with --fix "
            "combustion_variation=VALUE"
            for frf, f in figures.items()
            if f is not None and f.scatter_scale > ROUGH_SCALE
        ]

    def threshold_of(self, frf: str) -> float:
        """|z| a bin of ``frf`` (``drv`` or ``eng``) must pass."""
        if frf == "eng" and self.engine is not None:
            return self.engine.threshold_z
        return self.drv.threshold_z

    def as_dict(self) -> dict[str, object]:
        """The map's figures for the diagnosis JSON (``test``)."""
        return {
            "family_error": self.family_error,
            "scatter_scale": self.drv.scatter_scale,
            "effective_bins": self.effective_bins,
            "bin_correlation": self.drv.correlation,
            "degrees_of_freedom": self.drv.degrees_of_freedom,
            "threshold_z": self.drv.threshold_z,
            "global_p_value": self.global_p_value,
            "eng": None if self.engine is None else self.engine.as_dict(),
        }


class NoiseFigures(NamedTuple):
    """How one FRF's recordings scatter, as the map measured it (:func:`mismatch_map`).

    Attributes
    ----------
    scatter_scale
        Factor on the model's scatter for the recordings' roughness (:func:`scatter_scale`).
    correlation
        Lag-one correlation of neighbouring bins' deviations.
    effective_bins
        M_eff of this FRF's bins.
    degrees_of_freedom
        Of its bins' t statistics.
    threshold_z
        |z| a bin must pass.
    level_db
        The level moved onto the model's curves, dB (|G_ENG|: 20 log10 of the K its model asks
        for over the identification's; 0 for |G_DRV|).
    """

    scatter_scale: float
    correlation: float
    effective_bins: float
    degrees_of_freedom: float
    threshold_z: float
    level_db: float = 0.0

    def as_dict(self) -> dict[str, float]:
        """The figures as in the diagnosis JSON's ``test.eng``."""
        return {
            "scatter_scale": self.scatter_scale,
            "effective_bins": self.effective_bins,
            "bin_correlation": self.correlation,
            "degrees_of_freedom": self.degrees_of_freedom,
            "threshold_z": self.threshold_z,
            "level_db": self.level_db,
        }


def mismatch_map(
    parameters: DrivetrainParameters | np.ndarray,
    selections: Sequence[tuple[str, RunSelection]],
    draws: int = DRAWS,
    family_error: float = FAMILY_ERROR,
) -> MismatchMap:
    """Locate where a model misses its recordings (see the module notes).

    Parameters
    ----------
    parameters
        The model's parameters (K and T_loss as identified), or its kernel row with mechanisms
        added (:func:`model_row`).
    selections
        ``(role, selection)`` pairs: the identification's runs (``fit``) and the held-out ones
        (``validation``), each test with the combustion variation the model repeats.
    draws
        Model recordings drawn per run for its scatter (at least 4).
    family_error
        Family-wise error rate of the map.

    Returns
    -------
    MismatchMap
    """
    if draws < 4:
        raise ValueError(f"draws must be at least 4 for a scatter, got {draws}")
    runs = [
        run
        for role, selection in selections
        for run in model_scatter(parameters, role, selection, draws)
    ]
    by_frf = {frf: [run for run in runs if run.frf == frf] for frf in FRFS}
    by_frf = {frf: chosen for frf, chosen in by_frf.items() if chosen}
    spread = {frf: _spread(chosen, draws) for frf, chosen in by_frf.items()}
    effective = sum(figures.effective_bins for figures in spread.values())
    share = family_error / FAMILIES
    bin_error = 1.0 - (1.0 - share) ** (1.0 / effective)
    correlation = {
        frf: bin_autocorrelation([run.deviations / run.scatter_db for run in chosen], TREND_LAGS)
        for frf, chosen in by_frf.items()
    }
    levels = {  # |G_ENG| is compared in shape (module notes)
        frf: float(
            shape_level([run.residual_db for run in chosen], [run.scatter_db for run in chosen])[0]
        )
        for frf, chosen in by_frf.items()
        if frf == "eng"
    }
    figures = {
        frf: f._replace(
            threshold_z=float(stats.t.isf(bin_error / 2, f.degrees_of_freedom)),
            level_db=levels.get(frf, 0.0),
        )
        for frf, f in spread.items()
    }
    residuals, bands = [], []
    global_p = 1.0
    for run in runs:
        noise = figures[run.frf]
        estimate, scatter = run.estimate, run.scatter_db * noise.scatter_scale
        model_db = run.model_db + noise.level_db
        with np.errstate(invalid="ignore", divide="ignore"):
            z = (run.measured_db - model_db) / scatter
        residual = RunResidual(
            run.label,
            run.role,
            run.frf,
            estimate.run.amplitude_nm,
            estimate.frequency_hz,
            run.measured_db,
            model_db,
            scatter,
            z,
            estimate.coherence,
        )
        residuals.append(residual)
        finite = np.isfinite(z)
        if finite.any():
            largest = float(np.max(np.abs(z[finite])))
            single = family_p_value(largest, effective, noise.degrees_of_freedom)
            global_p = min(global_p, FAMILIES * single)
        bands.extend(
            dataclasses.replace(band, p_value=min(1.0, FAMILIES * band.p_value))
            for band in find_bands(residual, noise.threshold_z, effective, noise.degrees_of_freedom)
        )
        trend = trend_band(residual, correlation[run.frf], len(runs))
        if trend is not None:
            global_p = min(global_p, trend.p_value)
            if trend.p_value < family_error:
                bands.append(trend)
    bands.sort(key=lambda band: (band.p_value, -abs(band.excess_db)))
    return MismatchMap(
        tuple(residuals),
        tuple(bands),
        figures["drv"],
        effective,
        global_p,
        family_error,
        figures.get("eng"),
    )


def shape_level(residuals: Sequence[np.ndarray], scatters: Sequence[np.ndarray]) -> np.ndarray:
    """The one level, dB, that moves a model's curves closest to the measured over all runs,
    each bin weighted by its inverse scatter variance: how |G_ENG| is compared in shape.

    Parameters
    ----------
    residuals
        Per run, measured minus model, dB: (bins,) for one model or (n, bins) for n.
    scatters
        Per run, the bins' scatter, dB (bins,).

    Returns
    -------
    numpy.ndarray
        (n,) levels (0 for a model without a finite bin).
    """
    residual = np.hstack([np.atleast_2d(r) for r in residuals])
    weight = np.concatenate(scatters) ** -2.0
    weight = np.where(np.isfinite(residual) & np.isfinite(weight), weight, 0.0)
    total = np.sum(weight, axis=1)
    weighted = np.sum(np.where(weight > 0, residual, 0.0) * weight, axis=1)
    return weighted / np.where(total > 0, total, 1.0)


def _spread(runs: Sequence[ModelScatter], draws: int) -> NoiseFigures:
    """One FRF's noise figures over its runs (the threshold to be set over both FRFs)."""
    standard = [run.deviations / run.scatter_db for run in runs]
    correlation = neighbour_correlation(standard)
    scale = scatter_scale([run.residual_db / run.scatter_db for run in runs], standard)
    n_bins = sum(len(run.model_db) for run in runs)
    effective = max(1.0, n_bins * (1.0 - correlation) / (1.0 + correlation))
    dof = (draws - 1) * max(1.0, SMOOTH_BINS * (1.0 - correlation) / (1.0 + correlation))
    return NoiseFigures(scale, correlation, effective, dof, math.nan)


def adequacy(report: IdentificationReport) -> dict[str, Any] | None:
    """Does an identified model explain its recordings? The global test of :func:`mismatch_map`
    on the identifying and validating runs, as a campaign's plan carries it (``fit``:
    ``adequate``, ``global_p_value``, ``bands``); None, logged, when it cannot be computed.

    A search that ended at another optimum leaves bands no noise explains: on the campaign
    trial's truth 4 (eq. 17 0.196 against 0.076 near the truth) p = 0.003, one band; on truths 5
    and 6, whose searches found the truth's optimum, p = 0.24 and 0.25, none.
    """
    selections = [("fit", report.fit)]
    if report.validation is not None and report.validation.tests:
        selections.append(("validation", report.validation))
    try:
        found = mismatch_map(report.identification.parameters, selections)
    except (DtidError, ValueError) as error:
        logger.warning("the fit's adequacy test: %s", error)
        return None
    return adequacy_of(found)


def adequacy_of(found: MismatchMap) -> dict[str, Any]:
    """The ``fit`` entry of a campaign's plan from a mismatch map already made (a diagnosis's:
    the same runs and draws as :func:`adequacy`)."""
    return {
        "adequate": found.adequate,
        "global_p_value": found.global_p_value,
        "bands": len(found.bands),
    }


class ModelScatter(NamedTuple):
    """One run's model curve of one FRF and the scatter of the model's own recordings about it.

    Attributes
    ----------
    label, role
        ``recording @ A N*m`` and ``fit`` / ``validation``.
    frf
        ``drv`` or ``eng``.
    estimate
        The measured FRFs.
    model_db
        The model's |G_DRV| or |G_ENG| (its antithetic realizations' mean), dB.
    scatter_db
        Standard deviation of one recording's curve about it, dB (smoothed over
        :data:`SMOOTH_BINS`, the model curve's own share added).
    deviations
        (draws, bins) the draws' curves less their mean, dB.
    """

    label: str
    role: str
    frf: str
    estimate: FrfEstimate
    model_db: np.ndarray
    scatter_db: np.ndarray
    deviations: np.ndarray

    @property
    def measured_db(self) -> np.ndarray:
        """The recording's curve of this FRF, dB."""
        return self.estimate.drv_db if self.frf == "drv" else self.estimate.eng_db

    @property
    def residual_db(self) -> np.ndarray:
        """Measured minus model, dB."""
        return self.measured_db - self.model_db


def model_row(parameters: DrivetrainParameters | np.ndarray) -> np.ndarray:
    """A model as the kernel row it is simulated with: a drivetrain parameter set, or a row
    that has mechanism columns already (:mod:`dtid.simulator.mechanisms`)."""
    if isinstance(parameters, DrivetrainParameters):
        return parameters.as_array()
    return np.asarray(parameters, dtype=np.float64)


def model_scatter(
    parameters: DrivetrainParameters | np.ndarray,
    role: str,
    selection: RunSelection,
    draws: int,
) -> list[ModelScatter]:
    """Each run's model curve and scatter (see the module notes), for one selection."""
    params = model_row(parameters)[None]
    out = []
    for test, runs in zip(selection.tests, selection.runs, strict=True):
        model_test = test.model_test(runs)
        model = model_curves(params, model_test)
        singles = [
            model_curves(
                params,
                dataclasses.replace(
                    model_test,
                    realizations=1,
                    antithetic=False,
                    recording_noise=True,
                    seed=DRAW_SEED + k,
                ),
            )
            for k in range(draws)
        ]
        for position, i in enumerate(runs):
            estimate = test.estimates[i]
            label = test.run_label(i)
            for frf in FRFS:
                curve = model[position].drv_db if frf == "drv" else model[position].eng_db
                if frf == "eng" and not (
                    np.isfinite(estimate.eng).any() and np.isfinite(curve).any()
                ):
                    continue  # no torque request recorded, or a model driven by the torque
                draws_db = np.array(
                    [
                        (s[position].drv_db if frf == "drv" else s[position].eng_db)[0]
                        for s in singles
                    ]
                )
                if not np.nanmax(np.nanstd(draws_db, axis=0), initial=0.0) > NO_SCATTER_DB:
                    raise AnalysisError(
                        f"{test.name}: the model of this recording draws no noise (without a "
                        "torque_request role the measured torque drives it, variation and all), "
                        "so the diagnosis cannot tell a mismatch from the recording's scatter; "
                        "map the ECU's torque request in the signal map (docs/vehicle.md) and "
                        "record it"
                    )
                variance = smoothed(np.nanvar(draws_db, axis=0, ddof=1), estimate.excitation)
                variance *= 1.0 + 1.0 / model_test.realizations
                out.append(
                    ModelScatter(
                        label,
                        role,
                        frf,
                        estimate,
                        curve[0],
                        np.sqrt(variance),
                        draws_db - np.nanmean(draws_db, axis=0),
                    )
                )
    return out


def scatter_scale(standardised: Sequence[np.ndarray], deviations: Sequence[np.ndarray]) -> float:
    """How much rougher over frequency the recordings' residuals are than the model's own
    recordings, at least 1.

    The model's draws hold the noise the model knows (combustion variation, torque sensor);
    a vehicle has more (the speed sensor's jitter, disturbances nobody modelled). Such noise makes
    neighbouring bins differ; a physics the model lacks bends the residual smoothly over a band.
    The ratio of the median absolute neighbour differences, residual over draws (robust: a
    mismatch's band moves a median little), scales the scatter up when the recording is noisier.

    Parameters
    ----------
    standardised
        Per run, the residual divided by the model's scatter, (bins,).
    deviations
        Per run, the draws' deviations divided by the scatter, (draws, bins).
    """
    measured = np.concatenate([np.abs(np.diff(r)) for r in standardised])
    drawn = np.concatenate([np.abs(np.diff(d, axis=-1)).ravel() for d in deviations])
    measured, drawn = measured[np.isfinite(measured)], drawn[np.isfinite(drawn)]
    if len(measured) == 0 or len(drawn) == 0 or np.median(drawn) == 0:
        return 1.0
    return max(1.0, float(np.median(measured) / np.median(drawn)))


def smoothed(variance: np.ndarray, excitation: np.ndarray) -> np.ndarray:
    """A bin's variance averaged with its neighbours' over :data:`SMOOTH_BINS` (edges shorter),
    in proportion to the bin's excitation.

    An FRF's variance goes as the noise over the excitation, 1/S_zz. A chirp's S_zz is flat
    over its sweep but falls in the bins at its ends, which fewer Welch segments see whole, and
    the scatter rises there in one bin: the reference vehicle's |G_DRV| at 5 N*m scatters 0.40
    dB in its top bin over 24 seeds, 0.17-0.21 dB in the three below. So the average is
    taken of variance x S_zz, the noise's own smooth share, and divided by the bin's S_zz: a
    plain average over the neighbours halved that bin's scatter.

    Parameters
    ----------
    variance
        Per bin, the draws' variance, dB^2.
    excitation
        Per bin, the test torque's auto-spectrum S_zz, (N*m)^2/Hz (a bin without any: NaN).
    """
    finite = np.isfinite(variance) & (excitation > 0)
    kernel = np.ones(SMOOTH_BINS)
    total = np.convolve(np.where(finite, variance * excitation, 0.0), kernel, mode="same")
    count = np.convolve(finite.astype(float), kernel, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((count > 0) & (excitation > 0), total / count / excitation, np.nan)


def trend_db(residual: RunResidual) -> np.ndarray:
    """One run's residual smoothed in dB: measured minus model, its running mean over
    :data:`TREND_WINDOW` of the band's bins, each bin weighted by its inverse scatter variance
    (NaN where the residual or its scatter is not finite). What a trend band reports as its
    excess: a mean of the residual, never beyond it.

    The test's trend (:func:`trend_test`, cubic in z) is no curve in dB, and where the model
    lacks a mode it swings past the band's edge: on a concealed accessory mode (residual
    -8.7 dB at 10 Hz, +7.6 at 11.7 Hz, +2.8 at 13.5 Hz), scaled back by the edge bin's scatter
    it read +52 dB, a weighted cubic in dB +20 dB there.
    """
    finite = (
        np.isfinite(residual.residual_db)
        & np.isfinite(residual.scatter_db)
        & (residual.scatter_db > 0)
    )
    weight = np.where(finite, residual.scatter_db, 1.0) ** -2.0 * finite
    width = max(1, round(TREND_WINDOW * int(finite.sum())))
    kernel = np.ones(width)
    total = np.convolve(weight, kernel, mode="same")
    weighted = np.convolve(np.where(finite, residual.residual_db, 0.0) * weight, kernel, "same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(finite & (total > 0), weighted / total, np.nan)


def trend_band(
    residual: RunResidual, autocorrelation: np.ndarray, tests: int
) -> MismatchBand | None:
    """One run's smooth trend as a band over its whole frequency range (:func:`trend_test`), its
    p-value family-wise over ``tests`` runs (Sidak) and the :data:`FAMILIES` (Bonferroni); None
    when the run has too few bins."""
    statistic, dof, trend = trend_test(residual.z, residual.frequency_hz, autocorrelation)
    if dof == 0:
        return None
    single = float(stats.chi2.sf(statistic, dof))
    family = sidak(single, tests)
    excess = trend_db(residual)
    peak = int(np.nanargmax(np.abs(excess)))
    used = np.isfinite(trend)
    return MismatchBand(
        residual.frf,
        residual.label,
        residual.role,
        residual.amplitude_nm,
        float(residual.frequency_hz[used][0]),
        float(residual.frequency_hz[used][-1]),
        float(excess[peak]),
        min(1.0, FAMILIES * family),
        float(residual.frequency_hz[peak]),
        float(np.median(residual.coherence[used])),
        "trend",
    )


def find_bands(
    residual: RunResidual, threshold: float, effective: float, dof: float
) -> list[MismatchBand]:
    """The significant bands of one run (see the module notes)."""
    z = residual.z
    bands = []
    n = len(z)
    i = 0
    while i < n:
        if not (np.isfinite(z[i]) and abs(z[i]) >= EDGE_Z):
            i += 1
            continue
        sign = np.sign(z[i])
        j = i
        while j + 1 < n and np.isfinite(z[j + 1]) and z[j + 1] * sign >= EDGE_Z:
            j += 1
        stretch = slice(i, j + 1)
        peak = i + int(np.argmax(np.abs(z[stretch])))
        if abs(z[peak]) >= threshold:
            bands.append(
                MismatchBand(
                    residual.frf,
                    residual.label,
                    residual.role,
                    residual.amplitude_nm,
                    float(residual.frequency_hz[i]),
                    float(residual.frequency_hz[j]),
                    float(residual.residual_db[peak]),
                    family_p_value(float(z[peak]), effective, dof),
                    float(residual.frequency_hz[peak]),
                    float(np.median(residual.coherence[stretch])),
                )
            )
        i = j + 1
    return bands
