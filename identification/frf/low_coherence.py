"""Why a chirp run's coherence is low, and what to judge such a run by.

A run whose FRF would be mostly noise is refused
(:data:`~dtid.identification.frf.closed_loop.MIN_MEDIAN_COHERENCE`), with its cause: a chirp the
strokes fold into the band is excitation, not noise (:func:`stroke_coherence`); an engine that
delivers its request with a lag leaves too little test torque in the upper band
(:func:`incoherence_cause`); otherwise the test was disturbed.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from dtid.identification.frf.engine_lag import LAG_COHERENCE, EngineLag
from dtid.identification.samples.testdata import Series, TestData

REQUEST_FOLLOWS = 0.9
"""Median coherence of the torque request with the test torque above which the ECU is taken to
have added the test torque as asked (:func:`incoherence_cause`)."""
TORQUE_FALL = 0.25
"""Fall of the measured torque's median coherence from the band's lowest third to its highest
above which the engine is read as not following the request at high frequency."""


def stroke_coherence(
    data: TestData,
    grid: np.ndarray,
    torque: np.ndarray,
    welch: dict[str, object],
    keep: np.ndarray,
) -> np.ndarray:
    """Coherence of the measured mean torque with the test torque as the strokes took it, per
    bin of the band (``keep`` among Welch's bins), 1.

    The engine takes its request once per stroke, so a chirp that sweeps above the strokes'
    Nyquist frequency folds into the band (at f_s - f), in the torque and the speed alike but
    not in the test torque the tool sent. Against that test torque the folded part reads as
    noise: a test at a low idle swept to 20 Hz (650 rpm, f_s 21.7 Hz) showed a median coherence
    of 0.47 over 1.2-10.6 Hz, the independent vehicle_1 (850 rpm) 0.48-0.57 over 9-14 Hz.
    The model replays the folding (it takes the recorded request at the vehicle's crank events),
    so such a run is not disturbed: sampled as the strokes took it, once per mean-torque report
    at the better (by median) of the stroke's crank events, the test torque holds the folded
    part too, and the coherence is that of the run's noise (0.94 and 0.96-0.98 there).

    Parameters
    ----------
    data
        The run's signals.
    grid
        The speed's event grid, s.
    torque
        The measured mean torque held on ``grid``, N*m.
    welch
        The FRF's Welch settings.
    keep
        The band's bins among Welch's.
    """
    reports = data.mean_torque.t
    interval = float(np.median(np.diff(grid)))
    per_stroke = max(1, round(float(np.median(np.diff(reports))) / interval))
    s_xx = signal.welch(torque, **welch)[1][keep]
    best = np.zeros(int(np.count_nonzero(keep)))
    for events in range(per_stroke):
        taken = data.test_torque.held(reports - events * interval)
        z = Series(reports, taken).held(grid)
        _, s_zx = signal.csd(z, torque, **welch)
        s_zz = signal.welch(z, **welch)[1][keep]
        coherence = np.abs(s_zx[keep]) ** 2 / (s_zz * s_xx)
        if np.median(coherence) > np.median(best):
            best = coherence
    return best


def incoherence_cause(
    frequency_hz: np.ndarray,
    torque: np.ndarray,
    request: np.ndarray | None,
    lag: EngineLag | None = None,
) -> str:
    """Why a run's FRF would be noise, as the refusal's text.

    When the ECU's torque request follows the test torque (median coherence at least
    :data:`REQUEST_FOLLOWS`) and the measured mean torque's coherence falls from the band's
    lowest third to its highest by more than :data:`TORQUE_FALL`, the engine delivers the
    request with a lag (its torque path): the test torque reaching the drivetrain shrinks with
    frequency below the combustion's scatter, and repeating the test changes nothing
    (blind-trial case 10, a 0.12 s lag: at 5 N*m 0.82 over 1.5-5.7 Hz, 0.38 over 10.2-14.2 Hz,
    the request 1.00). The lag is then fitted where the torque is coherent (:func:`engine_lag`)
    and named with the frequency where it halves the delivered test torque. Otherwise something
    disturbed the test.

    Parameters
    ----------
    frequency_hz
        The band's bins, Hz.
    torque
        Coherence of the measured mean torque with the test torque per bin.
    request
        Coherence of the torque request with the test torque per bin (None: not on the bus).
    lag
        The run's lag fitted where the torque is coherent (:func:`run_lag`; None: none, or no
        torque request on the bus).
    """
    thirds = np.array_split(np.arange(len(frequency_hz)), 3)
    low, high = (float(np.median(torque[i])) for i in (thirds[0], thirds[-1]))
    follows = request is not None and float(np.median(request)) >= REQUEST_FOLLOWS
    if follows and low - high > TORQUE_FALL:
        assert request is not None
        span = [(frequency_hz[i[0]], frequency_hz[i[-1]]) for i in (thirds[0], thirds[-1])]
        fitted = ""
        if lag is not None:
            half = lag.half_hz
            halves = (
                ""
                if half is None
                else (f": the engine delivers half the requested test torque at {half:.1f} Hz")
            )
            fitted = (
                f" (T/T_ecu over {lag.band_hz[0]:.1f}-{lag.band_hz[1]:.1f} Hz, where the torque's "
                f"coherence holds {LAG_COHERENCE}, is a first-order lag of about "
                f"{lag.tau_s:.2f} s with K {lag.gain:.2f} behind a dead time of about "
                f"{lag.delay_s:.2f} s{halves})"
            )
        return (
            f"the ECU's torque request follows the test torque (coherence "
            f"{float(np.median(request)):.2f}) but the measured torque does so less and less "
            f"with frequency (coherence {low:.2f} over {span[0][0]:.1f}-{span[0][1]:.1f} Hz, "
            f"{high:.2f} over {span[1][0]:.1f}-{span[1][1]:.1f} Hz): the engine delivers the "
            f"request with a lag{fitted}, so too little test torque reaches the upper band above "
            "the combustion's scatter; repeating the test will not help, a larger amplitude or a "
            "sweep ending lower ([test] f2_hz) would"
        )
    return (
        "the speed and torque do not follow the test torque, so its FRF would be noise; the "
        "test was disturbed (a tool that could not send its requests on time, a driver input, "
        "a load switched on), repeat it"
    )
