"""How the model of a recorded test closes the vehicle's idle loop: with what the vehicle did.

The identification's model repeats a recorded chirp test in simulation (eq. 16 compares the
two |G_DRV|). The paper's plant runs in closed loop (Fig. 1): the vehicle's idle-speed controller
adds its own torque to the test torque. Eq. (13) removes the controller from the FRF, but only
for a linear plant: the free plays respond to the torque amplitude the engine actually delivers,
and near the DMF resonance the idle loop still has gain, so the delivered torque is not the test
torque (on an independent recording, |T_m / T_test| over 6.5-8 Hz was 0.96-0.99 in the vehicle
and 1.09-1.12 with the product's own PI imposed on the model: a DMF resonance 0.6 Hz off).

The vehicle's controller, its timing and how a stroke latches the request are the vehicle's
own; no recording discloses them. So the model assumes none of them and drives its engine with
what the vehicle's engine was asked for, from the recording:

``recorded_request``
    The ECU's total torque request T_ecu (role ``torque_request``), which real ECUs put on the
    bus: the engine's strokes latch it as the vehicle's did (K T_ecu, eq. 3), whatever
    controller, delay or filter produced it. The recorded request already holds the test
    torque the ECU accepted.
``measured_torque``
    Without T_ecu on the bus: the measured mean torque of each stroke (the engine gain K then
    cancels). This assumes the cylinder-pressure torque is the torque the engine delivered:
    its sensor noise becomes an excitation the vehicle did not see (0.3 N*m per stroke against
    5-10 N*m of test torque), and the measured strokes carry the vehicle's own combustion
    variation, so the model adds none. It also assumes each stroke's torque is reported when
    the stroke ends, as a cylinder-pressure system can first know it then.

The model repeats the test crank event by crank event, not second by second. The engine
takes its request once per stroke, so the torque the plant sees is the request *sampled at the
strokes*; near a third of the firing frequency its alias falls on the free play's second
harmonic, and how the two add depends on which samples the strokes took. Each model stroke
therefore takes exactly the request the vehicle's stroke at the same crank angle took, found by
regressing the measured mean torque on the recorded request over a few crank events of lag
(:func:`latch`); the model's speed samples are compared with the vehicle's at the same crank
angle, and its FRF uses the test torque the vehicle's ECU held at those crank events.

An engine driven open loop drifts: a 1 % error of K alone, or the sensor's noise integrated
over a minute, moves the idle speed by tens of rpm, which shifts the firing frequency and the
frequency axis. The model therefore keeps its simulated speed on the *recorded* speed with a
slow tracking controller of its own (:data:`TRACK_BANDWIDTH_HZ`, far below the chirp band).
At the true parameters the two speeds differ only by noise and it adds almost nothing; where a
candidate parameter set responds differently, its torque goes into the model's own measured
mean torque x, so eq. (13) removes it from the model's |G_DRV| as it removes the vehicle's
controller from the measured one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from dtid.errors import AnalysisError
from dtid.identification.model.combustion import (
    SYSTEMATIC_TAPS,
    recorded_variation,
    variation_and_noise,
)
from dtid.identification.model.cylinder_spread import odd_place, stroke_factors
from dtid.identification.model.speed_noise import speed_noise_rpm
from dtid.identification.samples.testdata import Series, TestData
from dtid.jsonfile import json_number
from dtid.simulator.angle_grid import N_CYL, RPM_PER_RAD_S
from dtid.simulator.controller import IdleController

RECORDED_REQUEST = "recorded_request"
"""The model's engine is driven by the recorded torque request T_ecu."""
MEASURED_TORQUE = "measured_torque"
"""The model's engine is driven by the measured mean torque (no T_ecu on the bus)."""

