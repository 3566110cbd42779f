"""Closed-loop frequency responses of one chirp run, paper eqs. (12)-(15).

Per run, the analysis works on the crank-event grid, as the paper does: the filtered speed's own
samples (every pi/2 of crank angle, uniform in angle and nearly uniform in time at idle), with
the mean torque, the torque request and the test torque request taken as the ECU holds them at
each event (the last value received). The test torque is then exactly the value the ECU added to
its request, the mean torque is held over L = 2 events as eq. (10) assumes, and no signal is
interpolated. A speed wandering by a few per cent smears a frequency by as much, well within a
Welch bin; resampling to a uniform time grid instead would turn the same wander into a jitter of
up to one event between the test torque and the torque it caused, which costs coherence. Missing
speed events (lost frames, up to ``MAX_GAP_SAMPLES`` in a row) are filled by cubic-spline
interpolation in time. Welch-averaged cross-spectra with the test torque z then give

* G = S_zy / S_zx, the plant seen from the measured mean torque x to the measured speed y (eq. 13),
* |G_DRV| = |G| |G_p| / |G_n| (eq. 14), (rad/s)/(N*m),
* |G_ENG| = |S_zx / S_zu| / |G_p| with u = T_ecu (eq. 15), 1,

and the coherence, the smaller of the z-x and z-y coherences (both paths must be clean).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
from scipy import fft, interpolate, ndimage, optimize, signal

from dtid.errors import AnalysisError
from dtid.identification.frf.runs import ChirpRun
from dtid.identification.frf.sensor_response import speed_filter_gain, torque_hold_gain
from dtid.identification.samples.testdata import Series, TestData
from dtid.simulator.angle_grid import STEPS_PER_STROKE, step_time

DEFAULT_RESOLUTION_HZ = 0.25
"""Welch frequency resolution: 4 s segments, a quarter of a typical DMF half-power bandwidth."""
MAX_GAP_SAMPLES = 5
"""A run whose speed has a gap longer than this many sample intervals is refused."""
MIN_SEGMENTS = 2
"""A run must hold at least this many Welch segments."""
GAIN_COHERENCE = 0.8
"""K (eq. 24) averages |G_ENG| over the bins at least this coherent."""
MIN_MEDIAN_COHERENCE = 0.5
"""A run whose coherence has a lower median over its band is refused: its FRF is mostly noise.
Simulated tests with realistic noise give 0.79-0.98 at 2-10 N*m, the HIL runs 0.71-0.96; a
10 N*m run on a host so loaded that the tool's requests came in bursts gave 0.10."""


