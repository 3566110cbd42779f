"""The shortest chirp test that meets every precision target (``dtid plan``).

A design is two identifying amplitudes, each chirped a number of times, with one chirp duration
and band, and the validation chirp after them. Its predicted covariance is eq. (17)'s
linearised sandwich (:mod:`dtid.identification.planning.information`) with each run's residual
variance scaled by the time the sweep spends per hertz: a chirp twice as long, or over half the
band, puts twice the excitation into each bin, and the Welch estimate's variance halves; a
repeated run is a second term of eq. (17) (the runs are fitted jointly, as ``dtid identify``
fits every run at an identifying amplitude). The search enumerates designs and keeps the one
with the shortest test time that meets every target; when none within the limits does, the one
that comes closest, with what each unmet target would need.

With vehicles around the prior (:mod:`dtid.identification.planning.spread`) a design must
meet every target at each of them; when none within the limits does, the closest is the one
whose vehicles' shortfalls (each vehicle's largest precision over target) have the smallest
geometric mean: the typical vehicle's, not the single hardest one's, which would spend the
test on one vehicle's friction.

Why two identifying amplitudes: eq. (23) needs two to split a stiffness from its free play, a
third adds less than repeating the better two (at the reference vehicle, no three amplitudes
sharing the recommended test's 23 chirps come closer to the targets), and
``dtid identify``'s default choice (the two largest amplitudes identify, the smaller validate)
then reads the planned test without options.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from dtid.acquisition.config import SafetyConfig
from dtid.acquisition.plan import MAX_TEST_S, TestPlan, in_rounds
from dtid.errors import AnalysisError, ConfigError
from dtid.identification.frf.closed_loop import sweep_edge_hz
from dtid.identification.frf.runs import ChirpRun
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.planning.confirmation import IntervalCheck, interval_checks
from dtid.identification.planning.information import (
    DEFAULT_SEEDS,
    RESOLUTION_HZ,
    LevelInformation,
    PlanInformation,
    measure_information,
)
from dtid.identification.planning.spread import (
    DEFAULT_VEHICLES,
    DRIVETRAIN,
    MAX_SPREAD,
    RECORDED,
    describe,
    half_widths,
    spread_priors,
)
from dtid.identification.search.parameterization import (
    PASSENGER_CAR_RANGES,
    THETA_NAMES,
    theta_from_parameters,
)
from dtid.identification.search.runs import AMPLITUDE_MATCH, amplitude_levels, split_runs
from dtid.simulator.angle_grid import N_CYL
from dtid.simulator.parameters import UNITS, DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions
from dtid.simulator.vehicle_data import VehicleData

PRECISION_NAMES: tuple[str, ...] = ("J1", "J2", "J3", *THETA_NAMES)
"""Parameters whose precision is predicted: the inertias and setup-4's ten."""
DEFAULT_TARGETS_PERCENT: dict[str, float] = {
    **dict.fromkeys(("J1", "J2", "J3", "J_sum", "x1", "x12", "c12", "c23", "eps12", "eps23"), 5.0),
    **dict.fromkeys(("d12", "d23", "Tc12"), 20.0),
}
"""Targets, % of the value at :data:`SIGMAS` standard deviations: inertias, mass ratios,
stiffnesses and free plays 5 %, dampings and the friction 20 %."""
SIGMAS = 2.0
"""A target is met when this many predicted standard deviations lie within it."""
DURATIONS_S: tuple[float, ...] = (30.0, 45.0, 60.0, 90.0, 120.0)
"""Chirp durations the search tries, s (a run longer than 120 s is a repeat instead: the same
information, and a drift of the idle between runs shows as scatter rather than bias)."""
BANDS_HZ: tuple[tuple[float, float], ...] = ((1.0, 15.0), (2.0, 15.0), (1.0, 12.0), (2.0, 12.0))
"""Sweep bands the search tries, Hz (those inside the measured chirps' band); where the mean
torque's Nyquist frequency is lower than a band's top, the band ends just below it instead (a
sweep above it excites what the FRF cannot see: :func:`bands`)."""
MAX_REPEATS = 30
"""Most chirps the search puts at one amplitude."""
DEFAULT_MAX_TIME_S = 1800.0
"""Default limit of the whole test's duration, s: half an hour at idle, in which an engine's
oil and coolant temperatures (and with them its friction) stay close to constant."""
VALIDATION_NM = 2.0
"""The validation chirp's amplitude, N*m (the paper's A3)."""
PRIOR_FLOOR = 0.05
"""Least prior value planned for, as a fraction of the top of the parameter's passenger-car
range (:data:`dtid.identification.search.parameterization.PASSENGER_CAR_RANGES`): a prior of zero
(a first test that found no friction, say) has no relative precision to plan for, and its
information matrix is singular there."""
CANDIDATE_AMPLITUDES_NM = (2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 25.0, 30.0)
"""Amplitudes the search chooses from (those up to the cap), N*m."""


