"""From measured tests to an identification report: search, profiles, JSON (``dtid identify``).

Validation data are held out: the identification sees each recording only up to
:data:`HOLD_OUT_S` after its last identification run (before the next chirp, if that starts
sooner), so K (eq. 24) comes from the identification runs alone and T_loss, the idle set-point
and the combustion variation from the idle before that time. A chirp recorded later (the
validation chirp A3 of a vehicle test) cannot change the identified parameters: the worker
identifies while A3 is still being recorded and gets what ``dtid identify`` gets from the whole
log. The validation runs are evaluated on each recording up to :data:`HOLD_OUT_S` after its last
run, so what follows the test (the daemon's last frames) does not matter either.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dtid.errors import ConfigError
from dtid.identification.frf.closed_loop import DEFAULT_RESOLUTION_HZ, FrfEstimate
from dtid.identification.frf.runs import ZERO_FRACTION
from dtid.identification.gain_choice import (
    gain_mismatch,
    gain_warning,
    held_gain,
    lag_warning,
    model_gain,
)
from dtid.identification.model.response import model_drv_db
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.testdata import Series, TestData
from dtid.identification.search.analytic import inseparable
from dtid.identification.search.identify import (
    Identification,
    Progress,
    SearchSettings,
    identify,
    identify_from,
    nrmse_by_run,
)
from dtid.identification.search.objective import FAILED_NRMSE, Objective
from dtid.identification.search.parameterization import (
    PRIOR_SPAN,
    THETA_NAMES,
    THETA_UNITS,
    Parameterization,
    passenger_car_bounds,
    theta_from_parameters,
    theta_to_arrays,
)
from dtid.identification.search.runs import amplitude_levels, runs_at, split_runs
from dtid.identification.search.start_values import start_thetas
from dtid.identification.uncertainty.comparison import (
    Comparison,
    outside_intervals,
    point_test,
)
from dtid.identification.uncertainty.gear_play import (
    GEAR_PLAY_CHECKS,
    check_name,
    gear_play_check,
    moved_off,
)
from dtid.identification.uncertainty.profile import Profile, profile, with_structure
from dtid.identification.uncertainty.statistic import THRESHOLD
from dtid.identification.uncertainty.target_test import TargetTest, target_test
from dtid.jsonfile import finite, write_json
from dtid.simulator.parameters import UNITS, DrivetrainParameters

if TYPE_CHECKING:
    from matplotlib.figure import Figure

logger = logging.getLogger(__name__)

OPERATING_POINT = ("K", "T_loss", "combustion_variation")
"""What is measured of the operating point before the drivetrain fit, each fixable too: K
(eq. 24), T_loss (the idle torque, N*m) and the relative cycle-to-cycle variation of each
stroke's mean torque that the model engine repeats
(:attr:`dtid.identification.model.test_setup.MeasuredTest.combustion_variation`). Measured at idle,
the variation counts the torque sensor's noise in; where the vehicle's indicating system gives the
COV of IMEP, that is the better value."""
HOLD_OUT_S = 2.0
"""Data kept after the last run a test analyses, s: one second of idle past the idle margin
(:data:`dtid.identification.model.test_setup.IDLE_MARGIN_S`), and less than the test's 3 s pause."""


@dataclass(frozen=True)
class RunSelection:
    """Measured tests cut :data:`HOLD_OUT_S` after the runs they analyse, with those runs.

    Attributes
    ----------
    tests
        One per recording that has such runs, rebuilt from its data up to the cut; ordered by
        their runs' amplitudes and FRFs, whatever order the recordings came in
        (:func:`_content_key`).
    runs
        Indices of the analysed runs in each test's estimates.
    cuts_s
        Where each test's data end, s (recording time).
    """

    tests: tuple[MeasuredTest, ...]
    runs: tuple[tuple[int, ...], ...]
    cuts_s: tuple[float, ...]

    def estimates(self) -> list[FrfEstimate]:
        """The analysed runs' FRFs, in order."""
        return [t.estimates[i] for t, runs in zip(self.tests, self.runs, strict=True) for i in runs]

    def objective(self, parameterization: Parameterization) -> Objective:
        """Eq. (17) over the analysed runs, over the parameterization's free values."""
        pairs = list(zip(self.tests, self.runs, strict=True))
        return Objective(
            parameterization,
            [t.model_test(runs) for t, runs in pairs],
            [[t.estimates[i].drv_db for i in runs] for t, runs in pairs],
        )