@dataclass(frozen=True)
class FrfEstimate:
    """Frequency responses of one chirp run.

    Attributes
    ----------
    run
        The chirp run.
    frequency_hz
        Frequency grid, Hz: the Welch bins inside the band.
    drv
        |G_DRV| of eq. (14), (rad/s)/(N*m).
    eng
        |G_ENG| of eq. (15), 1; NaN where the recording has no torque request.
    coherence
        min(gamma^2_zx, gamma^2_zy), 1.
    req
        |S_zy / S_zu| / |G_n|: speed per requested torque T_ecu, (rad/s)/(N*m), the engine gain
        K included (the input of eq. 18 and setup 1); NaN without a torque request.
    speed_rpm
        Mean engine speed over the run, rpm (the speed the sensor corrections use).
    sample_rate_hz
        Mean rate of the crank events, Hz (sets the frequency axis).
    n_events
        Crank events in the run (the length of the analysed signals).
    nperseg
        Welch segment length, events.
    eng_phase
        Phase of S_zx / S_zu, rad: the measured mean torque's against the requested torque's;
        NaN without a torque request. With ``eng`` it is T/T_ecu (:attr:`engine_lag`).
    torque_coherence
        gamma^2_zx alone, 1: the measured torque's coherence with the test torque, which
        bounds the lag's band (the speed's dips at the antiresonance do not concern T/T_ecu).
    excitation
        S_zz, the test torque's auto-spectrum per bin, (N*m)^2/Hz: how much of the chirp each
        bin saw. Flat over the sweep, it falls in the bins at its ends, which fewer Welch
        segments see whole, and an FRF's scatter rises there as 1/S_zz.
    request_gain
        |S_zu / S_zz| per bin, 1: how far the torque request moves per unit of test torque (the
        idle loop's sensitivity, near 1 above its crossover, for a total request T_ecu); NaN
        without a torque request (:data:`REQUEST_GAIN_RANGE`).
    stroke_coherence
        The measured torque's coherence with the test torque as the strokes took it, 1
        (:func:`stroke_coherence`): what :attr:`torque_coherence` would be if the part of a
        chirp the strokes fold into the band counted as excitation, not as noise.
    """

    run: ChirpRun
    frequency_hz: np.ndarray
    drv: np.ndarray
    eng: np.ndarray
    coherence: np.ndarray
    req: np.ndarray
    speed_rpm: float
    sample_rate_hz: float
    n_events: int
    nperseg: int
    eng_phase: np.ndarray
    torque_coherence: np.ndarray
    excitation: np.ndarray
    request_gain: np.ndarray
    stroke_coherence: np.ndarray

    @property
    def drv_db(self) -> np.ndarray:
        """20 log10 |G_DRV|, dB re 1 (rad/s)/(N*m)."""
        return 20 * np.log10(self.drv)

    @property
    def req_db(self) -> np.ndarray:
        """20 log10 of the speed response to the torque request, dB re 1 (rad/s)/(N*m)."""
        return 20 * np.log10(self.req)

    @property
    def eng_db(self) -> np.ndarray:
        """20 log10 |G_ENG|, dB."""
        return 20 * np.log10(self.eng)

    @property
    def engine_gain(self) -> float:
        """K of eq. (24): mean of |G_ENG| over the band (NaN without a torque request).

        Bins whose coherence is below :data:`GAIN_COHERENCE` are left out (all are used if none
        reaches it): there |G_ENG| is noise, and a few such bins move the mean by tens of %.
        """
        trusted = self.coherence >= GAIN_COHERENCE
        return float(np.mean(self.eng[trusted] if trusted.any() else self.eng))

    @cached_property
    def engine_lag(self) -> EngineLag | None:
        """The engine's lag behind its request fitted to this run's T/T_ecu, fitted once
        (:func:`run_lag`); None without a torque request or without a lag."""
        return run_lag(
            self.frequency_hz, self.eng, self.eng_phase, self.torque_coherence, self.speed_rpm
        )

    def as_dict(self) -> dict[str, object]:
        """JSON-ready entry: the run, the grid, the magnitudes in dB and the engine's lag."""
        return {
            "amplitude_nm": self.run.amplitude_nm,
            "start_s": self.run.start_s,
            "end_s": self.run.end_s,
            "f1_hz": self.run.f1_hz,
            "f2_hz": self.run.f2_hz,
            "speed_rpm": self.speed_rpm,
            "engine_gain": None if np.isnan(self.engine_gain) else self.engine_gain,
            "frequency_hz": self.frequency_hz.tolist(),
            "drv_db": self.drv_db.tolist(),
            "eng_db": None if np.all(np.isnan(self.eng)) else self.eng_db.tolist(),
            "coherence": self.coherence.tolist(),
            "engine_lag": None if (lag := self.engine_lag) is None else lag.as_dict(),
        }


def _hold(series: Series, grid: np.ndarray) -> np.ndarray:
    """Value of the last sample at or before each grid time (the first sample before it)."""
    index = np.searchsorted(series.t, grid, side="right") - 1
    return series.value[np.clip(index, 0, len(series) - 1)]


def _event_grid(times: np.ndarray, interval: float) -> np.ndarray:
    """The speed's event times with any missing events (gaps of 1.5 intervals or more) filled."""
    gaps = np.diff(times)
    missing = np.maximum(np.rint(gaps / interval).astype(np.int64) - 1, 0)
    if not np.any(missing > 0):
        return times
    pieces = [times[:1]]
    for start, gap, extra in zip(times[:-1], gaps, missing, strict=True):
        step = gap / (extra + 1)
        pieces.append(start + step * np.arange(1, extra + 2))
    return np.concatenate(pieces)


