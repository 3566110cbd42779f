"""The closed loop of :mod:`dtid.simulator.kernel`, integrated in the time domain with
``solve_ivp``.

This is the yardstick of the simulator benchmark: the same equations, sensors, controller and
test torque as the angle-discrete numba kernel, written the way a competent engineer would
write them with ``scipy.integrate.solve_ivp`` and no angle-domain tricks. Every fact (parameters,
engine tables, chirp, coupling physics, controller settings, noise draws) comes from the
project's modules; only the integration differs.

State, SI units: ``[phi, omega1, omega2, omega3, delta12, delta23, b]`` with phi the crank angle
since the start of the current working stroke, rad, the three speeds, rad/s, the two coupling
deflections, rad, and the backlash position b of the gear play, rad.

Design choices
--------------
* Segments. The right-hand side is smooth in time except where the engine's held mean torques
  change, which is at the start of every working stroke (every pi of crank angle). The loop
  therefore integrates one stroke per ``solve_ivp`` call, from phi = 0 to a terminal event at
  phi = pi located by solve_ivp's event root finder, and restarts the solver there with the new
  held torque. The controller (every pi/2) only changes the request that the *next* stroke event
  samples, so it needs no restart: it runs on the dense output. Restarting at every pi/2 as well
  would cost one more solver start-up per stroke and change nothing.
* Crank-synchronous sampling. The speed sensor averages omega1 at the 30 angle-grid points of
  the last pi (eq. 9). The times at which phi crosses those grid angles are found from the
  stroke's dense output by a vectorised Newton iteration on phi(t) - phi_j (phi is strictly
  increasing with slope omega1), so every sensor sample, and the controller's time stamp, is at
  the grid angle to round-off, without stopping the integrator.
* Engine torque. The tables of :func:`dtid.simulator.engine.engine_tables` are the engine torque on
  the 120-point angle grid of a working cycle. They are interpolated linearly at the continuous
  crank angle with ``np.interp``; as the held torques are constant over a stroke, the sum
  compression + sum_i T_m,i * shape_i is formed once per stroke and the table is rotated to the
  stroke's start, which takes the periodic wrap out of the right-hand side. (The kernel holds
  the mean of each table over its angle step instead; ``IvpSettings(hold_table=True)`` reads
  the tables that way, to tell that difference apart from the integrators'.)
* DMF. Spring with free play and damper through :func:`dtid.simulator.couplings.dmf_smooth_torque`;
  Coulomb friction as ``Tc12 * tanh(rate12 / w_f)`` because an ODE solver cannot apply the
  kernel's Moreau friction impulse (stick/slip needs a set-valued sign). The width w_f trades
  fidelity for stiffness; see :data:`FRICTION_WIDTH_RAD_S` for the choice of 1e-3 rad/s.
* Gear play. The Nordin-Galic-Gutman ODE: inside the gap db/dt = d(delta23)/dt
  + c23/d23 (delta23 - b), so the coupling transmits nothing; on a stop b is held while the
  torque pushes into it. The coupling torque c23 (delta23 - b) + d23 (d(delta23)/dt - db/dt) is
  then zero in the gap and the spring-damper torque in contact, as in
  :func:`dtid.simulator.couplings.backlash_torque`. RK45 takes the switch between gap and contact as
  it is, through its error control (no event and no solver restart per contact).
  LSODA cannot: its Newton iteration chatters across the switch and the step collapses to
  nanoseconds at the first contact, so for it db/dt fades to zero over the last 1e-7 rad before
  a stop (:data:`IMPLICIT_STOP_WIDTH_RAD`).
* Tolerances. rtol 1e-6, atol 1e-9 (rad, rad/s). Tightening to 1e-8/1e-11 moves the filtered
  speed by 0.03 rpm rms and |G_DRV| by under 0.01 dB on average: the result is converged.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import OdeSolution, solve_ivp

from dtid.acquisition.plan import TestPlan
from dtid.errors import AnalysisError
from dtid.simulator.angle_grid import (
    N_CYL,
    N_WIN,
    RPM_PER_RAD_S,
    STEP_RAD,
    STEPS_PER_CYCLE,
    STEPS_PER_SPEED_SAMPLE,
    STEPS_PER_STROKE,
)
from dtid.simulator.couplings import dead_zone, dmf_smooth_torque
from dtid.simulator.engine import engine_tables
from dtid.simulator.kernel import MAX_SPEED_RATIO, MIN_SPEED_RATIO
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import (
    SimulationOptions,
    SimulationResult,
    output_capacity,
    tool_requests,
)

FRICTION_WIDTH_RAD_S = 1e-3
"""Width w_f of the regularised Coulomb friction Tc12 * tanh(rate12 / w_f), rad/s.