def cut_time(test_torque: Series, last_end_s: float) -> float:
    """Where a test's data are cut after a run ending at ``last_end_s``, s.

    :data:`HOLD_OUT_S` after it, or just before the next non-zero test torque if that comes
    sooner (a chirp following after a short pause is left out whole).
    """
    t, value = test_torque.t, test_torque.value
    before = t <= last_end_s
    peak = float(np.max(np.abs(value[before]))) if before.any() else 0.0
    after = (
        (t > last_end_s) & (t < last_end_s + HOLD_OUT_S) & (np.abs(value) > ZERO_FRACTION * peak)
    )
    return float(t[after][0]) if after.any() else last_end_s + HOLD_OUT_S


def truncated(data: TestData, cut_s: float) -> TestData:
    """The test's samples before ``cut_s``."""

    def until(series: Series | None) -> Series | None:
        return None if series is None else series.window(-np.inf, cut_s)

    return TestData(
        speed=until(data.speed),
        mean_torque=until(data.mean_torque),
        test_torque=until(data.test_torque),
        torque_request=until(data.torque_request),
    )


def _select(
    tests: Sequence[MeasuredTest],
    identify_amplitudes: Sequence[float] | None,
    validation: bool,
    resolution_hz: float,
) -> RunSelection:
    ident, valid = split_runs(tests, identify_amplitudes)
    chosen = sorted(
        {
            round(t.estimates[i].run.amplitude_nm, 3)
            for t, runs in zip(tests, ident, strict=True)
            for i in runs
        }
    )
    picked = valid if validation else ident
    selected, indices, cuts = [], [], []
    for test, runs in zip(tests, picked, strict=True):
        if not runs:
            continue
        last = max(range(len(test.estimates)) if validation else runs)
        cut = cut_time(test.data.test_torque, test.estimates[last].run.end_s)
        kept = MeasuredTest.from_data(
            test.name, truncated(test.data, cut), resolution_hz, test.vehicle
        )
        at_levels = runs_at(kept, chosen)
        selected.append(kept)
        indices.append(
            tuple(i for i in range(len(kept.estimates)) if (i in at_levels) != validation)
        )
        cuts.append(cut)
    order = sorted(range(len(selected)), key=lambda k: _content_key(selected[k], indices[k]))
    return RunSelection(
        tuple(selected[k] for k in order),
        tuple(indices[k] for k in order),
        tuple(cuts[k] for k in order),
    )


def _content_key(test: MeasuredTest, runs: Sequence[int]) -> tuple[tuple[float, ...], str]:
    """Where a test goes among the selected ones: by its runs' amplitudes, then by a digest of
    their FRFs, never by the order the recordings were given in or their names.

    The same recordings listed in another order then give the same identification to the last
    bit. Before, the order changed only the arithmetic's last bits (the Levenberg-Marquardt
    steps stack the runs' residuals in order), yet the free plays make the objective chaotic
    enough near the resonance jump that the search's path followed: on vehicle_1 of
    ``../shared/independent`` J3 and c23 ended up to 6 % apart. Content, not names, because
    the worker names the live round differently from the same log replayed.
    """
    digest = hashlib.sha256()
    for i in runs:
        digest.update(np.ascontiguousarray(test.estimates[i].drv_db, dtype=float).tobytes())
    amplitudes = tuple(round(test.estimates[i].run.amplitude_nm, 3) for i in runs)
    return amplitudes, digest.hexdigest()


def identification_runs(
    tests: Sequence[MeasuredTest],
    identify_amplitudes: Sequence[float] | None = None,
    resolution_hz: float = DEFAULT_RESOLUTION_HZ,
) -> RunSelection:
    """The identification runs (see :func:`dtid.identification.search.runs.split_runs`), held
    out."""
    return _select(tests, identify_amplitudes, False, resolution_hz)


def validation_runs(
    tests: Sequence[MeasuredTest],
    identify_amplitudes: Sequence[float] | None = None,
    resolution_hz: float = DEFAULT_RESOLUTION_HZ,
) -> RunSelection:
    """The validation runs: every run whose amplitude does not identify."""
    return _select(tests, identify_amplitudes, True, resolution_hz)


def restart_finder(found_by: str, parameter: str) -> str:
    """What found the better fit a search restarted from, as a phrase (``found_by`` and
    ``parameter`` as :class:`SearchRestart` and its JSON hold them)."""
    if found_by in GEAR_PLAY_CHECKS:
        phrase = " and ".join(f"{f:.3g}" for f in GEAR_PLAY_CHECKS[found_by])
        return f"{parameter} held at {phrase} times the {found_by}'s value"
    return f"the {found_by} of {parameter}"


