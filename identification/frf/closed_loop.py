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
from functools import cached_property

import numpy as np
from scipy import interpolate, signal

from dtid.errors import AnalysisError
from dtid.identification.frf.engine_lag import EngineLag, run_lag
from dtid.identification.frf.low_coherence import incoherence_cause, stroke_coherence
from dtid.identification.frf.runs import ChirpRun
from dtid.identification.frf.sensor_response import speed_filter_gain, torque_hold_gain
from dtid.identification.frf.spectra import cross_spectra, segment_length, welch_settings
from dtid.identification.samples.testdata import Series, TestData

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
        (:func:`~dtid.identification.frf.low_coherence.stroke_coherence`): what
        :attr:`torque_coherence` would be if the part of a chirp the strokes fold into the band
        counted as excitation, not as noise.
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
        (:func:`~dtid.identification.frf.engine_lag.run_lag`); None without a torque request or
        without a lag."""
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
    x = data.mean_torque.held(grid)
    z = data.test_torque.held(grid)
    frequency, s_zy, s_zx = cross_spectra(z, y, x, rate, nperseg)
    keep = (frequency >= lo) & (frequency <= hi)
    if not np.any(keep):
        raise AnalysisError(f"no frequency bin of {resolution_hz} Hz lies in {lo:.2f}-{hi:.2f} Hz")
    f, s_zy, s_zx = frequency[keep], s_zy[keep], s_zx[keep]
    welch = welch_settings(rate, nperseg)
    s_zz, s_yy, s_xx = (signal.welch(v, **welch)[1][keep] for v in (z, y, x))
    torque_coherence = np.abs(s_zx) ** 2 / (s_zz * s_xx)
    coherence = np.minimum(np.abs(s_zy) ** 2 / (s_zz * s_yy), torque_coherence)
    request_coherence = None
    if data.torque_request is not None and len(data.torque_request) > 1:
        u = data.torque_request.held(grid)
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


def sweep_edge_hz(run: ChirpRun, resolution_hz: float) -> float:
    """Width at each end of a chirp's sweep that no Welch segment covers fully, Hz.

    A segment lasts 1/resolution; near the sweep's ends only part of one sees those frequencies
    (and the window tapers it), so their estimate is poor. That is half a segment's worth of
    sweep, and at least half a bin: 0.47 Hz for the default 60 s chirp from 1 to 15 Hz.
    """
    sweep_rate = abs(run.f2_hz - run.f1_hz) / run.duration_s
    return max(0.5 * resolution_hz, 0.5 * sweep_rate / resolution_hz)


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
