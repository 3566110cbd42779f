"""The statistics of the mismatch map over correlated frequency bins: the bins' correlation,
the smooth-trend test of a run's residual, and family-wise p-values (Sidak).

Pure functions of arrays; :mod:`dtid.identification.diagnosis.mismatch` builds the map with
them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

TREND_DEGREE = 3
"""Highest degree of the Legendre polynomials over a run's band on which the trend test
projects its residual (P_0 to P_3: a level, a slope, a bow and an S)."""


def neighbour_correlation(deviations: Sequence[np.ndarray]) -> float:
    """Pooled lag-one correlation over frequency of standardised deviations, within [0, 0.95].

    Parameters
    ----------
    deviations
        Per run, (draws, bins) deviations of the model's recordings from their mean, each
        divided by its bin's scatter.
    """
    return float(np.clip(bin_autocorrelation(deviations, 1)[1], 0.0, 0.95))


def bin_autocorrelation(deviations: Sequence[np.ndarray], lags: int) -> np.ndarray:
    """Pooled autocorrelation over frequency of standardised deviations, lags 0 to ``lags``.

    Parameters
    ----------
    deviations
        Per run, (draws, bins) deviations of the model's recordings from their mean, each
        divided by its bin's scatter.

    Returns
    -------
    numpy.ndarray
        (lags + 1,), 1 at lag 0.
    """
    products = np.zeros(lags + 1)
    for raw in deviations:
        block = np.where(np.isfinite(raw), raw, 0.0)
        n = block.shape[-1]
        for lag in range(min(lags, n - 1) + 1):
            products[lag] += float(np.sum(block[:, lag:] * block[:, : n - lag]))
    if products[0] == 0.0:
        return np.eye(1, lags + 1)[0]
    return products / products[0]


def trend_test(
    z: np.ndarray, frequency_hz: np.ndarray, autocorrelation: np.ndarray
) -> tuple[float, int, np.ndarray]:
    """The smooth trend of one run's standardised residual over frequency, and its statistic.

    A physics the model lacks can bend a residual smoothly over the whole band, each bin within
    its scatter (the blind trial's 44 ms torque lag: |G_ENG|'s residual from +5.2 to -3.4 dB
    where each bin scatters 1.1-1.5 dB); the largest |z| of a bin is weak against it. The
    residual's projection p = Q' z on the Legendre polynomials P_0 to :data:`TREND_DEGREE` over
    the run's band (orthonormalised over its bins, Q) has, for a right model, covariance
    C = Q' R Q, R the bins' correlation (Toeplitz in the measured ``autocorrelation``, zero
    beyond its last lag); T^2 = p' C^-1 p is then chi-square with as many degrees of freedom as
    polynomials.

    Parameters
    ----------
    z
        Standardised residual per bin (NaN bins left out).
    frequency_hz
        The bins, Hz.
    autocorrelation
        The bins' correlation at lags 0, 1, ... (:func:`bin_autocorrelation`).

    Returns
    -------
    tuple
        T^2, its degrees of freedom, and the trend Q p per bin (z units, NaN where z is).
    """
    used, q = _legendre_basis(z, frequency_hz)
    trend = np.full(len(z), np.nan)
    if not q.size:
        return 0.0, 0, trend
    lag = np.abs(used[:, None] - used[None, :])
    last = len(autocorrelation) - 1
    correlation = np.where(lag <= last, autocorrelation[np.minimum(lag, last)], 0.0)
    projection = q.T @ z[used]
    covariance = q.T @ correlation @ q
    statistic = float(projection @ np.linalg.solve(covariance, projection))
    trend[used] = q @ projection
    return statistic, q.shape[1], trend


def smooth_trend(z: np.ndarray, frequency_hz: np.ndarray) -> np.ndarray:
    """The trend of :func:`trend_test` alone: ``z``'s least-squares fit by the Legendre
    polynomials over the band, per bin (NaN where z is, or all NaN for too few bins)."""
    used, q = _legendre_basis(z, frequency_hz)
    trend = np.full(len(z), np.nan)
    if q.size:
        trend[used] = q @ (q.T @ z[used])
    return trend


def _legendre_basis(z: np.ndarray, frequency_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The finite bins of ``z`` and the Legendre polynomials P_0 to :data:`TREND_DEGREE` over
    their band, orthonormalised over them ((bins, degree + 1); empty for too few bins)."""
    used = np.flatnonzero(np.isfinite(z))
    if len(used) <= 2 * (TREND_DEGREE + 1):
        return used, np.zeros((0, 0))
    f = frequency_hz[used]
    x = 2.0 * (f - f[0]) / (f[-1] - f[0]) - 1.0
    q, _ = np.linalg.qr(np.polynomial.legendre.legvander(x, TREND_DEGREE))
    return used, q


def family_p_value(z: float, effective: float, dof: float) -> float:
    """Family-wise p-value of a |z| among ``effective`` independent t-distributed bins."""
    single = 2.0 * float(stats.t.sf(abs(z), dof))
    return sidak(single, effective)


def sidak(single: float, tests: float) -> float:
    """Family-wise p-value of the smallest of ``tests`` independent p-values (Sidak),
    ``1 - (1 - single)^tests``."""
    return float(-np.expm1(tests * np.log1p(-min(single, 1.0 - 1e-16))))