@dataclass(frozen=True)
class SearchRestart:
    """The search restarted where a profile had found a significantly better fit than its
    optimum (:attr:`dtid.identification.uncertainty.profile.Profile.beats_estimate`), or the
    gear play's check a better one (:func:`dtid.identification.uncertainty.gear_play.moved_off`).

    Attributes
    ----------
    parameter
        The profile that found it (the one whose minimum fitted best).
    statistic
        The search's optimum's likelihood-ratio statistic against that profile's minimum (above
        the 95 % threshold, 3.84, and its margin, for a profile or a target test; above 0 for
        the gear play's check).
    objective_search, objective_restart
        Eq. (17) at the search's optimum and where the restart ended (the report's estimate is
        the lower).
    search_theta
        The search's optimum, setup-4 values by name, SI units.
    found_by
        What held the parameter: ``"profile"``, ``"target test"``, or the gear play's check
        where the search left the play closed or open (:data:`GEAR_PLAY_CHECKS`).
    """

    parameter: str
    statistic: float
    objective_search: float
    objective_restart: float
    search_theta: Mapping[str, float]
    found_by: str = "profile"

    def message(self, adopted: bool) -> str:
        """What happened, for the log."""
        finder = restart_finder(self.found_by, self.parameter)
        if self.found_by in GEAR_PLAY_CHECKS:
            how = (
                f"fitted better than the search's optimum on fresh draws of the model (the "
                f"optimum {self.statistic:.2f} above it on the 95 % scale)"
            )
        else:
            how = (
                f"found a better fit than the search (the search's optimum {self.statistic:.1f} "
                f"above the profile's minimum on the 95 % scale, threshold {THRESHOLD:.2f}, or "
                "its value outside the interval): the search had ended at another optimum"
            )
        head = (
            f"{finder} {how}; restarted from there, "
            f"eq. (17) {self.objective_search:.4f} -> {self.objective_restart:.4f}"
        )
        if adopted and self.found_by == "profile":
            return head + "; the estimate is the restart's (the intervals are the profiles')"
        if adopted:
            return head + "; the estimate is the restart's"
        return head + "; the restart did not improve on the search, whose estimate is kept"

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (``search_restart`` of the identification JSON)."""
        return {
            "parameter": self.parameter,
            "statistic": self.statistic,
            "objective_search": self.objective_search,
            "objective_restart": self.objective_restart,
            "adopted": self.objective_restart < self.objective_search,
            "search_theta": dict(self.search_theta),
            "found_by": self.found_by,
        }


@dataclass(frozen=True)
class IdentificationReport:
    """An identification with its profiles.

    Attributes
    ----------
    identification
        The search's result.
    profiles
        Profile of each free parameter (empty when profiles were not asked for).
    fixed
        Parameters held at a value, by name (setup-4 names, K, T_loss, combustion_variation).
    gain, t_loss
        K and T_loss used, measured or fixed.
    fit, validation
        The identification and validation runs, with the combustion variation the model
        engine repeated in them.
    inseparable
        The free parameters the identification's excitation cannot identify, whatever their
        profiles show, with the reason (:func:`dtid.identification.search.analytic.inseparable`: a
        stiffness and its free play from one amplitude); their verdict is ``no``, with or
        without profiles.
    parameterization
        The search box and the values held (to score or refine other sets in it).
    restart
        Where the search was restarted from a profile (or a target test) that fitted better,
        None when none beat it.
    target_tests
        The likelihood-ratio test at each tested target's ends, by parameter name (empty when
        none was asked for).
    comparison
        Another drivetrain tested against the identified one (:meth:`compared`), None when none
        was given.
    """

    identification: Identification
    profiles: Mapping[str, Profile]
    fixed: Mapping[str, float]
    gain: float
    t_loss: float
    fit: RunSelection | None = None
    validation: RunSelection | None = None
    inseparable: Mapping[str, str] = dataclasses.field(default_factory=dict)
    parameterization: Parameterization | None = None
    restart: SearchRestart | None = None
    target_tests: Mapping[str, TargetTest] = dataclasses.field(default_factory=dict)
    comparison: Comparison | None = None

    def validated(self, selection: RunSelection) -> IdentificationReport:
        """The report with the validation NRMSE of the identified parameters on these runs, the
        model engine varying as it did in the identification."""
        if self.fit is not None:
            variations = {t.name: t.combustion_variation for t in self.fit.tests}
            selection = with_variation(selection, variations)
        params = self.identification.parameters.as_array()[None]
        scores = nrmse_by_run(selection.tests, selection.runs, params)
        warn_unrepeatable(scores, selection.tests)
        result = dataclasses.replace(self.identification, validation_nrmse=scores)
        return dataclasses.replace(self, identification=result, validation=selection)

    def fit_objective(self, parameters: DrivetrainParameters) -> float:
        """Eq. (17) of another parameter set on this report's identification runs, scored as the
        identified one was: the same combustion variation, K and T_loss.

        Below the report's own ``objective``, the search missed a better fit; above it, the data
        prefer what was found (a simulated truth's, for example: its noise's scatter).

        Parameters
        ----------
        parameters
            The set to score; its K and T_loss are replaced by the report's.
        """
        if self.fit is None:
            raise ValueError("the report holds no identification runs to score a set on")
        row = parameters.replace(K=self.gain, T_loss=self.t_loss).as_array()
        return sum(nrmse_by_run(self.fit.tests, self.fit.runs, row[None]).values())

    def compared(self, parameters: DrivetrainParameters, source: str) -> IdentificationReport:
        """The report with another drivetrain tested against the identified one
        (:mod:`dtid.identification.uncertainty.comparison`): does it fit the identifying runs
        significantly worse?

        Parameters
        ----------
        parameters
            The set to test (a data sheet's, an earlier identification's); its K and T_loss and
            the setup-4 parameters this identification held are replaced by the report's.
        source
            Where it came from, for the messages (a file name).
        """
        if self.fit is None or self.parameterization is None:
            raise ValueError("the report holds no identification runs to test a set on")
        theta = theta_from_parameters(parameters)
        held = tuple(name for name in THETA_NAMES if name in self.fixed)
        theta.update({name: self.fixed[name] for name in held})
        row = theta_to_arrays(
            np.array([[theta[name] for name in THETA_NAMES]]), self.t_loss, self.gain
        )[0]
        par = self.parameterization
        scores = {"fit": nrmse_by_run(self.fit.tests, self.fit.runs, row[None])}
        if self.validation is not None:
            scores["validation"] = nrmse_by_run(
                self.validation.tests, self.validation.runs, row[None]
            )
        comparison = Comparison(
            source=source,
            theta=theta,
            held=held,
            free=len(par.free),
            test=point_test(self.fit.objective(par), self.identification.unit, row),
            nrmse=scores,
            outside=outside_intervals(
                theta, {name: prof.interval for name, prof in self.profiles.items()}
            ),
        )
        return dataclasses.replace(self, comparison=comparison)

    def fit_curves(self) -> tuple[list[FrfEstimate], list[np.ndarray], list[str]]:
        """Measured FRFs, the identified model's |G_DRV| (dB) and the role of each run (Fig. 6)."""
        params = self.identification.parameters.as_array()[None]
        measured, model, roles = [], [], []
        for role, selection in (("fit", self.fit), ("validation", self.validation)):
            if selection is None:
                continue
            for test, runs in zip(selection.tests, selection.runs, strict=True):
                curves = model_drv_db(params, test.model_test(runs))
                for i, db in zip(runs, curves, strict=True):
                    measured.append(test.estimates[i])
                    model.append(db[0])
                    roles.append(role)
        return measured, model, roles

    def curves(self) -> list[dict[str, object]]:
        """:meth:`fit_curves` as JSON: per run its label, role, amplitude, frequencies and the
        measured and identified |G_DRV| (dB), for a report to draw Fig. 6 without the data; the
        identified curve is None where the model could not idle through the run (its NRMSE is
        :data:`FAILED_NRMSE`)."""
        labels = [  # as the NRMSEs are labelled, in fit_curves' order
            test.run_label(i)
            for selection in (self.fit, self.validation)
            if selection is not None
            for test, runs in zip(selection.tests, selection.runs, strict=True)
            for i in runs
        ]
        measured, model, roles = self.fit_curves()
        return [
            {
                "label": label,
                "role": role,
                "amplitude_nm": estimate.run.amplitude_nm,
                "frequency_hz": estimate.frequency_hz.tolist(),
                "measured_db": estimate.drv_db.tolist(),
                "model_db": np.asarray(db).tolist() if np.isfinite(db).all() else None,
            }
            for label, estimate, db, role in zip(labels, measured, model, roles, strict=True)
        ]

    @property
    def parameters(self) -> dict[str, float]:
        """The identified parameters by name (setup 4's, the inertias J1-J3 and K), SI units
        (``units`` of :meth:`as_dict`)."""
        p = self.identification.parameters
        return {**self.identification.theta, "J1": p.J1, "J2": p.J2, "J3": p.J3, "K": self.gain}

    @property
    def intervals(self) -> dict[str, tuple[float, float]]:
        """The profile likelihood interval of each profiled parameter, (lower, upper), SI
        units; empty when profiles were not asked for."""
        return {name: prof.interval for name, prof in self.profiles.items()}

    @property
    def at_bounds(self) -> dict[str, dict[str, object]]:
        """The free parameters that ended on an edge of the search box the vehicle could lie
        beyond (:meth:`dtid.identification.search.parameterization.Parameterization.at_edges`):
        ``side`` (``upper`` or ``lower``) and the box's ``lower`` and ``upper``, SI units."""
        par = self.parameterization
        if par is None:
            return {}
        out: dict[str, dict[str, object]] = {}
        for name, side in par.at_edges(self.identification.theta).items():
            lower, upper = par.bounds_of(name)
            out[name] = {"side": side, "lower": lower, "upper": upper}
        return out

    def to_json(self, path: str | os.PathLike[str] | None = None) -> str:
        """The JSON document of ``dtid identify`` (docs/schemas.md) as text, also written to
        ``path`` when one is given."""
        document = self.as_dict()
        if path is not None:
            write_json(Path(path), document)
        return json.dumps(document, indent=1, allow_nan=False)

    def plot(self, path: str | os.PathLike[str] | None = None) -> Figure:
        """Measured and identified |G_DRV| of every run, as the paper's Fig. 6 (a matplotlib
        figure; also saved to ``path`` when one is given, format by suffix)."""
        from dtid.identification.plots import fit_figure, plot_fit

        curves = self.fit_curves()
        if path is not None:
            plot_fit(*curves, path)
        return fit_figure(*curves)

    def engine_lags(self) -> dict[str, list[dict[str, object] | None]]:
        """Per recording and identifying run, the engine's lag behind its request fitted to
        T/T_ecu (:attr:`dtid.identification.frf.closed_loop.FrfEstimate.engine_lag`; None
        where the run shows none)."""
        if self.fit is None:
            return {}
        return {
            test.name: [
                None if (lag := test.estimates[i].engine_lag) is None else lag.as_dict()
                for i in runs
            ]
            for test, runs in zip(self.fit.tests, self.fit.runs, strict=True)
        }

    def as_dict(self) -> dict[str, object]:
        """The JSON document of ``dtid identify``."""
        result = self.identification
        parameters = self.parameters
        intervals = {
            name: {"lower": prof.interval[0], "upper": prof.interval[1]}
            for name, prof in self.profiles.items()
        }
        return {
            "parameters": parameters,
            "units": {**THETA_UNITS, **{name: UNITS[name] for name in ("J1", "J2", "J3", "K")}},
            "intervals": intervals,
            "nrmse": {"fit": result.fit_nrmse, "validation": result.validation_nrmse},
            "identifiable": {name: prof.verdict for name, prof in self.profiles.items()}
            | {name: "no" for name in self.inseparable},
            "identifiability_notes": dict(self.inseparable),
            "fixed": dict(self.fixed),
            "T_loss": self.t_loss,
            "combustion_variation": {
                t.name: t.combustion_variation if t.loop.by_request else 0.0 for t in self.fit.tests
            }
            if self.fit
            else {},
            "combustion_variation_without_sensor_noise": {
                t.name: t.loop.as_dict()["combustion_variation"] for t in self.fit.tests
            }
            if self.fit
            else {},
            "idle_loop": {t.name: t.loop.as_dict() for t in self.fit.tests} if self.fit else {},
            "engine_lag": self.engine_lags(),
            "vehicle_data": self.fit.tests[0].vehicle.as_dict() if self.fit else {},
            "objective": result.objective,
            "search_restart": self.restart.as_dict() if self.restart else None,
            "at_bounds": self.at_bounds,
            "parameter_sets": result.parameter_sets,
            "seconds": result.seconds,
            "profiles": {
                name: {
                    "values": prof.values.tolist(),
                    "objective": finite(prof.objective),
                    "statistic": finite(prof.statistic),
                    "margin": finite(prof.margin),
                }
                for name, prof in self.profiles.items()
            },
            "target_tests": {name: test.as_dict() for name, test in self.target_tests.items()},
            "comparison": self.comparison.as_dict() if self.comparison else None,
            "curves": self.curves() if self.fit else [],
        }