TRACK_BANDWIDTH_HZ = 0.1
"""Crossover of the model's speed-tracking loop, Hz: a fifth of the lowest chirp frequency
(0.5 Hz), where its loop gain is then 0.2, and ten times the inverse of a 60 s run, so that
drift cannot build up (a random walk of 0.3 N*m per stroke leaves about 2 rpm)."""
TRACK_INTEGRAL_HZ = 0.02
"""Corner of the tracking loop's integral action, Hz: it takes up a constant torque error (the
engine gain's or the loss torque's) within the settling time before each run."""
TRACK_FILTER_HZ = 0.3
"""Corner of the first-order low-pass on the tracking loop's speed error, Hz: the error's
content in the chirp band (where the model's and the vehicle's speed differ by their crank
alignment and by whatever parameter set is tried) reaches the tracking torque 0.5 times at
0.5 Hz, 0.04 times at 7 Hz; the loop keeps 60 degrees of phase margin."""
NOMINAL_INERTIA = 0.25
"""Total inertia the tracking gains are sized for, kg*m^2 (a passenger car's engine, DMF and
gearbox input; for 0.1-0.5 kg*m^2 the crossover lies at 0.05-0.25 Hz, still below the band)."""
LATCH_LAGS = range(-2, 6)
"""Crank events (pi/2 each) between the request a stroke takes and its mean torque's report
that :func:`latch` tries: a report may come at the stroke's start or its end, and an ECU may
latch a request formed some events before."""
SAMPLES_PER_STROKE = 2
"""Speed samples (crank events of pi/2) per stroke (pi)."""
LAG_BRACKET = 3.0
""":func:`stroke_lag` searches the lag within this factor either side of its first estimate."""
LAG_GRID = 13
"""Lags :func:`stroke_lag` tries, log-spaced over its bracket, before refining the best."""


