"""The engine's torque lag behind its request, fitted to a run's T/T_ecu (S_zx / S_zu).

A lag between the requested and the delivered mean torque (air path, torque model) shows in
|G_ENG| as a fall with frequency and in its phase as a growing delay. It is fitted in the
``torque_lag`` mechanism's own stroke-wise form (:func:`stroke_lag`), so that the value the FRF
reports (JSON ``engine_lag``) means what the diagnosis's ``tau_m`` means.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize

from dtid.simulator.angle_grid import STEPS_PER_STROKE, step_time

LAG_COHERENCE = 0.7
"""The lag's band (:func:`engine_lag`) runs from the run's lowest bin up to where the running
median of the measured torque's coherence first falls below this. A contiguous band, because
bins picked one by one for their coherence are those whose noise lifted coherence and
magnitude together, which flattens the fall (blind-trial case 10: 0.096-0.106 s for 0.119 s
that way); with the band, 0.5, 0.6 and 0.7 give the same lag within 0.01 s there."""
LAG_SMOOTHING = 5
"""Bins of that running median."""
LAG_BINS = 4
"""Fewest such bins for a lag to be fitted."""
LAG_FALL = 0.2
"""Least fall of the measured |T/T_ecu| from the band's lowest quarter to its highest for a lag
to be named. An engine without a lag has a T/T_ecu whose phase the strokes' timing and the ECU
shape (docs/model-assumptions.md, engine gain), and a fit of magnitude and phase then reads a
lag of 10-26 ms into a magnitude that hardly falls (eq. 24's mean within 4 % of K: the
reference vehicle, blind-trial cases 3, 4 and 6); the lags of cases 7 and 12 lower it by
42-57 %."""
LAG_SPREAD = 0.25
"""Largest relative standard error of the fitted lag for it to be named (bins taken as
independent, so a lower bound of the error)."""


@dataclass(frozen=True)
class EngineLag:
    """The engine's torque path fitted to T/T_ecu: the ``torque_lag`` mechanism's stroke-wise
    lag behind a dead time, K (1 - p) exp(-j w d) / (1 - p exp(-j w T)), p = exp(-T / tau).

    Attributes
    ----------
    tau_s
        Time constant of the delivered mean torque's lag behind the request, s.
    tau_sd_s
        Its standard error from the fit's Jacobian, s (the bins taken as independent).
    gain
        The low-frequency gain K, 1.
    delay_s
        Dead time: the strokes' own timing, the ECU's latch and the sensor's hold, s.
    stroke_s
        The stroke T the lag advances by, s.
    band_hz
        Lowest and highest bin the fit used, Hz.
    """

    tau_s: float
    tau_sd_s: float
    gain: float
    delay_s: float
    stroke_s: float
    band_hz: tuple[float, float]

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (the identification JSON's ``engine_lag``)."""
        return {
            "tau_s": self.tau_s,
            "tau_sd_s": self.tau_sd_s,
            "gain": self.gain,
            "delay_s": self.delay_s,
            "band_hz": list(self.band_hz),
            "half_hz": self.half_hz,
        }

    @property
    def half_hz(self) -> float | None:
        """Frequency where the lag delivers half the low-frequency torque, Hz (None: it does
        not halve below the strokes' Nyquist frequency): |1 - p exp(-j x)| = 2 (1 - p)."""
        p = np.exp(-self.stroke_s / self.tau_s)
        cosine = (1 + p**2 - 4 * (1 - p) ** 2) / (2 * p)
        if cosine < -1:
            return None
        return float(np.arccos(min(cosine, 1.0)) / (2 * np.pi * self.stroke_s))


def stroke_lag(omega: np.ndarray, tau_s: float, stroke_s: float) -> np.ndarray:
    """Response of the ``torque_lag`` mechanism's recurrence: each stroke the delivered torque
    moves towards the request by 1 - p, p = exp(-stroke / tau), so (1 - p) / (1 - p z^-1) at
    z = exp(j w stroke), 1 (complex).

    Parameters
    ----------
    omega
        Angular frequencies, rad/s.
    tau_s
        The lag's time constant, s (> 0).
    stroke_s
        The stroke period, s.
    """
    p = np.exp(-stroke_s / tau_s)
    return (1 - p) / (1 - p * np.exp(-1j * omega * stroke_s))


