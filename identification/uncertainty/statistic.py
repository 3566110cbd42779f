"""The statistic of the profiles and of every other test of a fit's improvement: the
likelihood ratio of eq. (17)'s fit in sandwich form, its small-sample factor, and the nested
models' p-value (the diagnosis's refits).

The objective (eq. 17) is a sum of NRMSEs, not a likelihood, and the dB residuals are neither
of one variance nor independent: near the resonances, where free play and friction act, the
measured FRF scatters several times more than elsewhere, and neighbouring Welch bins share data.
A least-squares statistic with one common variance (N ln(SSR/SSR_min)) treats every bin as equally
informative and made the intervals too narrow: on simulated data the truth fell outside them. The
statistic here is the sandwich form of the likelihood ratio of an unweighted least-squares fit:

    lambda = (SSR - SSR_min) / (tau * sigma2_eff),
    sigma2_eff = sum_i dm_i^2 s2_i / sum_i dm_i^2,

with dm the change of the model |G_DRV| (dB) from the profile's minimum, s2_i the local variance
of the residual at the minimum (a moving mean of its square over ``LOCAL_BINS`` bins each side)
and tau the residual's correlation length in bins (1 + 2 sum of its autocorrelation up to the
first negative lag, at least ``BIN_CORRELATION``, the Hann window's own). The noise that counts
is the noise where the parameter moves the model. A profile divides lambda further by
:func:`small_sample_factor`: two 60 s chirps give about sixty independent bins for ten
parameters, so the residuals at the minimum understate the noise by a sixth, and a ratio with
an estimated variance follows F(1, nu), not chi-square (1.22 and 1.30 on the two independent
vehicles). With it and the profiles' neighbour solutions
(:mod:`dtid.identification.uncertainty.profile`), the randomised trial's twelve recordings
whose intervals had missed: 86 of 96 closed intervals hold the truth (83 of 95
before; docs/history/accuracy-measurements.md).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
THRESHOLD = float(stats.chi2.ppf(CONFIDENCE, df=1))
"""Likelihood-ratio threshold of a 95 % interval for one parameter (3.84)."""
BIN_CORRELATION = 1.5
"""Welch bins per independent bin (Hann window, half overlap): the least correlation length."""
LOCAL_BINS = 5
"""Bins on each side of a bin over which the local residual variance is averaged."""


def statistic(
    measured_db: Sequence[np.ndarray],
    best_db: Sequence[np.ndarray],
    model_db: Sequence[np.ndarray],
) -> float:
    """Likelihood-ratio statistic of a model against the profile's minimum (sandwich form).

    Parameters
    ----------
    measured_db
        Measured |G_DRV| per identification run, dB.
    best_db
        Model |G_DRV| at the profile's minimum, per run, dB.
    model_db
        Model |G_DRV| at the point tested, per run, dB.

    Returns
    -------
    float
        (SSR - SSR_min) / (tau * sigma2_eff), see the module notes; 0 where the model equals the
        minimum's, infinite where the model could not idle.
    """
    delta_ssr = sum(
        float(np.sum((data - model) ** 2 - (data - best) ** 2))
        for data, best, model in zip(measured_db, best_db, model_db, strict=True)
    )
    return ssr_ratio(delta_ssr, noise_scale(measured_db, best_db, model_db))


def noise_scale(
    measured_db: Sequence[np.ndarray],
    best_db: Sequence[np.ndarray],
    model_db: Sequence[np.ndarray],
) -> float:
    """What an SSR difference is divided by to give the statistic: tau * sigma2_eff, dB^2.

    Same parameters as :func:`statistic`. 0 where the model equals the minimum's, NaN where the
    model could not idle.
    """
    if not all(np.isfinite(model).all() for model in model_db):
        return float("nan")
    weighted = change = 0.0
    lengths, bins = [], []
    for data, best, model in zip(measured_db, best_db, model_db, strict=True):
        residual = data - best
        dm2 = (model - best) ** 2
        weighted += float(np.sum(dm2 * local_variance(residual)))
        change += float(np.sum(dm2))
        lengths.append(correlation_length(residual))
        bins.append(len(residual))
    if change == 0.0 or weighted == 0.0:
        return 0.0
    return float(np.average(lengths, weights=bins)) * weighted / change


def independent_bins(measured_db: Sequence[np.ndarray], best_db: Sequence[np.ndarray]) -> float:
    """How many independent bins the residuals at the minimum hold: all their bins over the
    correlation length (bins-weighted over the runs, as :func:`noise_scale` takes it)."""
    residuals = [data - best for data, best in zip(measured_db, best_db, strict=True)]
    bins = [len(r) for r in residuals]
    tau = float(np.average([correlation_length(r) for r in residuals], weights=bins))
    return sum(bins) / tau


def small_sample_factor(independent: float, fitted: int) -> float:
    """What the noise scale of a profile is multiplied by when its variance comes from the
    residuals of a fit of ``fitted`` parameters to ``independent`` independent bins.

    The residuals at the minimum are smaller than the noise: the fit took ``fitted`` of the
    ``independent`` degrees of freedom, so their variance is low by nu / independent,
    nu = independent - fitted; and with the variance estimated, not known, the likelihood ratio
    of one parameter follows F(1, nu), not chi-square(1) (Bates and Watts 1988, the profile t
    with s^2 = SSR / (N - p)). Both are put on the chi-square scale of :data:`THRESHOLD`:

        factor = independent / nu * F_0.95(1, nu) / chi2_0.95(1).

    Two 60 s chirps give 96 bins, about 60 independent: with ten parameters free the factor is
    1.24 (the intervals' threshold 3.84 becomes 4.8 in the earlier units). Below one degree of
    freedom left (the residuals cannot tell the noise), nu is taken as one.
    """
    nu = max(independent - fitted, 1.0)
    return independent / nu * float(stats.f.ppf(CONFIDENCE, 1, nu)) / THRESHOLD


def nested_p_value(statistic_value: float, added: int, independent: float, fitted: int) -> float:
    """p-value of the statistic of a model with ``added`` parameters more than the one it
    extends, its variance estimated from the residuals of the larger model's fit.

    The statistic divides the SSR difference by the residuals' mean square (per independent
    bin), low by nu / independent with nu = independent - fitted degrees of freedom left, and
    estimated, not known: for a linear model the exact reference is the F test of nested models
    (Seber and Wild 2003, 5.3),

        F = statistic * nu / (independent * added)  ~  F(added, nu),

    which tends to chi-square(added) / added for many bins. Below one degree of freedom left,
    nu is taken as one.

    Parameters
    ----------
    statistic_value
        The likelihood-ratio statistic (:func:`statistic`) of the smaller model against the
        larger one's minimum.
    added
        Parameters the larger model adds, at least one.
    independent
        Independent bins of the larger model's residuals (:func:`independent_bins`).
    fitted
        Parameters fitted in the larger model.
    """
    nu = max(independent - fitted, 1.0)
    ratio = statistic_value * nu / (independent * added)
    return float(stats.f.sf(ratio, added, nu))


def ssr_ratio(delta_ssr: float, scale: float) -> float:
    """An SSR difference in units of the statistic: infinite for a failed model (NaN scale), 0
    for the minimum's own (zero scale) or a smaller SSR."""
    if np.isnan(scale):
        return float("inf")
    return max(delta_ssr, 0.0) / scale if scale > 0.0 else 0.0


def local_variance(residual: np.ndarray) -> np.ndarray:
    """Moving mean of the squared residual over ``LOCAL_BINS`` bins each side, dB^2."""
    window = np.ones(2 * LOCAL_BINS + 1)
    return np.convolve(residual**2, window, "same") / np.convolve(
        np.ones_like(residual), window, "same"
    )


def correlation_length(residual: np.ndarray) -> float:
    """Bins per independent residual: 1 + 2 * autocorrelation summed up to its first negative lag,
    at least :data:`BIN_CORRELATION`."""
    centred = residual - residual.mean()
    power = float(np.sum(centred**2))
    if power == 0.0:
        return BIN_CORRELATION
    rho = np.correlate(centred, centred, "full")[len(centred) :] / power
    negative = np.flatnonzero(rho < 0)
    positive = rho[: negative[0]] if len(negative) else rho
    return max(BIN_CORRELATION, 1.0 + 2.0 * float(positive.sum()))