def with_variation(selection: RunSelection, variations: Mapping[str, float]) -> RunSelection:
    """The selection with the combustion variation of each test named in ``variations``
    replaced (the same recording's identification and validation runs share it)."""
    tests = tuple(
        dataclasses.replace(t, combustion_variation=variations[t.name])
        if t.name in variations
        else t
        for t in selection.tests
    )
    return dataclasses.replace(selection, tests=tests)


def _fixed_variation(value: float) -> float:
    """A combustion variation given with --fix, checked."""
    if not 0.0 <= value < 1.0:
        raise ConfigError(
            f"combustion_variation is a relative standard deviation within [0, 1), got "
            f"{value:g} (0.03 is 3 %)"
        )
    return value


def run_identification(
    tests: Sequence[MeasuredTest],
    prior: DrivetrainParameters,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    identify_amplitudes: Sequence[float] | None = None,
    settings: SearchSettings | None = None,
    profile_points: int = 5,
    progress: Progress | None = None,
    resolution_hz: float = DEFAULT_RESOLUTION_HZ,
    span: float | None = None,
    profile_map: ProfileMap | None = None,
    warm_starts: Sequence[Mapping[str, float]] = (),
    target_widths: Callable[[Mapping[str, float]], Mapping[str, float]] | None = None,
) -> IdentificationReport:
    """Identify from measured tests, profile every free parameter and validate.

    Parameters
    ----------
    tests
        The recordings' tests.
    prior
        Centre of the bounds and source of start values the data do not give.
    fixed
        Values to hold, by setup-4 name or K / T_loss.
    bounds
        Explicit bounds by setup-4 name, SI units.
    identify_amplitudes
        Amplitudes that identify (default: the two largest); the rest validate.
    settings
        Search budget and seed.
    profile_points
        Grid points per profile; 0 skips the profiles (no intervals, no verdicts).
    progress
        Progress callback.
    resolution_hz
        Welch resolution the tests were estimated with.
    span
        Relative half-width of the bounds around the prior where ``bounds`` names none (1 is
        the paper's +-100 %); None: +-100 % widened to a passenger car's ranges
        (:func:`dtid.identification.search.parameterization.passenger_car_bounds`).
    profile_map
        How the profiles are computed (:data:`ProfileMap`); None: one after another.
    warm_starts
        Optima found before on part of these data (setup-4 values, e.g. an adaptive campaign's
        earlier round), polished whatever the global search made of them
        (:func:`dtid.identification.search.identify.identify`).
    target_widths
        From the identified setup-4 values, each target's half-width to test where a parameter
        is not profiled (:func:`identify_runs`); None: none.
    """
    selection = identification_runs(tests, identify_amplitudes, resolution_hz)
    report = identify_runs(
        selection,
        prior,
        fixed,
        bounds,
        settings,
        profile_points,
        progress,
        span,
        profile_map,
        warm_starts,
        target_widths,
    )
    return report.validated(validation_runs(tests, identify_amplitudes, resolution_hz))