@dataclass(frozen=True)
class IdleLoop:
    """A recording on its crank-event grid, as the model repeats it (see the module notes).

    Attributes
    ----------
    mode
        :data:`RECORDED_REQUEST` or :data:`MEASURED_TORQUE`.
    t
        Crank-event times (every pi/2; lost events filled in), s, recording time.
    speed_rpm
        The recorded speed at each event, rpm (what the model's speed tracks).
    test_nm
        The test torque the ECU held at each event, N*m (the FRF's excitation z).
    drive_nm
        The request a stroke starting at each event takes, N*m: the recorded T_ecu, or the
        measured torque of the stroke (then K is in it already).
    first_stroke
        An event at which a stroke starts (strokes start every second event from there).
    latch_samples
        Events from the request a stroke takes to its mean torque's report (:func:`latch`).
    gain
        Least-squares K of the measured torque on the latched request (1 for a drive by
        measured torque).
    residual_nm
        RMS of the measured torque less K times the latched request, N*m: the sensor's noise
        and the combustion variation when the latch is right.
    combustion_variation, torque_noise_nm
        The two told apart (:func:`dtid.identification.model.combustion.variation_and_noise`):
        relative variation of each stroke's delivered torque, 1, and the torque sensor's noise, N*m;
        NaN for a drive by measured torque.
    speed_noise_rpm
        The speed sensor's noise on each report, rpm
        (:func:`dtid.identification.model.speed_noise.speed_noise_rpm`; NaN if not measured).
    stroke_t, stroke_request_nm, stroke_torque_nm
        Each reported stroke's time (s), the request it took and its measured mean torque
        (N*m), for K read stroke by stroke (:meth:`engine_gain`); empty for a drive by measured
        torque.
    stroke_number
        Each reported stroke's number counted from :attr:`first_stroke` (two crank events per
        stroke; a lost report leaves a gap): ``stroke_number % N_CYL`` is its place in the
        firing order (:mod:`dtid.identification.model.cylinder_spread`).
    odd_stroke
        The place in the firing order (0..N_CYL-1 of :attr:`stroke_number`) whose torque departs
        most from the others': where the model puts a ``cylinder_imbalance``
        (:meth:`cylinder_offset`); 0 for a drive by measured torque, which holds the
        cylinders' spread already.
    lag_s
        The lag the model's engine delivers the request through (the ``torque_lag``
        mechanism's tau_m), s; 0: at once. The latch, K, the variation and
        :attr:`stroke_request_nm` are read through it (:func:`stroke_lagged`).
    variation_nm
        The recording's own combustion variation, per crank event at the event its stroke
        latched, in request units (N*m of T_ecu), as far as the measured torque tells it from
        the sensor's noise (:func:`dtid.identification.model.combustion.recorded_variation`);
        :meth:`drive` adds it to the request, so that the model's idle loop, which replays the
        vehicle's reaction to this variation, is excited by it and not by a draw of its own.
        Empty for a drive by measured torque and with an engine lag.
    variation_left
        The factor by which the relative variation the model still draws is smaller than
        :attr:`combustion_variation` (1 where nothing of it is known).
    """

    mode: str
    t: np.ndarray
    speed_rpm: np.ndarray
    test_nm: np.ndarray
    drive_nm: np.ndarray
    first_stroke: int
    latch_samples: int = 0
    gain: float = 1.0
    residual_nm: float = 0.0
    combustion_variation: float = float("nan")
    torque_noise_nm: float = float("nan")
    stroke_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stroke_request_nm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stroke_torque_nm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stroke_number: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    odd_stroke: int = 0
    lag_s: float = 0.0
    speed_noise_rpm: float = float("nan")
    variation_nm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    variation_left: float = 1.0

    def engine_gain(self, windows: Sequence[tuple[float, float]] = ()) -> tuple[float, float]:
        """K of eq. (3) from the strokes reported inside ``windows`` (s; all when empty):
        :func:`stroke_gain`'s slope and weight; NaN and 0 without a recorded request."""
        inside = np.ones(len(self.stroke_t), dtype=bool)
        if windows:
            inside = np.zeros(len(self.stroke_t), dtype=bool)
            for start, end in windows:
                inside |= (self.stroke_t >= start) & (self.stroke_t <= end)
        if inside.sum() < 8:
            return float("nan"), 0.0
        return stroke_gain(self.stroke_request_nm[inside], self.stroke_torque_nm[inside])

    @property
    def by_request(self) -> bool:
        """Whether the drive is the recorded T_ecu (else the measured torque, which already
        carries the vehicle's combustion variation and its engine gain: the model then adds no
        variation and takes K = 1)."""
        return self.mode == RECORDED_REQUEST

    @property
    def speed_mean_rpm(self) -> float:
        """Mean recorded speed, rpm."""
        return float(np.mean(self.speed_rpm))

    def controller(self) -> IdleController:
        """The model's speed-tracking controller: the stroke takes the request as it stands at
        its start (the drive's values are already latched as the vehicle's ECU latched them)."""
        kp = NOMINAL_INERTIA * 2 * math.pi * TRACK_BANDWIDTH_HZ / RPM_PER_RAD_S
        return IdleController(
            setpoint_rpm=self.speed_mean_rpm,
            kp_nm_per_rpm=kp,
            ki_nm_per_rpm_s=kp * 2 * math.pi * TRACK_INTEGRAL_HZ,
            request_min_nm=-1e3,
            request_max_nm=1e3,
            latch_samples=0,
            error_tau_s=1 / (2 * math.pi * TRACK_FILTER_HZ),
        )

    def event(self, t_s: float) -> int:
        """The crank event nearest to a recording time."""
        i = int(np.searchsorted(self.t, t_s))
        if i > 0 and (i == len(self.t) or t_s - self.t[i - 1] <= self.t[i] - t_s):
            i -= 1
        return i

    def start_event(self, wanted_s: float) -> int:
        """The last event at which a stroke starts at or before ``wanted_s`` (the first such
        event if none)."""
        e = self.event(wanted_s)
        e -= (e - self.first_stroke) % SAMPLES_PER_STROKE
        return max(e, self.first_stroke % SAMPLES_PER_STROKE)

    def reference(self, start: int) -> np.ndarray:
        """The model's reference speed from a start event: the recorded speed at every event
        after it, rpm."""
        first = start + 1
        return self.speed_rpm[first:] if first < len(self.t) else self.speed_rpm[-1:]

    def model_event(self, event: int, start: int) -> int:
        """The model's speed sample (row of its output) at a recorded crank event, for a
        replay from ``start``."""
        return event - start - 1

    def cylinder_offset(self, start: int) -> int:
        """Where a replay from ``start`` (an event at which a stroke starts) has its first stroke
        in the firing order, for the kernel's ``cylinder_imbalance`` to act on the recording's
        :attr:`odd_stroke` (:class:`dtid.simulator.kernel.Loop`)."""
        first = (start - self.first_stroke) // SAMPLES_PER_STROKE
        return int((first - self.odd_stroke) % N_CYL)

    def drive(self, start: int) -> np.ndarray:
        """The request of each stroke from a start event on, N*m: the recorded request with the
        recording's own combustion variation where it is known (:attr:`variation_nm`)."""
        drive = self.drive_nm[start::SAMPLES_PER_STROKE]
        if len(self.variation_nm):
            drive = drive + self.variation_nm[start::SAMPLES_PER_STROKE]
        return drive

    def as_dict(self) -> dict[str, object]:
        """The JSON entry ``idle_loop`` of a recording."""
        controller = self.controller()
        return {
            "mode": self.mode,
            "closed_by": (
                "the recorded torque request T_ecu drives the model's engine stroke by stroke; "
                "the vehicle's idle controller, its delays and its latch are in it"
                if self.by_request
                else "no torque request on the bus: the measured mean torque drives the model's "
                "engine stroke by stroke (its sensor noise counts as excitation; the model adds "
                "no combustion variation; K does not enter)"
            ),
            "latch_events": self.latch_samples,
            "latch_gain": self.gain,
            "engine_gain": json_number(self.engine_gain()[0]),
            "latch_residual_nm": self.residual_nm,
            "engine_lag_s": self.lag_s,
            "combustion_variation": json_number(self.combustion_variation),
            "torque_noise_nm": json_number(self.torque_noise_nm),
            "speed_noise_rpm": json_number(self.speed_noise_rpm),
            "variation_left": self.variation_left,
            "tracking_bandwidth_hz": TRACK_BANDWIDTH_HZ,
            "tracking_kp_nm_per_rpm": controller.kp_nm_per_rpm,
            "tracking_ki_nm_per_rpm_s": controller.ki_nm_per_rpm_s,
        }