Small against the DMF's relative speeds in a chirp test (0.8 rad/s rms, median 0.5 rad/s for the
reference vehicle at 10 N*m), so sliding friction is Tc12 to within 1e-6 once the slip exceeds
8 mrad/s, and a "stuck" DMF creeps at most about w_f * atanh(T/Tc12), a few mrad/s, some 1e-4 rad
over a stick phase of a tenth of a second against deflections of 2e-2 rad rms. The price of a
small width is stiffness while the DMF sticks: the friction then acts as a damper of Tc12 / w_f,
whose rate Tc12 / w_f (1/J1 + 1/J2) (5.3e3 1/s here) bounds an explicit step to about 3.3 over it
(0.6 ms), no tighter than the engine pulsation asks for. Measured on the reference vehicle
(10 N*m, 6 s chirp): widths from 1e-2 to 1e-5 rad/s give the same RK45 step count within 1 % and
filtered speeds within 0.05 rpm rms of each other; its DMF slips through zero rather than
sticking (Tc12 = 0.3 N*m is small against the dynamic torques), so the result does not hinge on
the width.
"""

STATE_NAMES = ("phi", "omega1", "omega2", "omega3", "delta12", "delta23", "backlash")
"""State vector of the time-domain plant, SI units (phi from the start of the current stroke)."""

IMPLICIT_STOP_WIDTH_RAD = 1e-7
"""Width of the gear-play stop ramp for implicit methods, rad.

Against the 12 mrad play of the reference vehicle it moves the stop by 1e-5 of the play, and the
coupling torque it leaves out at the stop is at most d23 * db/dt, a transition of some 1e-7 rad
instead of an instant one.
"""

NEWTON_TOLERANCE_RAD = 1e-10
"""Grid angles are located on the dense output to this crank-angle error, rad."""


@dataclass(frozen=True)
class IvpSettings:
    """How :func:`simulate_solve_ivp` integrates.

    Attributes
    ----------
    method
        ``solve_ivp`` method; it must offer dense output (RK45, RK23, DOP853, Radau, BDF, LSODA).
    rtol, atol
        ``solve_ivp`` tolerances; atol in the state's SI units (rad, rad/s).
    friction_width_rad_s
        Width w_f of the tanh friction, rad/s (:data:`FRICTION_WIDTH_RAD_S`).
    stop_width_rad
        0 (the default) switches the gear play exactly between gap and stop. A positive width
        lets db/dt fade linearly to zero over the last ``stop_width_rad`` before a stop, which
        makes the right-hand side Lipschitz: the implicit methods (LSODA, BDF, Radau) need it,
        because their Newton iteration chatters across the exact switch and the step collapses
        to nanoseconds at the first contact (:data:`IMPLICIT_STOP_WIDTH_RAD`).
    hold_table
        False (the default) interpolates the engine tables linearly in crank angle; True holds
        each table value over its angle step as the kernel does (for diagnosis: the right-hand
        side then jumps every pi/30 and the solver pays for it).
    """

    method: str = "RK45"
    rtol: float = 1e-6
    atol: float = 1e-9
    friction_width_rad_s: float = FRICTION_WIDTH_RAD_S
    stop_width_rad: float = 0.0
    hold_table: bool = False

    @classmethod
    def lsoda(cls) -> IvpSettings:
        """LSODA with the same tolerances and the gear-play stop ramp it needs."""
        return cls(method="LSODA", stop_width_rad=IMPLICIT_STOP_WIDTH_RAD)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dict of the attributes."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__}


@dataclass(frozen=True)
class SolverStats:
    """Work done by one time-domain run.

    Attributes
    ----------
    settings
        How the run was integrated.
    segments
        ``solve_ivp`` calls (one per working stroke).
    steps
        Accepted solver steps over all segments.
    nfev
        Right-hand-side evaluations over all segments.
    wall_s
        Wall time of the run, s.
    simulated_s
        Simulated test time, s.
    """

    settings: IvpSettings
    segments: int
    steps: int
    nfev: int
    wall_s: float
    simulated_s: float

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dict of the attributes, the settings flattened in."""
        out: dict[str, object] = dict(self.settings.as_dict())
        out.update({name: getattr(self, name) for name in self.__dataclass_fields__})
        del out["settings"]
        return out