def _unique_times(series: Series) -> Series:
    """Drop samples whose timestamp repeats the previous one (duplicated frames)."""
    keep = np.concatenate(([True], np.diff(series.t) > 0))
    return Series(series.t[keep], series.value[keep])


def estimate_frf(
    data: TestData,
    run: ChirpRun,
    resolution_hz: float = DEFAULT_RESOLUTION_HZ,
    band_hz: tuple[float, float] | None = None,
) -> FrfEstimate:
    """Estimate G_DRV, G_ENG and the coherence of one chirp run.

    Parameters
    ----------
    data
        The test's signals.
    run
        The chirp run to analyse (see :func:`dtid.identification.frf.runs.find_runs`).
    resolution_hz
        Welch frequency resolution, Hz; sets the segment length 1/resolution.
    band_hz
        Frequency band to report, Hz; the run's sweep (less half a bin at each end) by default.
        Must lie inside the sweep and below the mean torque's Nyquist frequency.

    Returns
    -------
    FrfEstimate

    Raises
    ------
    AnalysisError
        If the run is too short for the resolution, the speed has a gap, the band is not
        covered by the chirp, or the coherence is too low (:data:`MIN_MEDIAN_COHERENCE`).
    """
    data.require()
    speed = _unique_times(data.speed.window(run.start_s, run.end_s))
    if len(speed) < 16:
        raise AnalysisError(
            f"chirp run at {run.start_s:.1f}-{run.end_s:.1f} s holds only {len(speed)} speed "
            "samples; the speed signal is missing there"
        )
    interval = float(np.median(np.diff(speed.t)))
    gaps = np.diff(speed.t)
    if gaps.max() > MAX_GAP_SAMPLES * interval:
        at = float(speed.t[np.argmax(gaps)])
        raise AnalysisError(
            f"the speed signal has a {gaps.max():.3f} s gap at t = {at:.2f} s inside the chirp "
            f"run at {run.start_s:.1f}-{run.end_s:.1f} s (sample interval {interval * 1e3:.1f} "
            "ms); frames were lost, so this run cannot give an FRF"
        )
    rate = 1.0 / interval
    nperseg = segment_length(rate, resolution_hz)
    grid = _event_grid(speed.t, interval)
    if len(grid) < MIN_SEGMENTS * nperseg:
        raise AnalysisError(
            f"chirp run at {run.start_s:.1f}-{run.end_s:.1f} s lasts {run.duration_s:.1f} s, too "
            f"short for a {resolution_hz} Hz resolution (needs {MIN_SEGMENTS / resolution_hz:.0f} "
            "s); record a longer chirp or ask for a coarser resolution"
        )
    speed_rpm = float(np.mean(speed.value))
    torque_nyquist = 0.5 * rate / 2
    if band_hz is None:  # the sweep less its edges (below), clipped below the torque Nyquist
        edge = sweep_edge_hz(run, resolution_hz)
        lo = min(run.f1_hz, run.f2_hz) + edge
        hi = min(max(run.f1_hz, run.f2_hz) - edge, 0.98 * torque_nyquist)
        if hi <= lo:
            raise AnalysisError(
                f"a {resolution_hz:g} Hz resolution is too coarse for the chirp's "
                f"{run.f1_hz:.2f}-{run.f2_hz:.2f} Hz sweep (run at {run.start_s:.1f} s): its "
                "edges, half a bin each, leave no band; ask for a finer resolution"
            )
    else:
        lo, hi = band_hz
    sweep_lo, sweep_hi = sorted((run.f1_hz, run.f2_hz))
    if lo < sweep_lo - 1e-6 or hi > sweep_hi + 1e-6 or hi <= lo:
        raise AnalysisError(
            f"band {lo:.2f}-{hi:.2f} Hz is not inside the chirp's sweep {sweep_lo:.2f}-"
            f"{sweep_hi:.2f} Hz (run at {run.start_s:.1f} s)"
        )
    if hi > torque_nyquist:
        raise AnalysisError(
            f"band top {hi:.2f} Hz is above {torque_nyquist:.2f} Hz, the Nyquist frequency of a "
            f"mean torque sampled once per stroke at {speed_rpm:.0f} rpm"
        )

    if len(grid) == len(speed):
        y = speed.value
    else:
        y = interpolate.CubicSpline(speed.t, speed.value)(grid)
    x = _hold(data.mean_torque, grid)
    z = _hold(data.test_torque, grid)
    frequency, s_zy, s_zx = cross_spectra(z, y, x, rate, nperseg)
    keep = (frequency >= lo) & (frequency <= hi)
    if not np.any(keep):
        raise AnalysisError(f"no frequency bin of {resolution_hz} Hz lies in {lo:.2f}-{hi:.2f} Hz")
    f, s_zy, s_zx = frequency[keep], s_zy[keep], s_zx[keep]
    welch = _welch_settings(rate, nperseg)
    s_zz, s_yy, s_xx = (signal.welch(v, **welch)[1][keep] for v in (z, y, x))
    torque_coherence = np.abs(s_zx) ** 2 / (s_zz * s_xx)
    coherence = np.minimum(np.abs(s_zy) ** 2 / (s_zz * s_yy), torque_coherence)
    request_coherence = None
    if data.torque_request is not None and len(data.torque_request) > 1:
        u = _hold(data.torque_request, grid)
        _, s_zu = signal.csd(z, u, **welch)
        s_uu = signal.welch(u, **welch)[1][keep]
        request_coherence = np.abs(s_zu[keep]) ** 2 / (s_zz * s_uu)
        eng = engine_magnitude(f, s_zx, s_zu[keep], speed_rpm)
        phase = np.angle(s_zx / s_zu[keep])  # the hold's gain is real: it keeps the phase
        req = request_magnitude(f, s_zy, s_zu[keep], speed_rpm)
        request_gain = np.abs(s_zu[keep]) / s_zz
    else:
        eng = req = phase = request_gain = np.full_like(f, np.nan)
    median_coherence = float(np.median(coherence))
    by_strokes = stroke_coherence(data, grid, x, welch, keep)
    if median_coherence < MIN_MEDIAN_COHERENCE and not (
        sweep_hi > torque_nyquist  # the chirp folds: judge the test by what the strokes took
        and float(np.median(by_strokes)) >= MIN_MEDIAN_COHERENCE
    ):
        finer = _coherent_at_the_default(data, run, resolution_hz, band_hz)
        raise AnalysisError(
            f"the chirp run at {run.start_s:.1f}-{run.end_s:.1f} s has a median coherence of "
            f"{median_coherence:.2f} over {lo:.2f}-{hi:.2f} Hz (at least "
            f"{MIN_MEDIAN_COHERENCE} expected): "
            + (
                f"a {resolution_hz:g} Hz resolution cuts it into segments of "
                f"{1 / resolution_hz:.2g} s, shorter than the drivetrain's response, where "
                f"{DEFAULT_RESOLUTION_HZ:g} Hz gives {finer:.2f}; ask for a finer resolution"
                if finer is not None
                else incoherence_cause(
                    f,
                    torque_coherence,
                    request_coherence,
                    run_lag(f, eng, phase, torque_coherence, speed_rpm),
                )
            )
        )
    drv = drivetrain_magnitude(f, s_zy, s_zx, speed_rpm)
    return FrfEstimate(
        run,
        f,
        drv,
        eng,
        coherence,
        req,
        speed_rpm,
        rate,
        len(grid),
        nperseg,
        phase,
        torque_coherence,
        s_zz,
        request_gain,
        by_strokes,
    )