@dataclass(frozen=True)
class Design:
    """A chirp test as the search describes it.

    Attributes
    ----------
    amplitudes_nm
        The identifying amplitudes, ascending, N*m.
    repeats
        Chirps at each amplitude.
    duration_s
        T_D of every chirp, s.
    f1_hz, f2_hz
        The sweep's start and end frequency, Hz.
    validation_nm
        The validation chirp's amplitude after them, N*m; 0 for none.
    settle_s, pause_s
        Idle before the first chirp and between chirps, s.
    """

    amplitudes_nm: tuple[float, ...]
    repeats: tuple[int, ...]
    duration_s: float
    f1_hz: float
    f2_hz: float
    validation_nm: float = VALIDATION_NM
    settle_s: float = 3.0
    pause_s: float = 3.0

    def test_plan(self) -> TestPlan:
        """The daemon's and the simulator's plan: the amplitudes in rounds
        (:func:`dtid.acquisition.plan.in_rounds`), then the validation chirp."""
        return TestPlan(
            amplitudes_nm=in_rounds(self.amplitudes_nm, self.repeats),
            validation_nm=self.validation_nm,
            f1_hz=self.f1_hz,
            f2_hz=self.f2_hz,
            duration_s=self.duration_s,
            settle_s=self.settle_s,
            pause_s=self.pause_s,
        )

    @property
    def test_time_s(self) -> float:
        """Duration of the whole test: settle, chirps, pauses and the validation chirp, s."""
        chirps = sum(self.repeats) + (1 if self.validation_nm else 0)
        return self.settle_s + chirps * (self.duration_s + self.pause_s)

    def as_dict(self, setpoint_rpm: float) -> dict[str, object]:
        """The ``plan`` entry of ``dtid plan``'s JSON."""
        return {
            "amplitudes_nm": list(self.amplitudes_nm),
            "repeats": list(self.repeats),
            "duration_s": self.duration_s,
            "f1_hz": self.f1_hz,
            "f2_hz": self.f2_hz,
            "validation_nm": self.validation_nm,
            "settle_s": self.settle_s,
            "pause_s": self.pause_s,
            "setpoint_rpm": round(setpoint_rpm, 1),
            "sweep": "linear",
        }


PAPER_DESIGN = Design((5.0, 10.0), (1, 1), 60.0, 1.0, 15.0)
"""The paper's test: one 60 s chirp from 1 to 15 Hz at 5 and at 10 N*m, 2 N*m validates."""


def bands(info: PlanInformation) -> list[tuple[float, float]]:
    """The sweep bands the search tries at the prior's idle speed (:data:`BANDS_HZ`), Hz."""
    nyquist = 0.5 * info.setpoint_rpm / 60.0 * N_CYL / 2  # once per stroke
    top = math.floor(2 * 0.98 * nyquist) / 2
    candidates = [(f1, f2) for f1, f2 in BANDS_HZ if f2 <= top]
    if top < max(f2 for _, f2 in BANDS_HZ):
        candidates += [(f1, top) for f1 in sorted({f1 for f1, _ in BANDS_HZ})]
    reference = info.reference
    return sorted(
        {(f1, f2) for f1, f2 in candidates if f1 >= reference.f1_hz and f2 <= reference.f2_hz}
    )


def parse_targets(items: Sequence[str]) -> dict[str, float]:
    """``NAME=PERCENT`` items over the default targets; ``NAME=0`` drops a target.

    Raises
    ------
    ConfigError
        On an unknown name or a percentage that is not a non-negative number.
    """
    targets = dict(DEFAULT_TARGETS_PERCENT)
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in PRECISION_NAMES:
            raise ConfigError(
                f"--target {item!r}: expected NAME=PERCENT with NAME one of "
                f"{', '.join(PRECISION_NAMES)} (e.g. eps23=10)"
            )
        try:
            percent = float(value)
        except ValueError:
            percent = math.nan
        if not (math.isfinite(percent) and percent >= 0):
            raise ConfigError(f"--target {item!r}: the percentage must be a number >= 0")
        if percent == 0:
            targets.pop(name, None)
        else:
            targets[name] = percent
    return targets


@dataclass(frozen=True)
class _Block:
    """One run's terms of the sandwich: w J^T J and w^2 J^T Sigma J (SI units)."""

    a: np.ndarray
    b: np.ndarray


def _block(
    info: PlanInformation, level: LevelInformation, duration: float, band: tuple[float, float]
) -> _Block | None:
    f1, f2 = band
    edge = sweep_edge_hz(ChirpRun(0.0, duration, level.amplitude_nm, f1, f2), RESOLUTION_HZ)
    rows = (level.frequency_hz >= f1 + edge - 1e-9) & (level.frequency_hz <= f2 - edge + 1e-9)
    if rows.sum() < len(THETA_NAMES):
        return None
    reference = info.reference
    time_per_hz = duration / (f2 - f1)
    scale = reference.duration_s / (reference.f2_hz - reference.f1_hz) / time_per_hz
    jac = level.jacobian_db[rows]
    measured = level.drv_db[rows]
    spread = float(np.linalg.norm(measured - measured.mean()))
    sigma = level.covariance(rows) * scale
    weight = 1.0 / (spread * math.sqrt(float(np.trace(sigma))))
    return _Block(weight * jac.T @ jac, weight**2 * jac.T @ sigma @ jac)