def _stroke_rhs(
    p: DrivetrainParameters,
    gas_table: np.ndarray,
    inertia_table: np.ndarray,
    settings: IvpSettings,
) -> Callable[[float, np.ndarray], list[float]]:
    """Right-hand side dy/dt of one working stroke (held mean torques fixed).

    Parameters
    ----------
    p
        Drivetrain parameters.
    gas_table
        Compression torque plus the held combustion torques on the grid, rotated so that index 0
        is the stroke's start, with the wrap point appended (121 values), N*m.
    inertia_table
        Oscillating-mass torque over omega1^2, rotated likewise, N*m*s^2/rad^2.
    settings
        Friction width, stop ramp and table reading.
    """
    grid = np.arange(STEPS_PER_CYCLE + 1) * STEP_RAD
    j1, j2, j3 = p.J1, p.J2, p.J3
    c12, c23, d12, d23, tc12 = p.c12, p.c23, p.d12, p.d23, p.Tc12
    half12, half23, t_loss = 0.5 * p.eps12, 0.5 * p.eps23, p.T_loss
    relax = c23 / d23 if d23 > 0.0 else 0.0
    width, ramp, hold_table = (
        settings.friction_width_rad_s,
        settings.stop_width_rad,
        settings.hold_table,
    )
    interp, tanh = np.interp, math.tanh

    def rhs(t: float, y: np.ndarray) -> list[float]:
        phi, w1, w2, w3, delta12, delta23, backlash = y
        if hold_table:
            index = min(int(phi / STEP_RAD), STEPS_PER_CYCLE)
            engine = gas_table[index] + inertia_table[index] * w1 * w1
        else:
            engine = interp(phi, grid, gas_table) + interp(phi, grid, inertia_table) * w1 * w1
        rate12 = w1 - w2
        rate23 = w2 - w3
        torque12 = dmf_smooth_torque(delta12, rate12, c12, d12, half12) + tc12 * tanh(
            rate12 / width
        )
        if half23 <= 0.0:
            backlash_rate = 0.0
            torque23 = c23 * delta23 + d23 * rate23
        elif d23 <= 0.0:
            backlash_rate = 0.0
            torque23 = c23 * dead_zone(delta23, half23)
        else:
            backlash_rate = rate23 + relax * (delta23 - backlash)
            room = half23 - backlash if backlash_rate > 0.0 else backlash + half23
            if room <= 0.0:
                backlash_rate = 0.0  # on the stop, pushed into it
            elif room < ramp:
                backlash_rate *= room / ramp
            torque23 = c23 * (delta23 - backlash) + d23 * (rate23 - backlash_rate)
        return [
            w1,
            (engine - t_loss - torque12) / j1,
            (torque12 - torque23) / j2,
            torque23 / j3,
            rate12,
            rate23,
            backlash_rate,
        ]

    return rhs


def _stroke_end(t: float, y: np.ndarray) -> float:
    """Event: the crank has turned pi since the start of the stroke."""
    return y[0] - math.pi