ProfileMap = Callable[[Callable[[str], Profile], list[str]], list[Profile]]
"""Computes the profiles of the named parameters, in order, with the function given: a map
over an executor (``dtid batch`` spreads them over its Dask cluster). None: one after another
here."""


def _profile_one(
    polish_objective: Objective,
    search_objective: Objective,
    measured_db: list[np.ndarray],
    optimum_unit: np.ndarray,
    points: int,
    seed: int,
    name: str,
) -> Profile:
    """One parameter's profile (a module-level function, so that it travels to other
    processes)."""
    return profile(
        polish_objective,
        measured_db,
        name,
        optimum_unit,
        points=points,
        seed=seed,
        search_objective=search_objective,
    )


def identify_runs(
    selection: RunSelection,
    prior: DrivetrainParameters,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    settings: SearchSettings | None = None,
    profile_points: int = 5,
    progress: Progress | None = None,
    span: float | None = None,
    profile_map: ProfileMap | None = None,
    warm_starts: Sequence[Mapping[str, float]] = (),
    target_widths: Callable[[Mapping[str, float]], Mapping[str, float]] | None = None,
) -> IdentificationReport:
    """Identify from held-out identification runs and profile; no validation yet.

    See :func:`run_identification` for the parameters; :meth:`IdentificationReport.validated`
    adds the validation. ``target_widths`` gives, from the identified setup-4 values, the
    half-width of each target to test (SI units, by name): each free parameter named that is
    not profiled gets the likelihood-ratio test at the estimate less and plus it
    (:mod:`dtid.identification.uncertainty.target_test`, an adaptive campaign's cheaper check
    than a profile).
    """
    fixed = dict(fixed or {})
    operating = {name: fixed.pop(name) for name in OPERATING_POINT if name in fixed}
    if "combustion_variation" in operating:
        value = _fixed_variation(operating["combustion_variation"])
        selection = with_variation(selection, {t.name: value for t in selection.tests})
    tests = selection.tests
    ident = [list(runs) for runs in selection.runs]
    gain = (
        operating["K"]
        if "K" in operating
        else model_gain(
            [
                dataclasses.replace(t, estimates=tuple(t.estimates[i] for i in runs))
                for t, runs in zip(tests, ident, strict=True)
            ]
        )
    )
    t_loss = (
        operating["T_loss"]
        if "T_loss" in operating
        else float(np.mean([t.idle_torque_nm for t in tests]))
    )
    if span is None:  # the prior's +-100 % and a passenger car's range
        bounds = {**passenger_car_bounds(prior), **(bounds or {})}
        span = PRIOR_SPAN
    lagging = [
        (test, estimate, lag)
        for test, runs in zip(tests, ident, strict=True)
        for estimate, lag in ((test.estimates[i], test.estimates[i].engine_lag) for i in runs)
        if lag is not None
    ]
    mismatch = gain_mismatch(tests, ident)
    if mismatch:
        logger.warning("%s", mismatch)
    if lagging:
        modelled = all(t.loop.lag_s > 0 for t, _, _ in lagging)
        logger.warning("%s", lag_warning(lagging, gain, "K" not in operating, modelled))
    elif "K" not in operating:
        gain, warning = held_gain(tests, ident, gain)
        for message in (warning, gain_warning(gain)):
            if message:
                logger.warning("%s", message)
    par = Parameterization.around(prior, t_loss, gain, fixed=fixed, bounds=bounds, span=span)
    starts = start_thetas(selection.estimates(), prior)
    settings = settings or SearchSettings()
    result = identify(
        tests, par, ident, [[] for _ in tests], settings, progress, starts, warm_starts
    )
    tests = selection.tests
    reasons = inseparable(
        par.free, len(amplitude_levels(e.run.amplitude_nm for e in selection.estimates()))
    )
    for reason in dict.fromkeys(reasons.values()):  # once per coupling
        logger.warning("not identifiable from these data: %s", reason)
    profiles: dict[str, Profile] = {}
    measured_db = [e.drv_db for e in selection.estimates()]
    objective = selection.objective(par)
    # the profiles and target tests run on the cheaper objectives of the search's stages 1 and 2
    polish = objective.replacing(realizations=settings.polish_realizations)
    coarse = objective.replacing(realizations=settings.global_realizations)
    if profile_points:
        one = functools.partial(
            _profile_one, polish, coarse, measured_db, result.unit, profile_points, settings.seed
        )
        if profile_map is None:
            for step, name in enumerate(par.free):
                if progress:
                    progress("profile", step + 1, len(par.free), result.objective)
                profiles[name] = one(name)
        else:
            profiles = dict(zip(par.free, profile_map(one, list(par.free)), strict=True))
    half_widths = {
        name: width
        for name, width in (target_widths(result.theta) if target_widths else {}).items()
        if name in par.free and name not in profiles
    }
    tested: dict[str, TargetTest] = {}
    for step, (name, width) in enumerate(half_widths.items()):
        if progress:
            progress("target test", step + 1, len(half_widths), result.objective)
        tested[name] = target_test(
            polish, measured_db, name, result.unit, width, settings.seed, coarse
        )
    gear = (
        None
        if {"c23", "eps23"} & {*profiles, *tested} or not settings.gear_check
        else gear_play_check(polish, measured_db, result.unit, settings.seed, coarse)
    )
    if gear is not None and not moved_off(gear):
        logger.info(
            "%s fitted no better than the search's optimum",
            restart_finder(check_name(gear), gear.name),
        )
    restart = None
    held = [
        *((p, "profile") for p in profiles.values() if p.beats_estimate),
        *((t.profile, "target test") for t in tested.values() if t.profile.beats_estimate),
        *([(gear, check_name(gear))] if gear is not None and moved_off(gear) else []),
    ]
    beaten = [(p, by) for p, by in held if p.minimum_unit is not None]
    if beaten:  # a profile found a better fit than the search: go on from there
        lowest, found_by = min(beaten, key=lambda pair: float(np.min(pair[0].objective)))
        assert lowest.minimum_unit is not None
        start = dict(
            zip(THETA_NAMES, map(float, par.theta(lowest.minimum_unit[None])[0]), strict=True)
        )
        moved = identify_from(tests, par, ident, [[] for _ in tests], start, settings, progress)
        restart = SearchRestart(
            lowest.name,
            lowest.estimate_statistic,
            result.objective,
            moved.objective,
            result.theta,
            found_by,
        )
        logger.warning("%s", restart.message(moved.objective < result.objective))
        kept = moved if moved.objective < result.objective else result
        result = dataclasses.replace(  # the restart's cost counts with the search's
            kept,
            parameter_sets=result.parameter_sets + moved.parameter_sets,
            seconds=result.seconds + moved.seconds,
            objective_seconds=result.objective_seconds + moved.objective_seconds,
            stages={**result.stages, **{f"restart_{k}": v for k, v in moved.stages.items()}},
        )
    report = IdentificationReport(
        result,
        with_structure(profiles, reasons),
        {**fixed, **operating},
        gain,
        t_loss,
        fit=selection,
        inseparable=reasons,
        parameterization=par,
        restart=restart,
        target_tests=tested,
    )
    for name, edge in report.at_bounds.items():
        logger.warning("%s", edge_warning(name, edge["side"], edge["lower"], edge["upper"]))
    warn_unrepeatable(result.fit_nrmse, tests)
    return report


