"""Run the plant: the Python side of the numba kernels in :mod:`dtid.simulator.kernel`.

The wrappers validate, draw the random numbers from a seeded numpy Generator, preallocate the
outputs and hand everything to the compiled kernels, so a run is reproducible from its seed
whatever the number of threads.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from dtid.acquisition.plan import TestPlan, tool_requests
from dtid.errors import AnalysisError, ConfigError
from dtid.simulator.angle_grid import (
    N_CYL,
    RPM_PER_RAD_S,
    STEP_RAD,
    STEPS_PER_SPEED_SAMPLE,
    STEPS_PER_STROKE,
)
from dtid.simulator.controller import IdleController
from dtid.simulator.couplings import belt_is_rigid
from dtid.simulator.engine import EngineGeometry, EngineTables, engine_tables
from dtid.simulator.kernel import (
    INTEGRATION,
    MAX_SPEED_RATIO,
    MIN_SPEED_RATIO,
    SPEED_AVERAGES,
    STATUS_OK,
    STATUS_SPEED_RANGE,
    Job,
    Jobs,
    Loop,
    run_plant,
    run_plant_batch,
)
from dtid.simulator.mechanisms import (
    KERNEL_WIDTH,
    P_C12_2,
    P_C14,
    P_C23_2,
    P_D12_2,
    P_D14,
    P_J4,
    Effects,
    kernel_parameters,
)
from dtid.simulator.parameters import NAMES, DrivetrainParameters

STABILITY_LIMIT = 0.5
"""Largest omega*h (and damping rate * h) a substep may take; both of the kernel's schemes are
stable below 2 (:mod:`dtid.simulator.kernel`)."""
MAX_SUBSTEPS = 100_000
"""Most substeps per angle step a parameter set may need: beyond, a 60 s test takes hours and
the set is a unit slip, not a drivetrain (``--fix c12=1e300`` overflowed the count). The
default search box's corners need < 100; the diagnosis's refits up to about 16,000, where an
``accessory_mode`` belt of 1 N*m/rad and 5 N*m*s/rad holds an accessory of 2.5e-6 kg*m^2
(:func:`dtid.simulator.couplings.belt_is_rigid` lumps it only by its stiffness)."""
QUADRATIC_RATE_RAD_S = 5.0
"""Relative DMF speed at which quadratic damping's slope is bounded for the step size, rad/s
(a 10 Hz oscillation of 0.08 rad)."""


@dataclass(frozen=True)
class SimulationOptions:
    """How the plant and its sensors behave besides the drivetrain parameters.

    The defaults make realistic, not clean, data: combustion varies from cycle to cycle (a
    coefficient of variation of 3 % of the mean torque, typical of IMEP at idle) and both sensors
    are noisy (0.3 rpm on the filtered speed from tooth-wheel jitter, 0.3 N*m on the
    cylinder-pressure mean torque). :meth:`clean` switches all of that off.

    Attributes
    ----------
    pulsation
        Include the angle-periodic engine torque of eqs. (2), (4), (5); False keeps the mean
        torque of each stroke only.
    combustion_variation
        Relative standard deviation of each stroke's mean torque, 1.
    speed_noise_rpm
        Standard deviation of white noise on the filtered speed, rpm.
    torque_noise_nm
        Standard deviation of white noise on the measured mean torque, N*m.
    engine
        Crank-train data.
    controller
        Idle-speed controller (and whether the loop is closed).
    speed_average
        How the speed sensor averages its half revolution: ``"times"`` (the default), the
        window's angle over its time, as a tooth timer that adds up tooth times does, or
        ``"speeds"``, the mean of the 30 step speeds (eq. 9 read literally)
        (:data:`dtid.simulator.kernel.SPEED_AVERAGES`).
    integration
        ``"euler"`` (the default: the paper's angle-discrete model, first order) or ``"verlet"``
        (second order: the continuous plant to 0.02 dB; :mod:`dtid.simulator.kernel`).
    effects
        Mechanisms beyond the paper's model present in the vehicle
        (:mod:`dtid.simulator.mechanisms`); none by default. Parameter rows given with the
        mechanism columns already (:data:`dtid.simulator.mechanisms.KERNEL_WIDTH`) override
        them.
    """

    pulsation: bool = True
    combustion_variation: float = 0.03
    speed_noise_rpm: float = 0.3
    torque_noise_nm: float = 0.3
    engine: EngineGeometry = field(default_factory=EngineGeometry)
    controller: IdleController = field(default_factory=IdleController)
    speed_average: str = SPEED_AVERAGES[0]
    effects: Effects = field(default_factory=Effects)
    integration: str = "euler"

    def __post_init__(self) -> None:
        for name in ("combustion_variation", "speed_noise_rpm", "torque_noise_nm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"simulation option {name} must be >= 0, got {value}")
        if self.speed_average not in SPEED_AVERAGES:
            raise ConfigError(
                f"simulation option speed_average must be one of {', '.join(SPEED_AVERAGES)}, "
                f"got {self.speed_average!r}"
            )
        if self.integration not in INTEGRATION:
            raise ConfigError(
                f"simulation option integration must be one of {', '.join(INTEGRATION)}, got "
                f"{self.integration!r}"
            )

    @classmethod
    def clean(cls, **changes: object) -> SimulationOptions:
        """Options without combustion variation and sensor noise (other options as given)."""
        base = {"combustion_variation": 0.0, "speed_noise_rpm": 0.0, "torque_noise_nm": 0.0}
        return cls(**{**base, **changes})  # type: ignore[arg-type]

    def sigmas(self) -> np.ndarray:
        """Noise levels in the order the kernel takes them, then 1 where the speed sensor
        averages times."""
        return np.array(
            [
                self.combustion_variation,
                self.speed_noise_rpm,
                self.torque_noise_nm,
                1.0 if self.speed_average == "times" else 0.0,
            ]
        )

    def tables(self) -> EngineTables:
        """Engine tables for these options."""
        return engine_tables(self.engine) if self.pulsation else EngineTables.disabled()

    def loop(
        self,
        request_t: np.ndarray,
        request_nm: np.ndarray,
        reference: np.ndarray | None = None,
        drive: np.ndarray | None = None,
        cylinder_offset: int = 0,
    ) -> Loop:
        """The kernels' shared arguments (:class:`dtid.simulator.kernel.Loop`) for these options:
        the one place they are built.

        Parameters
        ----------
        request_t, request_nm
            The test-torque requests the ECU receives: times, s (increasing), values, N*m.
        reference
            The controller's reference per speed sample, rpm; its set-point by default (a
            vehicle's own ECU).
        drive
            Torque added to each stroke's request, N*m; none by default.
        cylinder_offset
            Where the first stroke falls in the firing order (:class:`dtid.simulator.kernel.
            Loop`); 0: the cylinder of ``cylinder_imbalance`` fires it.

        Raises
        ------
        ConfigError
            If the arrays do not fit together.
        """
        request_t = np.ascontiguousarray(request_t, dtype=np.float64)
        request_nm = np.ascontiguousarray(request_nm, dtype=np.float64)
        if request_t.shape != request_nm.shape or np.any(np.diff(request_t) < 0):
            raise ConfigError("request times must increase and match the request values")
        reference = self.controller.reference() if reference is None else reference
        reference = np.ascontiguousarray(reference, dtype=np.float64)
        drive = np.ascontiguousarray(np.zeros(0) if drive is None else drive, dtype=np.float64)
        if reference.ndim != 1 or len(reference) == 0 or drive.ndim != 1:
            raise ConfigError("reference must be a non-empty 1-D array and drive a 1-D array")
        tables = self.tables()
        return Loop(
            tables.combustion_shape,
            tables.compression,
            tables.inertia,
            self.controller.as_array(),
            reference,
            drive,
            request_t,
            request_nm,
            self.sigmas(),
            INTEGRATION[self.integration],
            cylinder_offset % N_CYL,
        )


@dataclass(frozen=True)
class SimulationResult:
    """What the vehicle's sensors and ECU report during one simulated test.

    Times are simulated test time in s from the start of the test.

    Attributes
    ----------
    speed_t, speed_rpm
        Filtered engine speed samples (every pi/2 of crank angle), rpm.
    torque_request_nm
        T_ecu at each speed sample, N*m.
    delta12_rad, delta23_rad
        Coupling deflections at each speed sample, rad (not on the bus; for analysis).
    torque_t, mean_torque_nm, cylinder
        Mean torque of each working stroke as the cylinder-pressure sensor reports it at the end
        of the stroke, N*m, and the index (0..3, firing order) of the cylinder.
    request_t, test_torque_nm
        The tool's test-torque requests, sent every ``plan.request_period_s``, N*m.
    parameters, plan, options
        What was simulated.
    """

    speed_t: np.ndarray
    speed_rpm: np.ndarray
    torque_request_nm: np.ndarray
    delta12_rad: np.ndarray
    delta23_rad: np.ndarray
    torque_t: np.ndarray
    mean_torque_nm: np.ndarray
    cylinder: np.ndarray
    request_t: np.ndarray
    test_torque_nm: np.ndarray
    parameters: DrivetrainParameters
    plan: TestPlan
    options: SimulationOptions

    @classmethod
    def from_outputs(
        cls,
        speed: np.ndarray,
        torque: np.ndarray,
        requests: tuple[np.ndarray, np.ndarray],
        parameters: DrivetrainParameters,
        plan: TestPlan,
        options: SimulationOptions,
    ) -> SimulationResult:
        """Build a result from an integrator's outputs in the kernel's format.

        Parameters
        ----------
        speed
            (n, 5) speed events, columns :data:`dtid.simulator.kernel.SPEED_COLUMNS`.
        torque
            (m, 3) stroke events, columns :data:`dtid.simulator.kernel.TORQUE_COLUMNS`.
        requests
            The tool's request times, s, and values, N*m.
        parameters, plan, options
            What was simulated.
        """
        return cls(
            speed_t=speed[:, 0].copy(),
            speed_rpm=speed[:, 1].copy(),
            torque_request_nm=speed[:, 2].copy(),
            delta12_rad=speed[:, 3].copy(),
            delta23_rad=speed[:, 4].copy(),
            torque_t=torque[:, 0].copy(),
            mean_torque_nm=torque[:, 1].copy(),
            cylinder=torque[:, 2].astype(np.int64),
            request_t=requests[0],
            test_torque_nm=requests[1],
            parameters=parameters,
            plan=plan,
            options=options,
        )


def substeps(params: np.ndarray, controller: IdleController) -> int:
    """Substeps per angle step that keep the explicit part of the integration stable.

    A Gershgorin bound on the largest eigenvalue of M^-1 C (and of M^-1 D for damping) gives the
    fastest mode; the longest step is the angle step at the lowest admitted speed.

    Parameters
    ----------
    params
        Parameters ordered as :data:`dtid.simulator.parameters.NAMES`.
    controller
        Gives the set-point, hence the step time.

    Raises
    ------
    ConfigError
        When more than :data:`MAX_SUBSTEPS` would be needed (a unit slip).
    """
    j1, j2, j3, c12, c23, d12, d23 = params[:7]
    j4 = c14 = d14 = 0.0
    if len(params) == KERNEL_WIDTH:  # the mechanisms' stiffer stages, dampings and mode
        c12 += params[P_C12_2]
        c23 += params[P_C23_2]
        d12 += 2 * params[P_D12_2] * QUADRATIC_RATE_RAD_S
        j4 = params[P_J4]
        if j4 > 0 and belt_is_rigid(j1, j4, params[P_C14]):  # lumped into J1 by the kernel
            j1, j4 = j1 + j4, 0.0
        if j4 > 0:
            c14, d14 = params[P_C14], params[P_D14]
    stiff = max(2 * (c12 + c14) / j1, 2 * (c12 + c23) / j2, 2 * c23 / j3)
    damp = max(2 * (d12 + d14) / j1, 2 * (d12 + d23) / j2, 2 * d23 / j3)
    if j4 > 0:
        stiff, damp = max(stiff, 2 * c14 / j4), max(damp, 2 * d14 / j4)
    rate = max(math.sqrt(stiff), damp)
    longest_step = STEP_RAD / (MIN_SPEED_RATIO * controller.setpoint_rpm / RPM_PER_RAD_S)
    needed = rate * longest_step / STABILITY_LIMIT
    if not needed <= MAX_SUBSTEPS:
        values = ", ".join(f"{name} {params[i]:g}" for i, name in enumerate(NAMES[:7]))
        raise ConfigError(
            f"the parameter set's fastest mode, {rate / (2 * math.pi):.3g} Hz, is beyond any "
            f"drivetrain's ({values} in SI units: a stiffness or damping too large for its "
            "inertias; check the units)"
        )
    return max(1, math.ceil(needed))


def _left_idle(t_s: float, plan: TestPlan) -> str:
    """Why a simulated engine left its speed band at ``t_s`` s: the chirp it was driven by when
    the engine had idled through a smaller one, else the parameter set (or either)."""
    what = f"the simulated engine left {MIN_SPEED_RATIO}..{MAX_SPEED_RATIO} times its idle "
    what += f"set-point at t = {t_s:.2f} s"
    during = [c for c in plan.chirps if c.start_s <= t_s <= c.end_s + plan.pause_s]
    if not during:
        return f"{what}, at idle: this parameter set cannot idle (check the inertias, T_loss and K)"
    chirp = during[0]
    held = [c.amplitude_nm for c in plan.chirps if c.end_s < chirp.start_s]
    if held and min(held) < chirp.amplitude_nm:
        return (
            f"{what}, during the {chirp.amplitude_nm:g} N*m chirp after it idled through the "
            f"{min(held):g} N*m one: that test torque is more than this engine's idle can hold; "
            "give a smaller amplitude"
        )
    return (
        f"{what}, during the {chirp.amplitude_nm:g} N*m chirp: either that test torque is more "
        "than this engine's idle can hold (try a smaller amplitude) or this parameter set cannot "
        "idle (check the inertias, T_loss and K)"
    )


def output_capacity(t_end: float, controller: IdleController) -> tuple[int, int]:
    """Output rows needed for the speed and stroke events of ``t_end`` s at the highest
    admitted speed (a few more than that, so a run's last partial step always fits)."""
    steps = t_end * MAX_SPEED_RATIO * controller.setpoint_rpm / RPM_PER_RAD_S / STEP_RAD
    return int(steps / STEPS_PER_SPEED_SAMPLE) + 8, int(steps / STEPS_PER_STROKE) + 8


def simulate(
    parameters: DrivetrainParameters,
    plan: TestPlan | None = None,
    options: SimulationOptions | None = None,
    seed: int = 0,
) -> SimulationResult:
    """Simulate one chirp test of the closed loop.

    Parameters
    ----------
    parameters
        Drivetrain parameter set.
    plan
        Test plan; the paper's three-amplitude test by default.
    options
        Engine, controller, noise; realistic defaults.
    seed
        Seed of the noise draws.

    Returns
    -------
    SimulationResult

    Raises
    ------
    AnalysisError
        If the engine stalls or runs away (the parameter set cannot idle).
    """
    plan = plan or TestPlan()
    options = options or SimulationOptions()
    params = kernel_parameters(parameters.as_array(), options.effects)
    n_speed_max, n_stroke_max = output_capacity(plan.end_s, options.controller)
    request_t, request_nm = tool_requests(plan)
    rng = np.random.default_rng(seed)
    cv_noise = rng.standard_normal(n_stroke_max)
    torque_noise = rng.standard_normal(n_stroke_max)
    speed_noise = rng.standard_normal(n_speed_max)
    out_speed = np.empty((n_speed_max, 5))
    out_torque = np.empty((n_stroke_max, 3))
    job = Job(
        params,
        1.0,
        substeps(params, options.controller),
        cv_noise,
        speed_noise,
        torque_noise,
        out_speed,
        out_torque,
    )
    n_speed, n_torque, status = run_plant(options.loop(request_t, request_nm), job, plan.end_s)
    if status == STATUS_SPEED_RANGE:
        raise AnalysisError(_left_idle(out_speed[max(n_speed - 1, 0), 0], plan))
    if status != STATUS_OK:
        raise RuntimeError(f"simulator kernel ended with status {status}")
    return SimulationResult.from_outputs(
        out_speed[:n_speed],
        out_torque[:n_torque],
        (request_t, request_nm),
        parameters,
        plan,
        options,
    )


@dataclass(frozen=True)
class BatchResult:
    """Outputs of :func:`simulate_batch`, one row per job, valid up to each job's counts.

    Attributes
    ----------
    speed
        (n_jobs, n_max, 5), columns :data:`dtid.simulator.kernel.SPEED_COLUMNS`.
    torque
        (n_jobs, n_max, 3), columns :data:`dtid.simulator.kernel.TORQUE_COLUMNS`.
    n_speed, n_torque
        Valid rows per job.
    status
        Kernel status per job (0 completed, 1 stalled or ran away, 2 buffer full).
    """

    speed: np.ndarray
    torque: np.ndarray
    n_speed: np.ndarray
    n_torque: np.ndarray
    status: np.ndarray


def simulate_batch(
    params: np.ndarray,
    amplitudes_nm: np.ndarray,
    plan: TestPlan,
    options: SimulationOptions | None = None,
    seed: int = 0,
    streams: np.ndarray | None = None,
    signs: np.ndarray | None = None,
) -> BatchResult:
    """Simulate many parameter sets, each driven by one chirp of its own amplitude.

    Job i simulates ``params[i]`` driven by a single chirp of amplitude ``amplitudes_nm[i]`` with
    the frequencies, duration and settling time of ``plan`` (its amplitudes are ignored).
    See :func:`replay_batch` for the parameters.
    """
    single = TestPlan(
        amplitudes_nm=(1.0,),
        validation_nm=0.0,
        f1_hz=plan.f1_hz,
        f2_hz=plan.f2_hz,
        duration_s=plan.duration_s,
        settle_s=plan.settle_s,
        pause_s=plan.pause_s,
        request_period_s=plan.request_period_s,
    )
    request_t, request_nm = tool_requests(single)
    return replay_batch(
        params, request_t, request_nm, amplitudes_nm, single.end_s, options, seed, streams, signs
    )


@functools.lru_cache(maxsize=64)
def _draws(seed: int, stream: int, n_strokes: int, n_speed: int) -> tuple[np.ndarray, ...]:
    """The standard normal draws of noise stream ``(seed, stream)``: the combustion variation's
    and the torque sensor's (one per stroke), then the speed sensor's (one per speed sample),
    read-only. Kept: an identification replays the same streams thousands of times."""
    rng = np.random.default_rng((seed, stream))
    draws = tuple(rng.standard_normal(n) for n in (n_strokes, n_strokes, n_speed))
    for array in draws:
        array.flags.writeable = False
    return draws


def replay_batch(
    params: np.ndarray,
    request_t: np.ndarray,
    request_nm: np.ndarray,
    scales: np.ndarray,
    t_end: float,
    options: SimulationOptions | None = None,
    seed: int = 0,
    streams: np.ndarray | None = None,
    signs: np.ndarray | None = None,
    reference: np.ndarray | None = None,
    drive: np.ndarray | None = None,
    cylinder_offset: int = 0,
) -> BatchResult:
    """Simulate many parameter sets driven by one table of test-torque requests, in parallel.

    This is the entry point of the identification, which replays a recording's own requests
    for thousands of parameter sets.

    Parameters
    ----------
    params
        (n_jobs, 12) parameters ordered as :data:`dtid.simulator.parameters.NAMES`, SI units.
    request_t, request_nm
        The test-torque requests: times (s, increasing) and values (N*m), shared by all jobs.
    scales
        (n_jobs,) factor on the request values per job.
    t_end
        Simulated duration, s.
    options
        Shared by all jobs.
    seed
        Seed of the noise draws; job i gets the stream ``(seed, streams[i])``.
    streams
        (n_jobs,) noise stream of each job, ``arange(n_jobs)`` by default. Jobs given the same
        stream see the same combustion variation and sensor noise (common random numbers, which
        keep an objective over parameter sets deterministic).
    signs
        (n_jobs,) +1 or -1 on each job's draws, all +1 by default: a job given -1 sees its
        stream's draws negated (antithetic variates: a pair of jobs with the same stream and
        opposite signs cancels the noise's first-order effect in their mean).
    reference
        The controller's reference speed per speed sample, rpm (the last holds on); the
        controller's set-point by default (a vehicle's own ECU).
    drive
        Torque added to each stroke's request, N*m, per stroke from the start; none by default
        (see :mod:`dtid.simulator.kernel`).
    cylinder_offset
        Where the first stroke falls in the firing order (:class:`dtid.simulator.kernel.Loop`).

    Returns
    -------
    BatchResult
    """
    options = options or SimulationOptions()
    params = np.asarray(params, dtype=np.float64)
    if params.ndim != 2 or params.shape[1] not in (len(NAMES), KERNEL_WIDTH):
        raise ConfigError(
            f"params must have shape (n, {len(NAMES)}) or (n, {KERNEL_WIDTH}), got {params.shape}"
        )
    params = kernel_parameters(params, options.effects)
    n_jobs = params.shape[0]
    scales = np.ascontiguousarray(scales, dtype=np.float64)
    if scales.shape != (n_jobs,):
        raise ConfigError(f"scales must have shape ({n_jobs},), got {scales.shape}")
    loop = options.loop(request_t, request_nm, reference, drive, cylinder_offset)
    streams = np.arange(n_jobs) if streams is None else np.asarray(streams, dtype=np.int64)
    if streams.shape != (n_jobs,):
        raise ConfigError(f"streams must have shape ({n_jobs},), got {streams.shape}")
    signs = np.ones(n_jobs) if signs is None else np.asarray(signs, dtype=np.float64)
    if signs.shape != (n_jobs,) or not np.all(np.abs(signs) == 1):
        raise ConfigError(f"signs must be ({n_jobs},) values of +1 or -1")
    n_speed_max, n_stroke_max = output_capacity(t_end, options.controller)
    # one row of draws per (stream, sign) pair, shared by the jobs that have it
    pairs, noise_row = np.unique(
        np.stack([streams, signs < 0], axis=1), axis=0, return_inverse=True
    )
    rows = [
        (-1.0 if negated else 1.0, _draws(seed, int(stream), n_stroke_max, n_speed_max))
        for stream, negated in pairs
    ]
    cv_noise, torque_noise, speed_noise = (
        np.stack([sign * draws[k] for sign, draws in rows]) for k in range(3)
    )
    n_sub = np.array([substeps(row, options.controller) for row in params], dtype=np.int64)
    out_speed = np.empty((n_jobs, n_speed_max, 5))
    out_torque = np.empty((n_jobs, n_stroke_max, 3))
    counts = np.zeros((n_jobs, 3), dtype=np.int64)
    jobs = Jobs(
        params,
        scales,
        n_sub,
        noise_row.reshape(n_jobs).astype(np.int64),
        cv_noise,
        speed_noise,
        torque_noise,
        out_speed,
        out_torque,
    )
    run_plant_batch(loop, jobs, t_end, counts)
    return BatchResult(out_speed, out_torque, counts[:, 0], counts[:, 1], counts[:, 2])
