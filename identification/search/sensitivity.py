"""The model's sensitivities at one parameter set: the Jacobian of eq. (17)'s residuals.

Eq. (17) is a sum of per-run NRMSEs of |G_DRV| in dB, so near an optimum it behaves like weighted
least squares on the dB residuals, each run's bins weighted by the inverse of its measured
spread (the NRMSE's denominator). Its Jacobian gives the directions a derivative-free search
finds slowly: the narrow, curved valleys where one parameter's change is undone by others (a
mass ratio 1 % off the optimum raises eq. (17) by a quarter unless the inertias and stiffnesses
move with it), and the shallow ones of the dampings and the friction.

The model is a Monte Carlo estimate (:mod:`dtid.identification.model.response`) whose curves jitter
by about 0.014 dB RMS between parameter sets 1e-6 apart (the accuracy trial's truth 4), so a
derivative from a tiny step is that jitter. Each parameter's central difference is instead
sized, after a first measurement with :data:`FIRST_STEP`, to change the curves by
:data:`SENSITIVITY_DB`.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the search (dtid.identification.search.identify) uses this module
    from dtid.identification.search.objective import Objective

SENSITIVITY_DB = 0.1
"""RMS change of the model's |G_DRV| (dB) each parameter's finite difference is sized for: seven
times the jitter, and still linear (on truth 4 a step three times longer changed the steepest
parameter's curves three times as much)."""
FIRST_STEP = 0.01
"""Normalised finite-difference step that measures each parameter's sensitivity first."""
STEP_RANGE = (0.002, 0.15)
"""Least and largest normalised step (the dampings and the friction need the largest)."""


def jacobian(
    objective: Objective,
    unit: np.ndarray,
    columns: Sequence[int] | None = None,
    steps: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian of the weighted residuals at one parameter set, by sized central differences.

    Parameters
    ----------
    objective
        Eq. (17).
    unit
        (n_free,) normalised free values; steps are clipped to the box.
    columns
        Free parameters to differentiate by (default: all); a held parameter's column costs two
        model evaluations a round for nothing.
    steps
        Normalised step of each column, already sized (:func:`sized_steps` of a Jacobian taken
        nearby: a Levenberg-Marquardt step's next): one round of differences instead of two.

    Returns
    -------
    tuple of numpy.ndarray
        The Jacobian (bins, len(columns)), per normalised unit, and the residuals at ``unit``
        (bins,), as :meth:`dtid.identification.search.objective.Objective.residuals`; NaN where
        the model could not idle at some step.
    """
    cols = np.arange(len(unit)) if columns is None else np.asarray(columns, dtype=int)
    n = len(cols)
    rounds = 1 if steps is not None else 2
    steps = np.full(n, FIRST_STEP) if steps is None else steps
    for _ in range(rounds):  # measure the sensitivities, then again with steps sized by them
        shift = np.zeros((n, len(unit)))
        shift[np.arange(n), cols] = steps
        up, down = np.clip(unit + shift, 0.0, 1.0), np.clip(unit - shift, 0.0, 1.0)
        rows = objective.residuals(np.vstack([up, down, unit[None]]))
        result = (rows[:n] - rows[n : 2 * n]).T / (up - down)[np.arange(n), cols]
        if not np.isfinite(result).all():
            break  # some step could not idle: no size to measure, the caller sees the NaN
        steps = sized_steps(objective, result)
    return result, rows[-1]


def sized_steps(objective: Objective, jac: np.ndarray) -> np.ndarray:
    """Each column's normalised step that changes the model's curves by :data:`SENSITIVITY_DB`
    RMS, to first order by ``jac`` (a finite Jacobian of :func:`jacobian`), within
    :data:`STEP_RANGE`."""
    spreads = np.concatenate(
        [
            np.full(len(data), np.linalg.norm(data - data.mean()))
            for measured in objective.measured_db
            for data in measured
        ]
    )
    rms_db = np.sqrt(np.mean((jac * spreads[:, None]) ** 2, axis=0))
    return np.clip(SENSITIVITY_DB / np.maximum(rms_db, 1e-9), *STEP_RANGE)


def compensation(objective: Objective, unit: np.ndarray) -> np.ndarray:
    """How the other free parameters move, to first order, when one is held off ``unit``.

    The Gauss-Newton least-squares solution: the others' change that best undoes, in the
    weighted residuals, one parameter's change.

    Returns
    -------
    numpy.ndarray
        (n_free, n_free): row k is the change of every free parameter per unit change of
        parameter k, normalised units, with 1 at k; the identity where the model could not idle.
    """
    n_free = len(unit)
    jac = jacobian(objective, unit)[0]
    moves = np.eye(n_free)
    if not np.isfinite(jac).all():
        return moves
    for k in range(n_free):
        others = [i for i in range(n_free) if i != k]
        moves[k, others] = np.linalg.lstsq(jac[:, others], -jac[:, k], rcond=None)[0]
    return moves


def linearised_step(jac: np.ndarray, residuals: np.ndarray, runs: Sequence[int]) -> np.ndarray:
    """The step eq. (17)'s minimum lies at, to first order, from where ``jac`` was taken.

    Near its minimum eq. (17), a sum of per-run norms, is weighted least squares with each run's
    bins weighted by the inverse of its residual norm (the module notes); one Gauss-Newton step
    of that problem is the first-order estimator. Applied at the truth of a simulated
    recording, it gives that recording's estimation error without a search (``dtid plan``'s
    predictions are checked against it: tests/test_plan.py, benchmarks/plan_trial.py).

    Parameters
    ----------
    jac
        (bins, n_free) Jacobian of the weighted residuals (:func:`jacobian`).
    residuals
        (bins,) weighted residuals, model minus measured, where ``jac`` was taken.
    runs
        Number of bins of each run, in order.

    Returns
    -------
    numpy.ndarray
        (n_free,) step, normalised units.
    """
    bounds = np.cumsum([0, *runs])
    weights = np.concatenate(
        [
            np.full(b - a, 1.0 / np.linalg.norm(residuals[a:b]))
            for a, b in itertools.pairwise(bounds)
        ]
    )
    weighted = jac * weights[:, None]
    return -np.linalg.solve(jac.T @ weighted, weighted.T @ residuals)
