"""Does another drivetrain explain the recordings as well as the identified one?

An engineer often holds a parameter set besides the recordings: the supplier's data sheet of the
DMF, the design values, an earlier identification of the same car. The question is whether the
recordings contradict it, and "it fits worse" says nothing by itself: the optimum is the best
fit of ten parameters to these data, noise included, so every other set fits worse, the truth
too (docs/accuracy.md, *The model at the truth*). The test here asks whether it fits worse by
more than the recordings' scatter allows.

It is the likelihood-ratio test of the point hypothesis "the free setup-4 parameters are those
of the set" against the identified optimum, with the intervals' statistic
(:func:`dtid.identification.uncertainty.statistic.statistic`: the sandwich form over the
residuals' local variance and correlation length). The set's K and T_loss are replaced by the
identification's (the operating point is measured, not identified), and so are the parameters
the identification held (``--fix``): the test is of what was searched.

Its reference distribution is not chi-square or F of as many degrees of freedom as parameters
are free. The FRF's errors are correlated over many more bins than the residuals' correlation
length says, along directions the ten parameters can follow (a level, a slope, a bump near a
mode), and the optimum follows them: on the randomised trial's truth 1 (the product's own
simulator, the model right) the truth's statistic was 36 over ten parameters, p = 0.009 by the
F reference, and on truth 6 65, p = 4e-5. So the reference is drawn: :data:`NULL_DRAWS`
recordings of the model at the optimum (single realizations with a recording's noise,
:attr:`dtid.identification.model.response.ModelTest.recording_noise`), each fitted to first
order (its deviation from the draws' mean projected on the Jacobian of the free parameters,
:func:`dtid.identification.search.sensitivity.jacobian`) and its statistic taken against the
mean as the recording's is against the set: a linearised parametric bootstrap. On truth 1 its
median was 18.7 and its 95th percentile 43.4, and the truth's 36 had a p-value of 0.09.

Both models are drawn on the same fresh realizations (:data:`REALIZATIONS`, seed :data:`SEED`),
not those the search chose its optimum on: an optimum is lucky on its own draws.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from dtid.identification.model.response import model_drv_db
from dtid.identification.search.objective import Objective, summed_nrmse
from dtid.identification.search.sensitivity import jacobian
from dtid.identification.uncertainty.statistic import CONFIDENCE, statistic
from dtid.jsonfile import json_number

REALIZATIONS = 8
"""Model realizations behind the test (twice the report's own, as the diagnosis's test)."""
SEED = 9_200
"""Seed of those realizations: fresh draws, not the search's."""
NULL_DRAWS = 99
"""Recordings of the model drawn for the reference distribution (p-values from 0.01)."""
NULL_SEED = 20_000
"""Seed of the first of them."""
LEVEL = 1.0 - CONFIDENCE
"""A set is said to fit significantly worse below this p-value (5 %)."""


@dataclass(frozen=True)
class PointTest:
    """The likelihood-ratio test of one parameter set against the identified optimum.

    Attributes
    ----------
    statistic
        The set's statistic against the optimum (0: it fits as well or better; infinite: its
        model could not idle).
    null
        The statistic of each of the model's drawn recordings, fitted to first order, against
        the model they were drawn from (:data:`NULL_DRAWS`; the module notes).
    objective_optimum, objective_other
        Eq. (17) of the optimum and of the set on the test's realizations.
    """

    statistic: float
    null: np.ndarray
    objective_optimum: float
    objective_other: float

    @property
    def p_value(self) -> float:
        """The share of the drawn statistics at least as large, the recording's counted among
        them (Davison and Hinkley 1997, eq. 4.11)."""
        return float((1 + np.count_nonzero(self.null >= self.statistic)) / (1 + len(self.null)))

    @property
    def critical(self) -> float:
        """The drawn statistics' 95th percentile: a set beyond it fits significantly worse."""
        return float(np.quantile(self.null, CONFIDENCE))