_stroke_end.terminal = True  # type: ignore[attr-defined]
_stroke_end.direction = 1.0  # type: ignore[attr-defined]


def _grid_crossings(
    sol: OdeSolution, t0: float, t1: float, angles: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Times at which phi(t) crosses ``angles`` inside a stroke, and the states there.

    Newton's iteration on phi(t) - angle with the slope omega1, started from a linear guess
    between the stroke's ends, on the solver's dense output.
    """
    times = t0 + (t1 - t0) * angles / math.pi
    for _ in range(20):
        states = sol(times)
        error = states[0] - angles
        if np.max(np.abs(error)) < NEWTON_TOLERANCE_RAD:
            return times, states
        times = np.clip(times - error / states[1], t0, t1)
    raise RuntimeError("grid-angle search on the dense output did not converge")


def simulate_solve_ivp(
    parameters: DrivetrainParameters,
    plan: TestPlan | None = None,
    options: SimulationOptions | None = None,
    seed: int = 0,
    settings: IvpSettings | None = None,
) -> tuple[SimulationResult, SolverStats]:
    """Simulate one chirp test of the closed loop with ``scipy.integrate.solve_ivp``.

    Same inputs, random draws and outputs as :func:`dtid.simulator.simulate.simulate`.

    Parameters
    ----------
    parameters
        Drivetrain parameter set.
    plan
        Test plan; the paper's three-amplitude test by default.
    options
        Engine, controller, noise.
    seed
        Seed of the noise draws (the same draws as :func:`dtid.simulator.simulate.simulate`).
    settings
        Method, tolerances and regularisations; RK45 at rtol 1e-6, atol 1e-9 by default.

    Returns
    -------
    SimulationResult
        As :func:`dtid.simulator.simulate.simulate` returns it.
    SolverStats
        Segments, steps, right-hand-side evaluations and wall time.

    Raises
    ------
    AnalysisError
        If the engine stalls or runs away.
    """
    started = time.perf_counter()
    plan = plan or TestPlan(amplitudes_nm=(2.0, 5.0, 10.0), validation_nm=0.0)
    options = options or SimulationOptions()
    settings = settings or IvpSettings()
    p = parameters
    controller = options.controller
    # point values to interpolate; the kernel's step means when reading the tables its way
    tables = (
        engine_tables(options.engine, step_mean=False)
        if options.pulsation and not settings.hold_table
        else options.tables()
    )
    request_t, request_nm = tool_requests(plan)
    sigma_cv, sigma_speed, sigma_torque = options.sigmas()[:3]
    n_speed_max, n_stroke_max = output_capacity(plan.end_s, controller)
    rng = np.random.default_rng(seed)
    cv_noise = rng.standard_normal(n_stroke_max)
    torque_noise = rng.standard_normal(n_stroke_max)
    speed_noise = rng.standard_normal(n_speed_max)

    setpoint, kp, ki = controller.setpoint_rpm, controller.kp_nm_per_rpm, controller.ki_nm_per_rpm_s
    u_min, u_max = controller.request_min_nm, controller.request_max_nm
    w_set = setpoint / RPM_PER_RAD_S
    w_min, w_max = MIN_SPEED_RATIO * w_set, MAX_SPEED_RATIO * w_set
    # one cylinder's combustion shape per cylinder, index shifted by its firing angle
    shapes = np.array(
        [np.roll(tables.combustion_shape, c * STEPS_PER_STROKE) for c in range(N_CYL)]
    )
    angles = np.arange(1, STEPS_PER_STROKE) * STEP_RAD  # grid points inside a stroke
    longest_stroke = math.pi / w_min

    held = np.full(N_CYL, p.T_loss)
    integral = min(max(p.T_loss / p.K, u_min), u_max)

    def test_torque(t_now: float) -> float:
        """The test-torque request the ECU holds at ``t_now`` (the last one received), N*m."""
        received = int(np.searchsorted(request_t, t_now, side="right"))
        return float(request_nm[received - 1]) if received > 0 else 0.0

    request = integral + test_torque(0.0)
    window = [w_set] * N_WIN
    t = 0.0
    t_control = 0.0
    y = np.array([0.0, w_set, w_set, w_set, 0.0, 0.0, 0.0])
    speed_rows: list[tuple[float, float, float, float, float]] = []
    torque_rows: list[tuple[float, float, int]] = []
    segments = steps = nfev = 0

    def speed_event(t_now: float, delta12: float, delta23: float) -> None:
        nonlocal integral, t_control, request
        n = len(speed_rows)
        measured = sum(window[-N_WIN:]) / N_WIN * RPM_PER_RAD_S + sigma_speed * speed_noise[n]
        if controller.closed_loop:
            error = setpoint - measured
            integral = min(max(integral + ki * error * (t_now - t_control), u_min), u_max)
            command = min(max(kp * error + integral, u_min), u_max)
        else:
            command = integral
        t_control = t_now
        request = command + test_torque(t_now)
        speed_rows.append((t_now, measured, request, delta12, delta23))

    stroke = 0
    while t < plan.end_s:
        # stroke event: the finished cylinder reports, the next one holds K * T_ecu
        if stroke > 0:
            finished = (stroke - 1) % N_CYL
            n = len(torque_rows)
            torque_rows.append((t, held[finished] + sigma_torque * torque_noise[n], finished))
        held[stroke % N_CYL] = p.K * request * (1.0 + sigma_cv * cv_noise[stroke])
        # then the speed sample at the same angle: the new request serves the next stroke
        if stroke > 0:
            speed_event(t, y[4], y[5])

        base = (stroke * STEPS_PER_STROKE) % STEPS_PER_CYCLE
        gas = np.roll(tables.compression + held @ shapes, -base)
        inertia = np.roll(tables.inertia, -base)
        rhs = _stroke_rhs(p, np.append(gas, gas[0]), np.append(inertia, inertia[0]), settings)
        y[0] = 0.0
        sol = solve_ivp(
            rhs,
            (t, t + longest_stroke),
            y,
            method=settings.method,
            rtol=settings.rtol,
            atol=settings.atol,
            events=_stroke_end,
            dense_output=True,
        )
        segments += 1
        steps += len(sol.t) - 1
        nfev += sol.nfev
        if sol.status != 1:
            if sol.status == -1:
                raise RuntimeError(f"solve_ivp failed at t = {t:.4f} s: {sol.message}")
            raise AnalysisError(
                f"the simulated engine fell below {MIN_SPEED_RATIO} times its idle set-point "
                f"near t = {t:.2f} s (solve_ivp)"
            )
        t_next = float(sol.t_events[0][0])
        y_next = np.array(sol.y_events[0][0], dtype=np.float64)
        times, states = _grid_crossings(sol.sol, t, t_next, angles)
        speeds = np.append(states[1], y_next[1])
        if speeds.min() < w_min or speeds.max() > w_max:
            raise AnalysisError(
                f"the simulated engine left {MIN_SPEED_RATIO}..{MAX_SPEED_RATIO} times its idle "
                f"set-point near t = {t:.2f} s (solve_ivp)"
            )
        half = STEPS_PER_SPEED_SAMPLE - 1  # index of the pi/2 grid point in ``angles``
        window.extend(speeds[: half + 1].tolist())
        if times[half] < plan.end_s:
            speed_event(float(times[half]), states[4, half], states[5, half])
        window.extend(speeds[half + 1 :].tolist())
        del window[:-N_WIN]
        t, y = t_next, y_next
        stroke += 1

    speed = np.array(speed_rows, dtype=np.float64).reshape(-1, 5)
    torque = np.array(torque_rows, dtype=np.float64).reshape(-1, 3)
    result = SimulationResult.from_outputs(
        speed, torque, (request_t, request_nm), parameters, plan, options
    )
    stats = SolverStats(
        settings=settings,
        segments=segments,
        steps=steps,
        nfev=nfev,
        wall_s=time.perf_counter() - started,
        simulated_s=plan.end_s,
    )
    return result, stats
