"""Welch spectra of crank-event signals, paper eqs. (12)-(13): the segment length, the
cross-spectra with the test torque, and the settings scipy's Welch functions take for the same
estimate.

The measured FRF (:mod:`dtid.identification.frf.closed_loop`) and the model side
(:mod:`dtid.identification.model.response`) both estimate with these, so that the estimator's
own biases (window, segment length, leakage) are the same on both sides of eq. (17).
"""

from __future__ import annotations

from functools import cache

import numpy as np
from scipy import fft, signal


def segment_length(rate: float, resolution_hz: float) -> int:
    """Welch segment length, events: the length nearest ``rate / resolution_hz`` whose FFT is
    fast (a product of 2, 3 and 5: :func:`scipy.fft.next_fast_len`), so the resolution is the
    one asked for within a few per cent.

    At a prime length pocketfft falls back on a slower algorithm: vehicle_1 of the independent
    recordings (56.7 events/s, 227 events for 0.25 Hz) spent 0.39 ms on each of a
    single-set model evaluation's FFTs, a quarter of it, where 225 takes a tenth of that.

    Parameters
    ----------
    rate
        Event rate, Hz.
    resolution_hz
        Frequency resolution asked for, Hz.
    """
    exact = rate / resolution_hz
    below = fft.prev_fast_len(max(round(exact), 1), real=True)
    above = fft.next_fast_len(max(round(exact), 1), real=True)
    return below if exact - below <= above - exact else above


def welch_settings(rate: float, nperseg: int) -> dict[str, object]:
    """The keyword arguments of :func:`scipy.signal.welch` and :func:`scipy.signal.csd` that
    :func:`cross_spectra` estimates alike: Hann window, half overlap, mean removed per segment.

    Parameters
    ----------
    rate
        Event rate, Hz.
    nperseg
        Welch segment length, samples.
    """
    return {"fs": rate, "nperseg": nperseg, "window": "hann", "detrend": "constant"}


def cross_spectra(
    z: np.ndarray, y: np.ndarray, x: np.ndarray, rate: float, nperseg: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Welch cross-spectra S_zy and S_zx of crank-event signals, eqs. (12)-(13).

    Parameters
    ----------
    z, y, x
        Test torque (N*m), filtered speed (rpm) and mean torque (N*m) on the event grid; 1-D, or
        2-D with one test per row (the model side of the identification), where ``z`` may be a
        single row that every test shares.
    rate
        Event rate, Hz.
    nperseg
        Welch segment length, samples (Hann window, half overlap, mean removed per segment).

    Returns
    -------
    tuple of numpy.ndarray
        Frequencies (Hz), S_zy and S_zx (complex, last axis over frequency).
    """
    window = _hann(nperseg)
    z_f, y_f, x_f = (_segment_spectra(v, window) for v in (z, y, x))
    scale = np.full(z_f.shape[-1], 2.0 / (rate * np.sum(window**2)))
    scale[0] /= 2
    if nperseg % 2 == 0:
        scale[-1] /= 2  # the Nyquist bin, like DC, is its own mirror
    conjugate = np.conj(z_f)
    s_zy = np.mean(conjugate * y_f, axis=-2) * scale
    s_zx = np.mean(conjugate * x_f, axis=-2) * scale
    return fft.rfftfreq(nperseg, 1.0 / rate), s_zy, s_zx


@cache
def _hann(nperseg: int) -> np.ndarray:
    """The Welch segments' Hann window (periodic, as :func:`scipy.signal.csd` takes it), made
    once per length: the model side asks for it at every evaluation."""
    window = signal.get_window("hann", nperseg)
    window.flags.writeable = False
    return window


def _segment_spectra(values: np.ndarray, window: np.ndarray) -> np.ndarray:
    """The FFTs of a signal's Welch segments (half overlap, the mean removed, the window
    applied), all at once: (..., segments, frequencies).

    :func:`scipy.signal.csd` makes the same estimate (``tests/test_frf.py`` checks it to 1e-10)
    but transforms segment by segment in Python; for the model side's single parameter sets,
    a search's commonest call, that loop took half of each evaluation (0.20 of 0.38 s for
    twelve sets of two realizations on vehicle_1's recordings, 2026-11-30)."""
    nperseg = len(window)
    step = nperseg - nperseg // 2
    segments = np.lib.stride_tricks.sliding_window_view(values, nperseg, axis=-1)[..., ::step, :]
    return fft.rfft((segments - segments.mean(axis=-1, keepdims=True)) * window, axis=-1)