def point_test(objective: Objective, optimum: np.ndarray, other: np.ndarray) -> PointTest:
    """The likelihood-ratio test of a parameter set against the optimum (the module notes).

    Parameters
    ----------
    objective
        Eq. (17) over the identifying runs, over its parameterization's free values.
    optimum
        The identified optimum, (n_free,) normalised values of that parameterization.
    other
        Physical parameter array (12,) of the set tested.
    """
    fresh = objective.replacing(realizations=REALIZATIONS, seed=SEED)
    rows = np.vstack([fresh.parameterization.parameters(optimum[None]), other[None]])
    measured = [data for run in objective.measured_db for data in run]
    best_db, other_db = [], []
    for test in fresh.tests:
        for curves in model_drv_db(rows, test):
            best_db.append(curves[0])
            other_db.append(curves[1])
    return PointTest(
        statistic=statistic(measured, best_db, other_db),
        null=null_statistics(fresh, optimum),
        objective_optimum=float(summed_nrmse(measured, [db[None] for db in best_db])[0]),
        objective_other=float(summed_nrmse(measured, [db[None] for db in other_db])[0]),
    )


def null_statistics(objective: Objective, optimum: np.ndarray) -> np.ndarray:
    """The statistic of :data:`NULL_DRAWS` recordings of the model at the optimum, each fitted to
    first order, against the model they were drawn from (:func:`linearised_null`). A column of
    the Jacobian whose step could not idle is left out."""
    jac = jacobian_db(objective, optimum)
    jac = jac[:, np.isfinite(jac).all(axis=0)]
    row = objective.parameterization.parameters(optimum[None])
    draws = model_recordings(objective, row, NULL_DRAWS)
    sizes = [len(data) for run in objective.measured_db for data in run]
    return linearised_null(jac, draws, sizes)


def jacobian_db(objective: Objective, unit: np.ndarray) -> np.ndarray:
    """(bins, free) Jacobian of the model's |G_DRV| (dB, every identifying run in order) per
    normalised unit of each free parameter (:func:`dtid.identification.search.sensitivity.\
jacobian`, whose residuals are divided by each run's measured spread)."""
    jac = jacobian(objective, unit)[0]
    spreads = np.concatenate(
        [
            np.full(len(data), np.linalg.norm(data - data.mean()))
            for run in objective.measured_db
            for data in run
        ]
    )
    return jac * spreads[:, None]


def model_recordings(objective: Objective, row: np.ndarray, draws: int) -> np.ndarray:
    """(draws, bins) recordings of the model at ``row`` (1, 12): single realizations with a
    recording's noise, seeds from :data:`NULL_SEED`, every identifying run's |G_DRV| in order,
    dB."""
    return np.array([_recording(objective, row, NULL_SEED + k) for k in range(draws)])


def linearised_null(jac_db: np.ndarray, draws: np.ndarray, sizes: Sequence[int]) -> np.ndarray:
    """The statistic of each drawn recording fitted to first order, against its truth.

    A draw's deviation from the draws' mean, e, is what a recording's noise is; a fit follows
    its projection on the columns of the Jacobian J, J J^+ e; the statistic is that of the
    mean (the draws' truth) against the fit, the recording being mean + e.

    Parameters
    ----------
    jac_db
        (bins, parameters) Jacobian of the model's curves, dB per unit of each parameter.
    draws
        (draws, bins) recordings of the model, every run's curve in order, dB.
    sizes
        Bins of each run.
    """
    centre = draws.mean(axis=0)
    noise = draws - centre
    fitted = noise @ (jac_db @ np.linalg.pinv(jac_db)).T
    edges = np.cumsum(sizes)[:-1]

    def runs(curve: np.ndarray) -> list[np.ndarray]:
        return np.split(curve, edges)

    return np.array(
        [
            statistic(runs(centre + e), runs(centre + f), runs(centre))
            for e, f in zip(noise, fitted, strict=True)
        ]
    )