def idle_loop(data: TestData, lag_s: float = 0.0) -> IdleLoop:
    """The recording on its crank-event grid, with the drive of its model: by its torque
    request if it has one, else by its measured mean torque (see the module notes).

    ``lag_s`` (s) says the engine lags behind its request (``[model] engine_lag = "measured"``:
    the lag T/T_ecu shows, which brackets it): the lag is then fitted to the strokes
    themselves (:func:`stroke_lag`), and the latch, K, the combustion variation and the sensor
    noise to the lagged latched request (:func:`stroke_lagged`), which a lagging engine's
    strokes follow; read at once, a 44-61 ms lag made K 0.40-0.45 for 0.91-0.96 and counted the
    lag's misfit as sensor noise of 2.4-2.8 N*m for 0.2-0.4 (blind-trial cases 7 and 12).

    Raises
    ------
    AnalysisError
        If the recording has too few speed or torque samples for a crank-event grid.
    """
    if len(data.speed) < 8 or len(data.mean_torque) < 4:
        raise AnalysisError("too few speed or mean-torque samples to repeat the test in the model")
    t, speed = _event_grid(data.speed)
    noise_rpm = speed_noise_rpm(speed, 1.0 / float(np.median(np.diff(t))))
    test = data.test_torque.held(t, before=0.0)
    strokes = _nearest(t, data.mean_torque.t)
    if data.torque_request is not None and len(data.torque_request) > 1:
        request = _per_event(data.torque_request, t)
        report_t = data.mean_torque.t
        if lag_s > 0:
            lag_s = stroke_lag(request, strokes, data.mean_torque.value, report_t, lag_s)
        lag, gain, residual = latch(request, strokes, data.mean_torque.value, report_t, lag_s)
        at = strokes - lag
        ok = (at >= 0) & (at < len(request))
        taken = stroke_lagged(request[at[ok]], report_t[ok], lag_s)
        variation, noise = variation_and_noise(gain * taken, data.mean_torque.value[ok])
        first = int(strokes[0]) - lag
        number = np.rint((at[ok] - first) / SAMPLES_PER_STROKE).astype(np.int64)
        own = np.zeros(len(request))
        left = 1.0
        if lag_s <= 0:  # a lagging engine's strokes are not read one by one
            known, left = recorded_variation(
                gain * taken,
                data.mean_torque.value[ok],
                variation,
                noise,
                number % N_CYL,
                gain * _earlier_requests(request, at[ok]),
            )
            own[at[ok]] = known / gain
        factors = stroke_factors(number, data.mean_torque.value[ok], taken)[0]
        return IdleLoop(
            RECORDED_REQUEST,
            t,
            speed,
            test,
            request,
            first,
            lag,
            gain,
            residual,
            variation,
            noise,
            data.mean_torque.t[ok],
            taken,
            data.mean_torque.value[ok],
            number,
            odd_place(factors),
            lag_s,
            noise_rpm,
            own,
            left,
        )
    # a stroke's mean torque is known, and reported, when the stroke ends: the stroke started
    # SAMPLES_PER_STROKE events before its report
    measured = _per_event(data.mean_torque, t)
    starting = np.append(measured[SAMPLES_PER_STROKE:], np.full(SAMPLES_PER_STROKE, measured[-1]))
    first = int(strokes[0]) % SAMPLES_PER_STROKE
    return IdleLoop(
        MEASURED_TORQUE,
        t,
        speed,
        test,
        starting,
        first,
        SAMPLES_PER_STROKE,
        speed_noise_rpm=noise_rpm,
    )


