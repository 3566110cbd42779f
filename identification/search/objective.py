"""The objective of the identification, eqs. (16) and (17): NRMSE of |G_DRV| in dB, and
:class:`Objective`, eq. (17) of the model over the identification runs as the search calls it."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtid.identification.model.response import ModelTest, model_drv_db
from dtid.identification.search.parameterization import Parameterization

FAILED_NRMSE = 10.0
"""NRMSE given to a parameter set whose simulated engine could not idle (a poor fit is ~1)."""


def nrmse(measured_db: np.ndarray, model_db: np.ndarray) -> np.ndarray:
    """Eq. (16): ||zeta - zeta~|| / ||zeta - mean(zeta)|| over the frequency grid.

    Parameters
    ----------
    measured_db
        zeta = 20 log10 |G_DRV| measured, (n_f,).
    model_db
        zeta~ of the model, (n_f,) or (n_sets, n_f); NaN rows are failed simulations.

    Returns
    -------
    numpy.ndarray
        NRMSE per row (1 for a model that predicts the mean level, 0 for a perfect fit);
        :data:`FAILED_NRMSE` for failed rows.
    """
    spread = np.linalg.norm(measured_db - measured_db.mean())
    error = np.linalg.norm(np.atleast_2d(model_db) - measured_db, axis=-1) / spread
    return np.where(np.isfinite(error), error, FAILED_NRMSE)


def summed_nrmse(measured_db: Sequence[np.ndarray], model_db: Sequence[np.ndarray]) -> np.ndarray:
    """Eq. (17): the NRMSE summed over the excitation amplitudes, per parameter set."""
    return np.sum([nrmse(m, s) for m, s in zip(measured_db, model_db, strict=True)], axis=0)


@dataclass
class Objective:
    """Eq. (17) over the identification runs, with a count of simulator calls."""

    parameterization: Parameterization
    tests: Sequence[ModelTest]
    measured_db: Sequence[Sequence[np.ndarray]]
    calls: int = 0
    parameter_sets: int = 0
    seconds: float = 0.0

    def __call__(self, unit: np.ndarray) -> np.ndarray:
        """Objective of each row of normalised free values (n, n_free)."""
        start = time.perf_counter()
        params = self.parameterization.parameters(np.atleast_2d(unit))
        total = np.zeros(params.shape[0])
        for test, measured in zip(self.tests, self.measured_db, strict=True):
            total += summed_nrmse(measured, model_drv_db(params, test))
            self.calls += 1
        self.parameter_sets += params.shape[0]
        self.seconds += time.perf_counter() - start
        return total

    def residuals(self, unit: np.ndarray) -> np.ndarray:
        """Weighted residuals behind eq. (17) of each row of normalised free values.

        Returns
        -------
        numpy.ndarray
            (n, bins): model minus measured |G_DRV|, dB, each run's bins divided by the run's
            measured spread (the NRMSE's denominator), runs in order; NaN where the model could
            not idle. Each run's NRMSE is the norm of its part.
        """
        start = time.perf_counter()
        params = self.parameterization.parameters(np.atleast_2d(unit))
        columns = []
        for test, measured in zip(self.tests, self.measured_db, strict=True):
            for model, data in zip(model_drv_db(params, test), measured, strict=True):
                columns.append((model - data) / np.linalg.norm(data - data.mean()))
            self.calls += 1
        self.parameter_sets += params.shape[0]
        self.seconds += time.perf_counter() - start
        return np.hstack(columns)

    def count(self, other: Objective) -> None:
        """Add another objective's counters to this one's (evaluations made on its behalf)."""
        self.calls += other.calls
        self.parameter_sets += other.parameter_sets
        self.seconds += other.seconds

    def replacing(self, **changes: object) -> Objective:
        """The same objective with its tests changed, for example ``realizations`` (fewer are
        cheaper) or ``seed`` (:class:`dtid.identification.model.response.ModelTest`); the counters
        start at zero."""
        tests = [dataclasses.replace(t, **changes) for t in self.tests]
        return Objective(self.parameterization, tests, self.measured_db)