def _recording(objective: Objective, row: np.ndarray, seed: int) -> np.ndarray:
    """One recording of the model at ``row``: every identifying run's |G_DRV|, dB, in order."""
    curves = []
    for test in objective.tests:
        single = dataclasses.replace(
            test, realizations=1, antithetic=False, recording_noise=True, seed=seed
        )
        curves.extend(c[0] for c in model_drv_db(row, single))
    return np.concatenate(curves)


@dataclass(frozen=True)
class Comparison:
    """Another parameter set tested against the identified optimum on the identifying runs.

    Attributes
    ----------
    source
        Where the set came from (a file name), for the messages.
    theta
        Its setup-4 values as tested (the held ones at their held values), SI units.
    held
        The setup-4 parameters taken at the identification's held values instead of the set's.
    free
        Parameters the identification searched.
    test
        The likelihood-ratio test against the optimum.
    nrmse
        The set's NRMSE per run, ``{"fit": {...}, "validation": {...}}`` as the identification's
        (on the report's own realizations).
    outside
        The set's values outside the identification's 95 % profile intervals, by name: (value,
        lower, upper), an open end None (:func:`outside_intervals`); empty without profiles.
    """

    source: str
    theta: Mapping[str, float]
    held: tuple[str, ...]
    free: int
    test: PointTest
    nrmse: Mapping[str, Mapping[str, float]]
    outside: Mapping[str, tuple[float, float | None, float | None]] = dataclasses.field(
        default_factory=dict
    )

    @property
    def fits_worse(self) -> bool:
        """Whether the recordings reject the set at the 5 % level."""
        return self.test.p_value < LEVEL

    def sentence(self) -> str:
        """The verdict in one sentence, with its figures."""
        test = self.test
        figures = (
            f"eq. (17) {test.objective_other:.4f} against the identified "
            f"{test.objective_optimum:.4f}, likelihood ratio {test.statistic:.1f} where the "
            f"model's own recordings reach {test.critical:.1f} one time in twenty with "
            f"{self.free} parameters fitted, p = {test.p_value:.2g}"
        )
        if self.fits_worse:
            verdict = "fits these recordings significantly worse than the identified one"
        elif test.statistic == 0.0:
            verdict = "fits these recordings as well as the identified one or better"
        else:
            verdict = "fits these recordings as well as the identified one within their scatter"
        held = f"; held as identified: {', '.join(self.held)}" if self.held else ""
        outside = ""
        if self.outside:
            outside = "; outside their 95 % intervals: " + ", ".join(
                f"{name} {value:.4g} ({_end(lower)} - {_end(upper)})"
                for name, (value, lower, upper) in self.outside.items()
            )
        return f"the drivetrain of {self.source} {verdict} ({figures}{held}{outside})"

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (``comparison`` of the identification JSON)."""
        test = self.test
        return {
            "source": self.source,
            "theta": dict(self.theta),
            "held": list(self.held),
            "objective": test.objective_other,
            "objective_identified": test.objective_optimum,
            "nrmse": {role: dict(scores) for role, scores in self.nrmse.items()},
            "statistic": json_number(test.statistic),
            "critical": test.critical,
            "draws": len(test.null),
            "degrees_of_freedom": self.free,
            "p_value": test.p_value,
            "fits_worse": self.fits_worse,
            "outside_intervals": {
                name: {"value": value, "lower": lower, "upper": upper}
                for name, (value, lower, upper) in self.outside.items()
            },
            "sentence": self.sentence(),
        }


def outside_intervals(
    theta: Mapping[str, float], intervals: Mapping[str, tuple[float | None, float | None]]
) -> dict[str, tuple[float, float | None, float | None]]:
    """The values of ``theta`` outside their 95 % intervals (an open end None), by name, in
    the intervals' order: which of a data sheet's parameters the recordings contradict one at
    a time, where the joint test says whether they contradict the whole."""
    out = {}
    for name, (lower, upper) in intervals.items():
        value = theta[name]
        if (lower is not None and value < lower) or (upper is not None and value > upper):
            out[name] = (value, lower, upper)
    return out


def _end(value: float | None) -> str:
    """An interval's end as the sentence shows it (open: "open")."""
    return "open" if value is None else f"{value:.4g}"
