"""The speed sensor's noise, measured from the recorded speed where the engine puts nothing.

The speed is reported at every crank event (pi/2), each report the mean speed over half a
revolution (eq. 9, or the window's angle over its time for a tooth timer). That half
revolution is one firing period of a four-cylinder engine, two events long, and an average
over two samples has its zero at the events' Nyquist frequency: the crankshaft's motion, its
pulsation and the chirp alike, hardly reaches there, while noise the sensor adds to each report
(tooth-wheel jitter, the arithmetic's quantisation) does. The recorded speed's power spectral
density over the top :data:`NYQUIST_BAND` of the band is that noise's, and for white noise of
standard deviation s sampled at f_s it is 2 s^2 / f_s.

The diagnosis needs it: its model draws a recording's scatter (:mod:`dtid.identification.
diagnosis.mismatch`), and without the speed's noise the draws missed half of the scatter the
recordings of a 5 N*m chirp show at the top of the sweep, where the speed's response is
smallest (the reference vehicle, seeds 1-24: 0.17-0.23 dB against 0.11-0.13 dB over 13.2-14.2
Hz).

Measured: on the reference vehicle's recordings (seed 3, 5 and 10 N*m) 0.298 rpm for 0.3 rpm
and 0.595 rpm for 0.6, 0.013 rpm without noise, whatever the combustion variation (3 or 6 %);
on the independent recordings (0.2 rpm per speed event) 0.186-0.216 rpm from each of their six
files. A sensor whose noise is averaged with the speed (jitter on the tooth times inside the
window) shows less there, and the model then draws less of it: the mismatch map's scatter scale
(``scatter_scale``) still widens the scatter by the residual's roughness.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

NYQUIST_BAND = 0.05
"""Share of the band below the events' Nyquist frequency over which the noise is read."""
SEGMENT = 256
"""Welch segment length, events (0.2-0.3 Hz bins at idle: five or six in the band)."""


def speed_noise_rpm(speed_rpm: np.ndarray, rate_hz: float) -> float:
    """Standard deviation of the white noise on each speed report, rpm (NaN if too short).

    Parameters
    ----------
    speed_rpm
        The recorded speed on its crank-event grid (lost events filled in), rpm.
    rate_hz
        The events' rate, Hz.

    Returns
    -------
    float
        sqrt(mean PSD over the top :data:`NYQUIST_BAND` of the band x f_s / 2), rpm.
    """
    if len(speed_rpm) < 4 * SEGMENT:
        return float("nan")
    f, psd = signal.welch(speed_rpm, fs=rate_hz, nperseg=SEGMENT)
    nyquist = rate_hz / 2
    top = (f >= (1 - NYQUIST_BAND) * nyquist) & (f < nyquist)  # the Nyquist bin is not doubled
    return float(np.sqrt(np.mean(psd[top]) * nyquist))