REQUEST_GAIN_RANGE = (0.5, 2.0)
"""Median over a recording's runs and bins of |S_zu / S_zz| (:attr:`FrfEstimate.request_gain`)
outside which the mapped torque request is not the total request T_ecu = controller + test
torque of the paper's Fig. 1 (or it or the test torque is in another unit): 1.09-1.13 on the
reference vehicle's test, 1.04-1.06 on the independent recordings, 0.93-1.17 on the randomised
trial's vehicles 1-40 (their own idle loops, kp 0.05-0.48 N*m/rpm, hunting ones among them),
0.16-0.18 where the reference's request was recorded without its test torque (an ECU's base
request), 2026-12-07."""
REQUEST_FOLLOWS = 0.9
"""Median coherence of the torque request with the test torque above which the ECU is taken to
have added the test torque as asked (:func:`incoherence_cause`)."""
TORQUE_FALL = 0.25
"""Fall of the measured torque's median coherence from the band's lowest third to its highest
above which the engine is read as not following the request at high frequency."""


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


def _coherent_at_the_default(
    data: TestData,
    run: ChirpRun,
    resolution_hz: float,
    band_hz: tuple[float, float] | None,
) -> float | None:
    """The median coherence of a run refused at a resolution coarser than
    :data:`DEFAULT_RESOLUTION_HZ` where the default passes it, else None: the resolution, not
    the test, is then why (`dtid frf --resolution 3` said "the test was disturbed")."""
    if resolution_hz <= DEFAULT_RESOLUTION_HZ:
        return None
    try:
        estimate = estimate_frf(data, run, DEFAULT_RESOLUTION_HZ, band_hz)
    except AnalysisError:
        return None
    return float(np.median(estimate.coherence))


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
        taken = _hold(data.test_torque, reports - events * interval)
        z = _hold(Series(reports, taken), grid)
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


