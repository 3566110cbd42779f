"""The objective of the identification, eqs. (16) and (17): NRMSE of |G_DRV| in dB."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

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