def _precision_gradient(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The :data:`PRECISION_NAMES` values at setup-4 ``values`` and their gradient,
    (13, 10): the inertias J1, J2, J3 from J_sum, x1, x12, then setup 4's own."""
    j_sum, x1, x12 = (values[THETA_NAMES.index(n)] for n in ("J_sum", "x1", "x12"))
    inertias = np.array([j_sum * x1 * x12, j_sum * (1 - x1) * x12, j_sum * (1 - x12)])
    grads = np.zeros((3, len(THETA_NAMES)))  # d(J1, J2, J3) / d(J_sum, x1, x12)
    grads[:, :3] = [
        [x1 * x12, j_sum * x12, j_sum * x1],
        [(1 - x1) * x12, -j_sum * x12, j_sum * (1 - x1)],
        [1 - x12, 0.0, -j_sum],
    ]
    return np.concatenate([inertias, values]), np.vstack([grads, np.eye(len(THETA_NAMES))])


def _relative_sd(info: PlanInformation, covariance: np.ndarray) -> np.ndarray:
    """(..., len(PRECISION_NAMES)) relative standard deviations from setup-4 covariances."""
    values, grads = _precision_gradient(info.values)
    variance = np.einsum("ki,...ij,kj->...k", grads, covariance, grads)
    return np.sqrt(np.maximum(variance, 0.0)) / values


def _sandwich(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    inverse = np.linalg.inv(a)
    return inverse @ b @ inverse


def information(info: PlanInformation, designs: Sequence[Design]) -> tuple[np.ndarray, np.ndarray]:
    """The sandwich's two sums over every run of the designs: sum w J^T J, sum w^2 J^T Sigma J.
    A run at an amplitude whose chirp gives no FRF on this vehicle
    (:attr:`~dtid.identification.planning.information.LevelInformation.unusable`) adds nothing.

    Raises
    ------
    ConfigError
        If an amplitude of a design was not measured, or its band leaves too few bins.
    """
    a = np.zeros((len(THETA_NAMES), len(THETA_NAMES)))
    b = np.zeros_like(a)
    for design in designs:
        for amplitude, repeats in zip(design.amplitudes_nm, design.repeats, strict=True):
            level = _level(info, amplitude)
            if level.unusable:  # such a chirp gives no FRF on this vehicle: no information
                continue
            block = _block(info, level, design.duration_s, (design.f1_hz, design.f2_hz))
            if block is None:
                raise ConfigError(
                    f"a {design.duration_s:g} s chirp over {design.f1_hz:g}-{design.f2_hz:g} Hz "
                    "leaves too few frequency bins to identify ten parameters"
                )
            a += repeats * block.a
            b += repeats * block.b
    return a, b


def predict(
    info: PlanInformation, design: Design | None, recorded: Sequence[Design] = ()
) -> dict[str, float]:
    """Each parameter's predicted relative standard deviation (1 sigma) for a design, after the
    runs already ``recorded`` (identified together with them); ``design`` None: those alone.

    Raises
    ------
    ConfigError
        As :func:`information`.
    """
    a, b = information(info, [*recorded, *([design] if design else [])])
    sd = _relative_sd(info, _sandwich(a, b))
    return {name: float(value) for name, value in zip(PRECISION_NAMES, sd, strict=True)}


def predict_worst(
    info: PlanInformation, design: Design | None, recorded: Sequence[Design] = ()
) -> dict[str, float]:
    """As :func:`predict`, each parameter's worst over the prior and the vehicles around it
    (:attr:`PlanInformation.around`); the prior's alone when there are none."""
    each = [predict(vehicle, design, recorded) for vehicle in info.vehicles]
    return {name: max(p[name] for p in each) for name in PRECISION_NAMES}


def _level(info: PlanInformation, amplitude: float) -> LevelInformation:
    for level in info.levels:
        if abs(level.amplitude_nm - amplitude) <= AMPLITUDE_MATCH * amplitude:
            return level
    raise ConfigError(
        f"no information measured at {amplitude:g} N*m (measured: "
        f"{', '.join(f'{a:g}' for a in info.amplitudes_nm)} N*m)"
    )


@dataclass(frozen=True)
class Unmet:
    """A target the recommended design does not reach.

    Attributes
    ----------
    name
        The parameter.
    target_percent, predicted_percent
        The target and the design's prediction, both at :data:`SIGMAS` sigma, %.
    reason
        Why, and what would meet it.
    """

    name: str
    target_percent: float
    predicted_percent: float
    reason: str

    def as_dict(self) -> dict[str, object]:
        """The JSON entry."""
        return {
            "name": self.name,
            "target_percent": self.target_percent,
            "predicted_percent": round(self.predicted_percent, 2),
            "reason": self.reason,
        }


@dataclass(frozen=True)
class Recommendation:
    """The search's answer.

    Attributes
    ----------
    design
        The shortest design meeting every target, or the closest within the limits; None when
        the runs already recorded meet every target.
    per_vehicle
        Its predicted relative standard deviations (1 sigma), by :data:`PRECISION_NAMES`, with
        the recorded runs: at the prior, then at each vehicle around it
        (:attr:`PlanInformation.vehicles`).
    unmet
        The targets it does not reach (empty when it meets them all).
    excluded
        Candidate amplitudes left out, each with the reason.
    designs_tried
        Designs evaluated.
    recorded
        The runs recorded before, counted in (a follow-up's; empty otherwise).
    intervals
        The recorded runs' profile intervals against the targets
        (:mod:`~dtid.identification.planning.confirmation`; empty without an identification);
        a target they do not confirm is unmet whatever the prediction says.
    """

    design: Design | None
    per_vehicle: tuple[dict[str, float], ...]
    unmet: tuple[Unmet, ...]
    excluded: dict[float, str]
    designs_tried: int
    recorded: tuple[Design, ...] = ()
    intervals: tuple[IntervalCheck, ...] = ()

    @property
    def unconfirmed(self) -> tuple[IntervalCheck, ...]:
        """The targets whose profile intervals do not confirm them."""
        return tuple(c for c in self.intervals if not c.confirms)

    @property
    def meets_targets(self) -> bool:
        """Whether every target is met: predicted, and confirmed by the intervals given."""
        return not self.unmet and not self.unconfirmed

    @property
    def precision(self) -> dict[str, float]:
        """Each parameter's worst predicted relative standard deviation over the vehicles."""
        return {n: max(p[n] for p in self.per_vehicle) for n in PRECISION_NAMES}


VALIDATION_REASON = "the validation chirp's amplitude (it must not identify)"
"""Why the validation amplitude is no candidate (:func:`request_exclusion`)."""


def request_exclusion(
    amplitude_nm: float,
    max_amplitude_nm: float,
    validation_nm: float,
    held_out_nm: Sequence[float] = (),
) -> str:
    """Why an amplitude may not identify by the request alone, before anything is simulated.

    Parameters
    ----------
    amplitude_nm
        The candidate amplitude, N*m.
    max_amplitude_nm, validation_nm, held_out_nm
        As :func:`recommend`'s, N*m.

    Returns
    -------
    str
        The reason, or ``""`` when the request allows it.
    """
    a = amplitude_nm
    if a > max_amplitude_nm * (1 + 1e-9):
        return f"above the amplitude cap of {max_amplitude_nm:g} N*m"
    if validation_nm and abs(a - validation_nm) <= AMPLITUDE_MATCH * validation_nm:
        return VALIDATION_REASON
    if validation_nm and a < validation_nm:
        return "below the validation chirp's (the two largest amplitudes identify)"
    if any(abs(a - h) <= AMPLITUDE_MATCH * h for h in held_out_nm):
        return "the recorded tests' validation amplitude (it must stay held out)"
    return ""


def _nothing_fits(max_time_s: float, validation_nm: float) -> ConfigError:
    return ConfigError(
        f"no test fits in --max-time {max_time_s:g} s: the shortest (one "
        f"{min(DURATIONS_S):g} s chirp per amplitude"
        f"{', and the validation chirp' if validation_nm else ''}) lasts "
        f"{shortest_test_s(validation_nm):g} s"
    )


def _too_few_amplitudes(excluded: Mapping[float, str]) -> ConfigError:
    return ConfigError(
        "fewer than two amplitudes are allowed ("
        + "; ".join(f"{a:g} N*m: {why}" for a, why in excluded.items())
        + "); two identify a stiffness and its free play (eq. 23): raise --max-amplitude"
    )


def recommend(
    info: PlanInformation,
    targets: Mapping[str, float],
    max_amplitude_nm: float,
    max_time_s: float = DEFAULT_MAX_TIME_S,
    validation_nm: float = VALIDATION_NM,
    speed_window_rpm: float = SafetyConfig().speed_window_rpm,
    recorded: Sequence[Design] = (),
    held_out_nm: Sequence[float] = (),
) -> Recommendation:
    """Search the shortest design that meets every target (see the module notes).

    With runs already ``recorded`` (identified together with the new ones: a follow-up test),
    the search counts their information in and the new test's time only; when they meet every
    target alone, no design is recommended.

    Parameters
    ----------
    info
        The candidate amplitudes' information, and at the vehicles around the prior
        (:attr:`PlanInformation.around`), each of which must meet every target.
    targets
        Target per parameter name, % at :data:`SIGMAS` sigma.
    max_amplitude_nm
        Largest amplitude allowed, N*m.
    max_time_s
        Longest whole test allowed, s.
    validation_nm
        The validation chirp's amplitude, N*m (0: none); it does not identify, so it is not a
        candidate.
    speed_window_rpm
        The daemon's safety window around the idle speed: an amplitude whose chirp took the
        speed further at the prior (or a vehicle around it) is left out, as is one whose chirp
        gave no FRF there.
    recorded
        The identifying runs recorded so far, each a design of its own.
    held_out_nm
        The recorded tests' validation amplitudes, N*m: not candidates either (a new run there
        would make them identify).

    Raises
    ------
    ConfigError
        If fewer than two amplitudes are allowed, or no design fits in ``max_time_s``.
    """
    vehicles = info.vehicles
    excluded: dict[float, str] = {}
    allowed = []
    where = "the prior" if len(vehicles) == 1 else "the prior or a vehicle around it"
    for k, level in enumerate(info.levels):
        a = level.amplitude_nm
        excursion = max(vehicle.levels[k].speed_excursion_rpm for vehicle in vehicles)
        refused = next((v.levels[k].unusable for v in vehicles if v.levels[k].unusable), "")
        if why := request_exclusion(a, max_amplitude_nm, validation_nm, held_out_nm):
            excluded[a] = why
            if why == VALIDATION_REASON and refused:
                excluded[a] += (
                    f"; at {where} its chirp gave no FRF, so the test may have nothing to "
                    f"validate on: {refused}"
                )
        elif refused:
            excluded[a] = f"its chirp gave no FRF at {where}: {refused}"
        elif excursion > speed_window_rpm:
            excluded[a] = (
                f"its chirp took the speed {excursion:.0f} rpm from idle at {where}, outside "
                f"the {speed_window_rpm:g} rpm safety window"
            )
        else:
            allowed.append(k)
    if len(allowed) < 2:
        raise _too_few_amplitudes(excluded)
    names = [n for n in PRECISION_NAMES if n in targets]
    index = [PRECISION_NAMES.index(n) for n in names]
    needed = np.array([targets[n] / 100.0 / SIGMAS for n in names])
    recorded = tuple(recorded)
    before = [information(vehicle, recorded) for vehicle in vehicles]
    if recorded:
        so_far = tuple(predict(vehicle, None, recorded) for vehicle in vehicles)
        if all(
            max(p[n] for p in so_far) <= target for n, target in zip(names, needed, strict=True)
        ):
            return Recommendation(None, so_far, (), excluded, 0, recorded)
    counts = np.array(list(itertools.product(range(1, MAX_REPEATS + 1), repeat=2)))
    best: tuple[tuple[float, float], Design] | None = None
    closest: tuple[float, Design] | None = None
    tried = 0
    for low, high in itertools.combinations(allowed, 2):
        for duration, band in itertools.product(DURATIONS_S, bands(info)):
            ratios = _ratios(vehicles, before, (low, high), duration, band, counts, index, needed)
            if ratios is None:
                continue
            worst = np.max(ratios, axis=0)
            typical = np.exp(np.mean(np.log(ratios), axis=0))
            for (n_low, n_high), ratio, shortfall in zip(counts, worst, typical, strict=True):
                design = Design(
                    (info.levels[low].amplitude_nm, info.levels[high].amplitude_nm),
                    (int(n_low), int(n_high)),
                    duration,
                    *band,
                    validation_nm=validation_nm,
                )
                if design.test_time_s > max_time_s:
                    continue
                tried += 1
                if ratio <= 1.0:
                    key = (design.test_time_s, float(ratio))
                    if best is None or key < best[0]:
                        best = (key, design)
                # a prediction that is not finite (information the simulator could not
                # measure) can neither meet a target (NaN <= 1 is false) nor come closest
                if np.isfinite(shortfall) and (closest is None or shortfall < closest[0]):
                    closest = (float(shortfall), design)
    if closest is None and tried:
        raise AnalysisError(
            "no test's precision could be predicted: the information measured at the prior "
            "(or at a vehicle around it) is not finite, so a parameter set there could not be "
            "simulated; plan with --spread 0, or at another --prior"
        )
    if closest is None:
        raise _nothing_fits(max_time_s, validation_nm)
    design = best[1] if best is not None else closest[1]
    per_vehicle = tuple(predict(vehicle, design, recorded) for vehicle in vehicles)
    unmet = tuple(
        _unmet(name, targets[name], per_vehicle, design, max_time_s, recorded, info.spread)
        for name in names
        if SIGMAS * 100.0 * max(p[name] for p in per_vehicle) > targets[name]
    )
    return Recommendation(design, per_vehicle, unmet, excluded, tried, recorded)


def _ratios(
    vehicles: Sequence[PlanInformation],
    before: Sequence[tuple[np.ndarray, np.ndarray]],
    pair: tuple[int, int],
    duration: float,
    band: tuple[float, float],
    counts: np.ndarray,
    index: Sequence[int],
    needed: np.ndarray,
) -> np.ndarray | None:
    """(vehicles, counts): for every pair of repeat counts, each vehicle's largest predicted
    precision over target of any targeted parameter (1: its every target just met); None when
    the band leaves too few bins."""
    ratios = []
    for vehicle, (a0, b0) in zip(vehicles, before, strict=True):
        blocks = [_block(vehicle, vehicle.levels[k], duration, band) for k in pair]
        if blocks[0] is None or blocks[1] is None:
            return None
        a = a0 + counts[:, 0, None, None] * blocks[0].a + counts[:, 1, None, None] * blocks[1].a
        b = b0 + counts[:, 0, None, None] * blocks[0].b + counts[:, 1, None, None] * blocks[1].b
        sd = _relative_sd(vehicle, _sandwich(a, b))[:, index]
        ratios.append(np.max(sd / needed, axis=1))
    return np.array(ratios)


def run_designs(tests: Sequence[MeasuredTest], runs: Sequence[Sequence[int]]) -> list[Design]:
    """The given runs of measured tests (indices into each test's estimates), each as a design
    of its own, its amplitude the level it belongs to
    (:func:`dtid.identification.search.runs.amplitude_levels`)."""
    levels = amplitude_levels(
        t.estimates[i].run.amplitude_nm
        for t, indices in zip(tests, runs, strict=True)
        for i in indices
    )
    designs = []
    for test, indices in zip(tests, runs, strict=True):
        for i in indices:
            run = test.estimates[i].run
            level = min(levels, key=lambda a: abs(a - run.amplitude_nm))
            low, high = sorted((run.f1_hz, run.f2_hz))
            designs.append(Design((level,), (1,), run.duration_s, low, high, validation_nm=0.0))
    return designs


def recorded_designs(tests: Sequence[MeasuredTest]) -> tuple[list[Design], list[float]]:
    """The identifying runs of measured tests (the default choice:
    :func:`dtid.identification.search.runs.split_runs`), each as a design of its own, and
    the amplitudes of the runs that validate, N*m."""
    identifying, validating = split_runs(tests)
    held_out = amplitude_levels(
        t.estimates[i].run.amplitude_nm
        for t, runs in zip(tests, validating, strict=True)
        for i in runs
    )
    return run_designs(tests, identifying), held_out


def planning_floor(name: str) -> float:
    """The least value a precision of ``name`` is planned relative to, SI units:
    :data:`PRIOR_FLOOR` of its passenger-car range's top for a stiffness, damping, friction or
    free play, 0 for the others."""
    if name in ("x1", "x12") or name not in PASSENGER_CAR_RANGES:
        return 0.0
    return PRIOR_FLOOR * PASSENGER_CAR_RANGES[name][1]


def planning_prior(prior: DrivetrainParameters) -> tuple[DrivetrainParameters, list[str]]:
    """The prior with each value at least its :func:`planning_floor`, and a note for each
    raised."""
    changes, notes = {}, []
    for name in PASSENGER_CAR_RANGES:
        floor = planning_floor(name)
        if floor == 0.0:
            continue
        value = getattr(prior, name)
        if value < floor:
            changes[name] = floor
            notes.append(
                f"{name} = {value:.4g} in the prior is planned for as {floor:.4g} {UNITS[name]} "
                f"({100 * PRIOR_FLOOR:g} % of a passenger car's largest): its relative "
                "precision needs a value to be relative to"
            )
    return prior.replace(**changes), notes


def plan_test(
    prior: DrivetrainParameters,
    targets: Mapping[str, float],
    safety: SafetyConfig,
    max_time_s: float = DEFAULT_MAX_TIME_S,
    validation_nm: float = VALIDATION_NM,
    seeds: int = DEFAULT_SEEDS,
    options: SimulationOptions | None = None,
    recorded: Sequence[Design] = (),
    held_out_nm: Sequence[float] = (),
    vehicle: VehicleData | None = None,
    spread: float | Mapping[str, float] | str = 0.0,
    vehicles: int = DEFAULT_VEHICLES,
    identification: Mapping[str, Any] | None = None,
    correlated: bool = True,
) -> tuple[PlanInformation, Recommendation]:
    """Measure the candidate amplitudes' information at a prior and recommend a test.

    The candidates are :data:`CANDIDATE_AMPLITUDES_NM` up to ``safety.max_amplitude_nm`` and
    the validation amplitude; the speed window is ``safety``'s too (see :func:`recommend`).
    ``options`` is the simulated vehicle (its idle speed, engine, noise; the reference's by
    default); ``recorded`` the identifying runs recorded so far (a follow-up test) and
    ``held_out_nm`` the amplitudes of their tests' validation runs; ``vehicle`` the engine and
    speed sensor the user gave (``--vehicle``), which then both the simulated vehicle and the
    model side have. With ``spread`` (relative half-widths, 1, for every drivetrain parameter
    or by name; :data:`~dtid.identification.planning.spread.RECORDED` for the recorded runs'
    own precision, drawn along the directions they leave open, :func:`recorded_correlation`,
    unless ``correlated`` is false) the information is measured at ``vehicles`` drivetrains
    around the prior too (:func:`dtid.identification.planning.spread.spread_priors`) and the
    test must meet every target at each of them. With ``identification`` (the JSON document of
    the ``recorded`` runs' identification, with its profiles) a target is met only where the
    profile interval confirms it too, and the next test is planned for what the intervals
    showed the prediction to be off by (:mod:`dtid.identification.planning.confirmation`).
    """
    options = options or SimulationOptions()
    if vehicle is not None:
        options = vehicle.simulated(options)
    cap = safety.max_amplitude_nm
    amplitudes = [a for a in CANDIDATE_AMPLITUDES_NM if a <= cap * (1 + 1e-9)]
    for extra in [validation_nm, *(a for d in recorded for a in d.amplitudes_nm)]:
        if extra and all(abs(a - extra) > AMPLITUDE_MATCH * extra for a in amplitudes):
            amplitudes.append(extra)
    excluded = {
        a: why for a in amplitudes if (why := request_exclusion(a, cap, validation_nm, held_out_nm))
    }
    if len(amplitudes) - len(excluded) < 2:  # refused before a minute of simulations
        raise _too_few_amplitudes(excluded)
    max_time_s = min(max_time_s, MAX_TEST_S)  # a longer plan would be refused (a campaign's
    # budget may be longer: it is spent over rounds)
    if not recorded and max_time_s < shortest_test_s(validation_nm):  # recorded may suffice
        raise _nothing_fits(max_time_s, validation_nm)
    centre, notes = planning_prior(prior)
    info = measure_information(centre, amplitudes, options=options, seeds=seeds, vehicle=vehicle)
    correlation = None
    if isinstance(spread, str):
        if spread != RECORDED:
            raise ValueError(f"spread {spread!r}: give half-widths or {RECORDED!r}")
        spread = recorded_spread(info, recorded)
        correlation = recorded_correlation(info, recorded) if correlated else None
    widths = half_widths(spread)
    around = [
        measure_information(
            planning_prior(draw)[0], amplitudes, options=options, seeds=seeds, vehicle=vehicle
        )
        for draw in spread_priors(prior, widths, vehicles, correlation)
    ]
    info = dataclasses.replace(
        info,
        notes=tuple(notes),
        around=tuple(around),
        spread=widths if around else {},
        spread_correlated=bool(around) and correlation is not None,
    )
    recommendation = recommend_confirmed(
        info,
        targets,
        identification,
        max_amplitude_nm=cap,
        max_time_s=max_time_s,
        validation_nm=validation_nm,
        speed_window_rpm=safety.speed_window_rpm,
        recorded=recorded,
        held_out_nm=held_out_nm,
    )
    return info, recommendation


def recommend_confirmed(
    info: PlanInformation,
    targets: Mapping[str, float],
    identification: Mapping[str, Any] | None,
    **limits: Any,
) -> Recommendation:
    """:func:`recommend`, with each target checked against the recorded runs' profile interval
    (:mod:`dtid.identification.planning.confirmation`): a target the interval does not confirm
    stays unmet, and where a closed interval is wider than the prediction the test is planned
    for the prediction scaled by the factor it was off by.

    Parameters
    ----------
    info, targets
        As :func:`recommend`.
    identification
        The JSON document of the recorded runs' identification (its ``parameters``,
        ``intervals`` and ``profiles``); None, or no runs recorded: :func:`recommend` alone.
    **limits
        :func:`recommend`'s other arguments (``recorded`` among them).
    """
    recommendation = recommend(info, targets, **limits)
    recorded = limits.get("recorded") or ()
    if identification is None or not recorded:
        return recommendation
    reached = predict_worst(info, None, recorded)
    checks = interval_checks(
        identification,
        targets,
        {name: SIGMAS * 100.0 * value for name, value in reached.items()},
        theta_from_parameters(info.prior),
    )
    planning = {**targets, **{c.name: c.planning_target_percent for c in checks if not c.confirms}}
    if planning != dict(targets):
        recommendation = recommend(info, planning, **limits)
    return dataclasses.replace(recommendation, intervals=checks)


def target_half_widths(
    theta: Mapping[str, float], targets: Mapping[str, float]
) -> dict[str, float]:
    """Each target's half-width around identified values, SI units: the target (% at
    :data:`SIGMAS` sigma) of the value its precision is planned relative to (the value, at
    least its :func:`planning_floor`), for the targets ``theta`` holds.

    Parameters
    ----------
    theta
        Identified values by setup-4 name, SI units.
    targets
        Targets by name, %.
    """
    return {
        name: target / 100.0 * relative_to(name, theta[name])
        for name, target in targets.items()
        if name in theta
    }


def relative_to(name: str, value: float) -> float:
    """The value a target or a precision of ``name`` is relative to, SI units: ``value``, at
    least its :func:`planning_floor`."""
    return max(float(value), planning_floor(name))


def wider_than_targets(
    theta: Mapping[str, float],
    intervals: Mapping[str, tuple[float | None, float | None]],
    targets: Mapping[str, float] = DEFAULT_TARGETS_PERCENT,
) -> dict[str, tuple[float | None, float | None]]:
    """The identified parameters whose 95 % interval reaches past a target's half-width.

    A 95 % interval spans about :data:`SIGMAS` standard deviations on each side, as a target
    does, so an interval wider than the target on either side says the test did not reach it
    (and ``dtid plan --after`` can design the one that does).

    Parameters
    ----------
    theta
        Identified values by setup-4 name, SI units.
    intervals
        (lower, upper) by name, SI units; None for an open end.
    targets
        Targets by name, % (at :data:`SIGMAS` sigma) of the value, at least of its
        :func:`planning_floor`, as :func:`target_half_widths` reads them.

    Returns
    -------
    dict
        By name, in the order of ``intervals``: each end's distance from the value in % of the
        value the target is relative to (negative below), None for an open end.
    """
    wide: dict[str, tuple[float | None, float | None]] = {}
    for name, ends in intervals.items():
        if name not in targets or name not in theta:
            continue
        value, scale = float(theta[name]), relative_to(name, theta[name])
        percent = tuple(None if end is None else 100.0 * (end - value) / scale for end in ends)
        if any(p is None or abs(p) > targets[name] for p in percent):
            wide[name] = (percent[0], percent[1])
    return wide


def recorded_spread(info: PlanInformation, recorded: Sequence[Design]) -> dict[str, float]:
    """Each drivetrain parameter's half-width the recorded runs leave open at the prior:
    :data:`SIGMAS` times their predicted relative precision, at most
    :data:`~dtid.identification.planning.spread.MAX_SPREAD` (none without recorded runs)."""
    if not recorded:
        return {}
    precision = predict(info, None, recorded)
    return {name: min(SIGMAS * precision[name], MAX_SPREAD) for name in DRIVETRAIN}


def recorded_correlation(info: PlanInformation, recorded: Sequence[Design]) -> np.ndarray | None:
    """The correlation between the :data:`~dtid.identification.planning.spread.DRIVETRAIN`
    parameters' errors that the recorded runs leave, predicted at the prior (the sandwich
    covariance of setup 4 carried to J1, J2, J3 by their gradient): the directions in which the
    vehicles those runs cannot tell from the identified one lie (None without recorded runs)."""
    if not recorded:
        return None
    _, grads = _precision_gradient(info.values)
    covariance = grads @ _sandwich(*information(info, recorded)) @ grads.T
    rows = [PRECISION_NAMES.index(name) for name in DRIVETRAIN]
    covariance = covariance[np.ix_(rows, rows)]
    sd = np.sqrt(np.maximum(np.diagonal(covariance), 0.0))
    if np.any(sd <= 0.0):
        return None
    correlation = covariance / np.outer(sd, sd)
    np.fill_diagonal(correlation, 1.0)
    return (correlation + correlation.T) / 2.0


def shortest_test_s(validation_nm: float = 0.0) -> float:
    """The shortest test the search can recommend: one chirp of the shortest duration at each of
    two amplitudes, and the validation chirp (``validation_nm``, N*m; 0 for none), s."""
    design = Design((1.0, 2.0), (1, 1), min(DURATIONS_S), 1.0, 15.0, validation_nm)
    return design.test_time_s


def _chirp_time(design: Design) -> float:
    return sum(design.repeats) * design.duration_s


def _unmet(
    name: str,
    target: float,
    per_vehicle: Sequence[Mapping[str, float]],
    design: Design,
    max_time_s: float,
    recorded: Sequence[Design],
    spread: Mapping[str, float],
) -> Unmet:
    each = [SIGMAS * p[name] * 100.0 for p in per_vehicle]
    predicted = max(each)
    earlier = sum(_chirp_time(d) for d in recorded)
    chirp_time = _chirp_time(design)
    needed = (earlier + chirp_time) * (predicted / target) ** 2 - earlier
    amplitudes = " and ".join(f"{a:g}" for a in design.amplitudes_nm)
    where = ""
    if len(each) > 1:
        missed = sum(value > target for value in each)
        where = (
            f" at the worst of the prior and {len(each) - 1} vehicles within "
            f"{describe(spread)} of it ({each[0]:.1f} % at the prior; {missed} of "
            f"{len(each)} miss)"
        )
    reason = (
        f"{predicted:.1f} % at {SIGMAS:g} sigma{where} within --max-time {max_time_s:g} s; the "
        f"precision grows with the square root of the chirp time, so about {needed / 60:.0f} "
        f"min of chirps at {amplitudes} N*m (now {chirp_time / 60:.0f} min) would reach "
        f"{target:g} %"
    )
    return Unmet(name, target, predicted, reason)


def scaled(design: Design, factor: float) -> Design:
    """The design with its repeats scaled by ``factor`` (at least one chirp per amplitude)."""
    repeats = tuple(max(1, round(n * factor)) for n in design.repeats)
    return dataclasses.replace(design, repeats=repeats)