def latch(
    request: np.ndarray,
    strokes: np.ndarray,
    torque: np.ndarray,
    report_t: np.ndarray | None = None,
    lag_s: float = 0.0,
) -> tuple[int, float, float]:
    """Which request each stroke took: the lag, in crank events, from the request to the
    stroke's mean-torque report that explains the measured torque best (eq. 3: T_m = K T_ecu).

    Parameters
    ----------
    request
        T_ecu at each crank event, N*m.
    strokes
        The crank event of each mean-torque report.
    torque
        The reported mean torques, N*m.
    report_t, lag_s
        The reports' times, s, and an engine lag to read the requests through, s
        (:func:`stroke_lagged`; 0: none).

    Returns
    -------
    tuple
        The lag (events, from :data:`LATCH_LAGS`), the least-squares K at it and the RMS
        residual, N*m.
    """
    best = (0, 1.0, math.inf)
    for lag in LATCH_LAGS:
        at = strokes - lag
        ok = (at >= 0) & (at < len(request))
        x, y = request[at[ok]], torque[ok]
        if lag_s > 0 and report_t is not None:
            x = stroke_lagged(x, report_t[ok], lag_s)
        if len(x) < 8 or not np.dot(x, x) > 0:
            continue
        gain = float(np.dot(x, y) / np.dot(x, x))
        residual = float(np.sqrt(np.mean((y - gain * x) ** 2)))
        if residual < best[2]:
            best = (lag, gain, residual)
    return best


def stroke_lag(
    request: np.ndarray,
    strokes: np.ndarray,
    torque: np.ndarray,
    report_t: np.ndarray,
    guess_s: float,
) -> float:
    """The engine's lag behind its request, s, fitted to the strokes: the time constant of
    :func:`stroke_lagged` (the ``torque_lag`` mechanism's own recurrence, as the model's engine
    delivers it) whose lagged latched request explains the measured mean torques best
    (:func:`latch`'s residual, the latch free), within a factor :data:`LAG_BRACKET` of
    ``guess_s``.

    The strokes' torque and the requests they took are the lag's own data: the fit sees neither
    the speed sensor nor the strokes' aliases, which move T/T_ecu's frequency-domain fit
    (:func:`dtid.identification.frf.engine_lag.engine_lag`, the guess): on a clean reference
    recording lagging 50 ms and 120 ms a tooth-timer speed sensor made that fit 0.0528 and
    0.1217 s and eq. (9)'s 0.0488 and 0.1156 s; this fit gives 0.0494 and 0.1184 s with
    either (2026-12-03, ``tests/test_idle_loop.py``).

    Parameters
    ----------
    request, strokes, torque, report_t
        As :func:`latch`.
    guess_s
        A first estimate of the lag, s (positive).

    Returns
    -------
    float
        The lag, s.
    """

    def residual(log_tau: float) -> float:
        return latch(request, strokes, torque, report_t, math.exp(log_tau))[2]

    centre = math.log(guess_s)
    span = math.log(LAG_BRACKET)
    grid = np.linspace(centre - span, centre + span, LAG_GRID)
    values = [residual(x) for x in grid]
    best = int(np.argmin(values))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, LAG_GRID - 1)]
    found = optimize.minimize_scalar(
        residual, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3 * (grid[1] - grid[0])}
    )
    return float(math.exp(found.x if found.fun <= values[best] else grid[best]))


def stroke_lagged(taken: np.ndarray, report_t: np.ndarray, lag_s: float) -> np.ndarray:
    """The requests the strokes took, through the ``torque_lag`` mechanism's recurrence: each
    stroke the delivered torque moves towards its request by 1 - exp(-stroke / lag_s), the
    stroke the time since the report before (as :mod:`dtid.simulator.kernel` advances it).

    Parameters
    ----------
    taken
        The request each reported stroke took, N*m.
    report_t
        The reports' times, s.
    lag_s
        The lag's time constant, s (0 or less: the requests unchanged).

    Returns
    -------
    numpy.ndarray
        The lagged requests, N*m.
    """
    if lag_s <= 0 or len(taken) == 0:
        return taken
    stroke = np.diff(report_t, prepend=report_t[0] - np.median(np.diff(report_t)))
    step = 1.0 - np.exp(-stroke / lag_s)
    out = np.empty_like(taken, dtype=np.float64)
    state = float(taken[0])
    for i, (value, fraction) in enumerate(zip(taken, step, strict=True)):
        state += (value - state) * fraction
        out[i] = state
    return out