def warn_unrepeatable(scores: Mapping[str, float], tests: Sequence[MeasuredTest]) -> None:
    """Log a warning for each run the identified model could not repeat.

    Parameters
    ----------
    scores
        NRMSE by run label (``"<recording> @ <amplitude> N*m"``), as the identification gives
        them; :data:`~dtid.identification.search.objective.FAILED_NRMSE` marks a run whose
        model engine could not idle.
    tests
        The recordings the labels name.
    """
    by_name = {test.name: test for test in tests}
    for label, score in scores.items():
        if score >= FAILED_NRMSE:
            test = by_name.get(label.rsplit(" @ ", 1)[0])
            scatter = test.idle_speed_sd_rpm if test is not None else float("nan")
            logger.warning("%s", unrepeatable_warning(label, scatter))


def unrepeatable_warning(label: str, idle_sd_rpm: float) -> str:
    """What a run the identified model cannot repeat means, for the log (``idle_sd_rpm``: the
    recording's idle speed scatter outside the chirps, rpm, :attr:`MeasuredTest.
    idle_speed_sd_rpm`)."""
    return (
        f"the identified model could not idle through {label}: at these parameters its engine "
        "does not keep the idle the recording holds, so they do not describe that run (its "
        f"NRMSE is the failure's {FAILED_NRMSE:g}). Outside the chirps the recorded idle speed "
        f"scatters by {idle_sd_rpm:.1f} rpm (SD; a steady idle by a few rpm, one that hunts "
        "about as much as a chirp moves the speed): check the vehicle's idle before the test, "
        "and read `dtid diagnose` before using these parameters"
    )


def edge_warning(name: str, side: str, lower: float, upper: float) -> str:
    """What a parameter that ended on an edge of its search box means, and the option that
    widens the box, for the log (``side``: ``upper`` or ``lower``; the box in SI units)."""
    unit = THETA_UNITS[name]
    unit = "" if unit == "1" else f" {unit}"
    if side == "upper":  # a mass ratio stays below 1
        wider = (lower, (1 + upper) / 2 if name in ("x1", "x12") else 2 * upper)
    else:
        wider = (lower / 2, upper)
    return (
        f"{name} ended at the {side} end of its search box ({lower:.4g} to {upper:.4g}{unit}): "
        "the vehicle may lie beyond it, and the parameters that trade with it are bent to make "
        f"up; if it can, widen the box (--bounds {name}={wider[0]:.4g}:{wider[1]:.4g}) and "
        "identify again"
    )