def engine_lag(
    frequency_hz: np.ndarray, ratio: np.ndarray, coherence: np.ndarray, speed_rpm: float
) -> EngineLag | None:
    """The engine's torque lag behind its request, fitted to T/T_ecu where it is coherent.

    The ``torque_lag`` mechanism moves the delivered torque towards the request by
    1 - exp(-T / tau) each stroke T (:func:`stroke_lag`); behind a dead time d and with a gain K
    that is T/T_ecu, fitted in its own form so that tau means what the diagnosis's
    ``tau_m`` means. Its magnitude alone pins only K/tau once the band lies above the corner,
    so magnitude and phase are fitted together (log-magnitude and phase residuals, scipy's
    least_squares). Measured on the simulator's lag: blind-trial case 10 (0.119 s, K 0.918,
    60 s chirp at 5 N*m from 1.5 Hz), seeds 710 and 1-3: 0.107-0.118 s, K 0.84-0.93; the
    reference vehicle (0.12 s, 30 s chirp at 4 N*m from 2 Hz, above the 1.3 Hz corner), seeds
    1-6: 0.091-0.131 s.

    Parameters
    ----------
    frequency_hz
        The band's bins, Hz.
    ratio
        S_zx / S_zu per bin: the measured mean torque per requested torque, complex, with the
        torque sensor's hold removed from its magnitude.
    coherence
        Coherence of the measured mean torque with the test torque per bin.
    speed_rpm
        The run's mean speed, rpm: it sets the stroke.

    Returns
    -------
    EngineLag or None
        None when the band (:data:`LAG_COHERENCE`) holds fewer than :data:`LAG_BINS` bins, the
        measured magnitude falls by less than :data:`LAG_FALL` across it, the fit ends on a bound
        of K or tau, or tau's standard error exceeds :data:`LAG_SPREAD` of it.
    """
    smooth = ndimage.median_filter(coherence, size=LAG_SMOOTHING, mode="nearest")
    below = np.flatnonzero(smooth < LAG_COHERENCE)
    keep = np.arange(len(coherence)) < (below[0] if len(below) else len(coherence))
    keep &= np.isfinite(ratio) & (np.abs(ratio) > 0)
    if np.count_nonzero(keep) < LAG_BINS:
        return None
    omega, measured = 2 * np.pi * frequency_hz[keep], ratio[keep]
    stroke = STEPS_PER_STROKE * step_time(speed_rpm)

    def residual(x: np.ndarray) -> np.ndarray:
        gain, tau, delay = x
        relative = measured * np.exp(1j * omega * delay) / (gain * stroke_lag(omega, tau, stroke))
        return np.concatenate([np.log(np.abs(relative)), np.angle(relative)])

    # start: 1/|.|^2 of a continuous lag is a line in w^2; its tau_c is the strokes' lag of
    # stroke / ln(1 + stroke / tau_c); the dead time from the phase's slope
    slope, intercept = np.polyfit(omega**2, np.abs(measured) ** -2.0, 1)
    tau_c = min(float(np.sqrt(slope / intercept)), 1.0) if slope > 0 and intercept > 0 else 0.05
    phase = np.unwrap(np.angle(measured)) + np.arctan(omega * tau_c)
    delay = min(max(-float(np.polyfit(omega, phase, 1)[0]), 0.0), 0.4)
    tau = stroke / np.log1p(stroke / tau_c)
    start = [float(np.abs(measured[0]) * np.hypot(1.0, omega[0] * tau_c)), tau, delay]
    fit = optimize.least_squares(residual, start, bounds=([1e-3, 1e-4, 0.0], [10.0, 2.0, 0.5]))
    gain, tau, delay = map(float, fit.x)
    quarter = max(len(measured) // 4, 1)
    low, high = (
        float(np.mean(np.abs(measured[q]))) for q in (slice(quarter), slice(-quarter, None))
    )
    if high > (1 - LAG_FALL) * low or np.any(fit.active_mask[:2]):  # no fall, or at a bound
        return None
    spread = 2 * fit.cost / max(fit.fun.size - 3, 1)  # the residuals' variance
    covariance = spread * np.linalg.pinv(fit.jac.T @ fit.jac)
    tau_sd = float(np.sqrt(covariance[1, 1]))
    if tau_sd > LAG_SPREAD * tau:
        return None
    band = (float(frequency_hz[keep][0]), float(frequency_hz[keep][-1]))
    return EngineLag(tau, tau_sd, gain, delay, stroke, band)


def run_lag(
    frequency_hz: np.ndarray,
    eng: np.ndarray,
    phase: np.ndarray,
    coherence: np.ndarray,
    speed_rpm: float,
) -> EngineLag | None:
    """:func:`engine_lag` of a run from |G_ENG| and the phase of S_zx / S_zu (T/T_ecu); None
    without a torque request (NaN phase)."""
    if not np.isfinite(phase).any():
        return None
    return engine_lag(frequency_hz, eng * np.exp(1j * phase), coherence, speed_rpm)