def stroke_gain(latched: np.ndarray, torque: np.ndarray) -> tuple[float, float]:
    """K of eq. (3), T_m = K T_ecu, read stroke by stroke: the least-squares slope of each
    stroke's measured mean torque on the request it took, with an offset.

    Eq. (24) takes K as the mean of |G_ENG| instead, but that mean is not K: the strokes sample
    the request and hold it after the ECU's latch, so |G_ENG| is K times a transfer that depends
    on the vehicle's timing and controller. On the twenty random vehicles of
    ``benchmarks/diagnosis_calibration.py`` eq. (24) was off by 1.2 % RMS (-3.9 % on one with a
    PID controller, +2.3 % on one with a two-event output delay), this slope, over the strokes
    of the identifying runs, by 0.16 % RMS (at most 0.37 %); on the independent recordings by
    +0.08 and -0.06 % where eq. (24) gave -0.5 and -0.9 % (the model's own |G_ENG| matched to
    theirs: +0.09 and +0.05 %). The offset keeps K the request's gain where the request and the
    indicated torque differ by a constant (a request that leaves out part of the friction); the
    test chirp and the controller's action vary the request enough for the slope.

    It is reported (``idle_loop.engine_gain``), and held by the search only where eq. (24)'s
    is far from it (:func:`dtid.identification.gain_choice.held_gain`): with it the truth fits
    better (the independent recordings' and 13 of the randomised trial's 20), but the searches
    do not end better (175 against 178 of the trial's 200 targets, a difference within the
    friction's scatter; docs/accuracy.md).

    Parameters
    ----------
    latched
        The request each stroke took, N*m.
    torque
        Each stroke's measured mean torque, N*m.

    Returns
    -------
    tuple of float
        The slope K, 1, and its weight among recordings: the request's sum of squared
        deviations from its mean, N*m^2.
    """
    spread = latched - latched.mean()
    weight = float(np.dot(spread, spread))
    return float(np.dot(spread, torque - torque.mean()) / weight), weight


def _event_grid(speed: Series) -> tuple[np.ndarray, np.ndarray]:
    """The speed's crank events, lost ones filled in (times evenly across a gap, speed
    interpolated linearly): times, s, and speeds, rpm."""
    t, value = speed.t, speed.value
    keep = np.concatenate(([True], np.diff(t) > 0))
    t, value = t[keep], value[keep]
    interval = float(np.median(np.diff(t)))
    missing = np.maximum(np.rint(np.diff(t) / interval).astype(np.int64) - 1, 0)
    if not missing.any():
        return t, value
    counts = np.concatenate(([0], np.cumsum(missing + 1)))
    grid = np.interp(np.arange(counts[-1] + 1), counts, t)
    return grid, np.interp(grid, t, value)


def _earlier_requests(request: np.ndarray, latched: np.ndarray) -> np.ndarray:
    """(strokes, SYSTEMATIC_TAPS - 1) the request latched 1, 2, ... strokes before each stroke,
    read off the crank-event grid (so a lost torque report shifts nothing), N*m; NaN before
    the recording's first event."""
    lags = SAMPLES_PER_STROKE * np.arange(1, SYSTEMATIC_TAPS)
    at = latched[:, None] - lags[None, :]
    return np.where(at >= 0, request[np.maximum(at, 0)], np.nan)


def _nearest(grid: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Index of the grid time nearest to each time."""
    i = np.clip(np.searchsorted(grid, times), 1, len(grid) - 1)
    return np.where(times - grid[i - 1] <= grid[i] - times, i - 1, i)


def _per_event(series: Series, grid: np.ndarray) -> np.ndarray:
    """A crank-synchronous signal on the event grid: each sample at its nearest event, events
    without one holding the value before (the first sample before it)."""
    index = _nearest(grid, series.t)
    out = np.full(len(grid), np.nan)
    out[index] = series.value
    filled = np.where(np.isfinite(out), np.arange(len(grid)), 0)
    np.maximum.accumulate(filled, out=filled)
    out = out[filled]
    out[~np.isfinite(out)] = series.value[0]
    return out