def sweep_edge_hz(run: ChirpRun, resolution_hz: float) -> float:
    """Width at each end of a chirp's sweep that no Welch segment covers fully, Hz.

    A segment lasts 1/resolution; near the sweep's ends only part of one sees those frequencies
    (and the window tapers it), so their estimate is poor. That is half a segment's worth of
    sweep, and at least half a bin: 0.47 Hz for the default 60 s chirp from 1 to 15 Hz.
    """
    sweep_rate = abs(run.f2_hz - run.f1_hz) / run.duration_s
    return max(0.5 * resolution_hz, 0.5 * sweep_rate / resolution_hz)


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


def _welch_settings(rate: float, nperseg: int) -> dict[str, object]:
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


def request_magnitude(
    frequency_hz: np.ndarray, s_zy: np.ndarray, s_zu: np.ndarray, speed_rpm: float | np.ndarray
) -> np.ndarray:
    """|G| from the torque request T_ecu to the speed, (rad/s)/(N*m): K times the plant.

    T_ecu is sampled at every crank event without a hold, so only the speed filter is corrected.
    """
    return np.abs(s_zy / s_zu) / speed_filter_gain(frequency_hz, speed_rpm)


def engine_magnitude(
    frequency_hz: np.ndarray, s_zx: np.ndarray, s_zu: np.ndarray, speed_rpm: float | np.ndarray
) -> np.ndarray:
    """|G_ENG| of eq. (15) from the cross-spectra with the test torque, 1: the measured mean torque
    per requested torque T_ecu, the torque sensor's hold G_p removed (T_ecu is sampled at every
    crank event without a hold).

    ``speed_rpm`` may be one speed per row of the spectra (shape (n, 1)) for a batch of tests.
    """
    return np.abs(s_zx / s_zu) / torque_hold_gain(frequency_hz, speed_rpm)


def drivetrain_magnitude(
    frequency_hz: np.ndarray, s_zy: np.ndarray, s_zx: np.ndarray, speed_rpm: float | np.ndarray
) -> np.ndarray:
    """|G_DRV| of eq. (14) from the cross-spectra, (rad/s)/(N*m).

    ``speed_rpm`` may be one speed per row of the spectra (shape (n, 1)) for a batch of tests.
    """
    hold = torque_hold_gain(frequency_hz, speed_rpm)
    return np.abs(s_zy / s_zx) * hold / speed_filter_gain(frequency_hz, speed_rpm)
