"""Angle-discrete integration of the closed loop of Fig. 1, compiled with numba.

The independent variable is the crank angle phi_1, advanced by exactly ``STEP_RAD`` per step
(eq. 8); the time step is dt = STEP_RAD / omega_1. A step may be split into ``n_sub`` equal
substeps when a parameter set is stiff for the angle step (see
:func:`dtid.simulator.simulate.substeps`); the engine torque is held over them. Two schemes
(``Loop.integration``):

* :data:`EULER`, the default: the smooth forces (springs, dampers, engine torque) act on the
  velocities with their values at the substep's start (symplectic Euler), Coulomb friction acts
  as an impulse (Moreau), then the deflections and the backlash state advance with the new
  velocities. First order in the step: the paper's angle-discrete model as eq. (8) reads, and
  what an independent implementation of the paper evidently integrates too
  (docs/model-assumptions.md).
* :data:`VERLET`: drift-kick-drift (Stormer-Verlet): the deflections advance half the substep,
  the smooth forces kick the velocities with their values at that midpoint (the velocities
  there predicted from the forces at the substep's start, as the dampers' forces depend on
  them), the friction impulse follows, then the deflections advance the other half. Second
  order: a linear three-mass plant's |G_DRV| is within 0.02 dB of the continuous-time response
  at the angle step, where Euler is off by up to 0.3 dB near the resonances of a stiff
  drivetrain at 800 rpm (``tests/test_simulator.py``): the continuous plant, a vehicle.

Events on the angle grid, at the start of a step, in this order:

1. every pi/2 (15 steps): the speed sensor outputs the mean of the last 30 step speeds (eq. 9),
   the ECU's idle controller updates and forms its torque request (see below);
2. every pi (30 steps): the cylinder whose working stroke ends reports its mean torque (the
   cylinder-pressure sensor, once per stroke), then the next cylinder starts its stroke and holds
   T_m = K * T_ecu for its working cycle (eq. 3), T_ecu being the request the ECU formed
   ``latch`` speed samples before (1: the one before this step's, the product ECU's timing).

The ECU's request at a speed sample is the controller's output (``delay`` samples old) plus the
test torque request; the controller acts on the error reference - measured speed (optionally
low-passed): proportional, integral and a filtered derivative of the measured speed (see
:class:`dtid.simulator.controller.IdleController`). A starting stroke takes that request plus its
entry of the *drive*. Reference and drive are indexed by crank angle: ``reference[i]`` is the
reference at the (i+1)-th speed sample of the run (the last entry holds after the end), and
``drive[n]`` the torque added to the n-th stroke's request (the last holds after the end). A
vehicle's own ECU has one reference entry, its set-point, and no drive. The identification's
model of a recorded test instead drives each stroke with the torque request the vehicle's
stroke at that crank angle took, and keeps the simulated speed on the recorded one, sample by
sample, with a slow controller of its own (:mod:`dtid.identification.model.idle_loop`); the test
torque requests are then already in the drive and the request table is empty.

Beyond the paper's plant, the parameter vector carries the mechanisms of
:mod:`dtid.simulator.mechanisms` (a second spring stage, an asymmetric free play, friction
growing with deflection, quadratic damping, a two-stage clutch, gearbox drag, a belt-driven
accessory, a torque lag, a torque-sensor gain, a cylinder imbalance); at their neutral values
each term vanishes and the kernel is the paper's.

A run may be advanced in segments: :func:`advance` continues a state vector made by
:func:`initial_state` (the virtual vehicle steps the plant in real time this way, with the request
it holds); advancing once to the end is :func:`run_plant`.

Kernels return a status and never raise: 0 completed, 1 the engine speed left 0.5..3 times the
set-point (a stall or run-away of a non-physical parameter set), 2 an output buffer filled up.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from dtid.simulator.angle_grid import (
    N_CYL,
    N_WIN,
    RPM_PER_RAD_S,
    STEP_RAD,
    STEPS_PER_CYCLE,
    STEPS_PER_SPEED_SAMPLE,
    STEPS_PER_STROKE,
)
from dtid.simulator.couplings import (
    backlash_torque,
    backlash_update,
    belt_is_rigid,
    dmf_smooth_torque,
    friction_impulse,
    second_stage_torque,
)
from dtid.simulator.mechanisms import (
    P_ASYM12,
    P_C12_2,
    P_C14,
    P_C23_2,
    P_D3,
    P_D12_2,
    P_D14,
    P_G_T,
    P_J4,
    P_KNEE12,
    P_KNEE23,
    P_PHI12_F,
    P_SHARE,
    P_TAU_M,
    P_TC12_2,
)

STATUS_OK = 0
STATUS_SPEED_RANGE = 1
STATUS_BUFFER_FULL = 2

SPEED_COLUMNS = ("t_s", "speed_rpm", "torque_request_nm", "delta12_rad", "delta23_rad")
"""Columns of a kernel's speed-event output: time, filtered speed, T_ecu and the deflections."""
TORQUE_COLUMNS = ("t_s", "mean_torque_nm", "cylinder")
"""Columns of a kernel's stroke-event output."""

MIN_SPEED_RATIO = 0.5
"""The run stops below this fraction of the set-point speed (stall)."""
MAX_SPEED_RATIO = 3.0
"""The run stops above this multiple of the set-point speed (run-away)."""
EULER = 0
"""``Loop.integration``: symplectic Euler, first order (the paper's scheme as eq. 8 reads)."""
VERLET = 1
"""``Loop.integration``: drift-kick-drift with predicted midpoint velocities, second order."""
INTEGRATION: dict[str, int] = {"euler": EULER, "verlet": VERLET}
"""The integration schemes by the name vehicle data and simulation options give them."""
SPEED_AVERAGES = ("times", "speeds")
"""How the speed sensor averages its half revolution, by the name vehicle data and simulation
options give it. ``"times"``, the default: the window's angle over its time, as an engine ECU
computes a crank-synchronous speed from its tooth wheel (the time the crank takes over the
segment, one division); ``"speeds"``: the mean of the step speeds, eq. (9) read literally. Both
have eq. (9)'s frequency response to first order; they differ by the speeds' variance within
the window over their mean, which the firing pulsation makes and the load modulates, so the
chirp's torque leaks into the reported speed differently (docs/model-assumptions.md)."""


# Layout of a controller array (:meth:`dtid.simulator.controller.IdleController.as_array`).
C_SETPOINT, C_KP, C_KI, C_U_MIN, C_U_MAX, C_CLOSED, C_KD, C_D_TAU, C_DELAY, C_LATCH, C_E_TAU = (
    range(11)
)
N_CONTROLLER = 11
N_RING = 8
"""Speed samples of past controller outputs and requests the state keeps (delay and latch are
at most ``N_RING - 1``)."""

# Layout of a plant state vector (see :func:`initial_state`): scalars, then the held mean torque
# of each cylinder, the speed sensor's window of step speeds and their inverses (a tooth timer
# adds up the latter, each divided once when it enters rather than at every sample; kept only
# while the sensor is a tooth timer, which a run does not change), and the
# rings of the controller's past outputs and the ECU's past requests.
S_T, S_T_CONTROL, S_STEP, S_W1, S_W2, S_W3 = 0, 1, 2, 3, 4, 5
S_DELTA12, S_DELTA23, S_BACKLASH, S_INTEGRAL, S_REQUEST, S_WINDOW_SUM, S_WINDOW_POS = (
    6,
    7,
    8,
    9,
    10,
    11,
    12,
)
S_DERIVATIVE, S_LAST_MEASURED, S_RING_POS, S_ERROR = 13, 14, 15, 16
S_LAG, S_W4, S_DELTA14 = 17, 18, 19  # the torque_lag and accessory_mode mechanisms' states
N_SCALARS = 20
O_HELD = N_SCALARS
O_WINDOW = O_HELD + N_CYL
O_INVERSES = O_WINDOW + N_WIN
O_COMMANDS = O_INVERSES + N_WIN
O_REQUESTS = O_COMMANDS + N_RING
STATE_SIZE = O_REQUESTS + N_RING
"""Length of a plant state vector."""


class Loop(NamedTuple):
    """What every job of a run shares: the engine's tables, the ECU and what drives it.

    Built in one place, :meth:`dtid.simulator.simulate.SimulationOptions.loop`.

    Attributes
    ----------
    combustion_shape, compression, inertia
        Engine tables of :class:`dtid.simulator.engine.EngineTables`.
    controller
        :meth:`dtid.simulator.controller.IdleController.as_array` (layout ``C_*``).
    reference
        (>= 1,) the controller's reference speed per speed sample of the run, rpm (the last
        holds after the end).
    drive
        Torque added to each stroke's request, per stroke of the run, N*m (the last holds after
        the end; empty: none).
    request_t, request_nm
        Test-torque requests as the ECU receives them: times (s, increasing) and values (N*m);
        the ECU holds the last one received at each speed sample (zero before the first).
    sigmas
        Standard deviations: relative combustion variation of T_m, speed noise in rpm, torque
        noise in N*m; then 1 for a speed sensor that averages times (a tooth timer: the
        window's angle over its time) instead of the step speeds (eq. 9), if given.
    integration
        :data:`EULER` or :data:`VERLET` (see the module notes).
    cylinder_offset
        Where the run's first stroke falls in the firing order: stroke ``k`` of the run is fired
        by the cylinder of ``cylinder_imbalance`` when ``(k + cylinder_offset) % N_CYL == 0``
        (0 for a test simulated from its start; a model repeating a recording from a stroke in
        mid-cycle takes it from the recording, :meth:`dtid.identification.model.idle_loop.
        IdleLoop.cylinder_offset`).
    """

    combustion_shape: np.ndarray
    compression: np.ndarray
    inertia: np.ndarray
    controller: np.ndarray
    reference: np.ndarray
    drive: np.ndarray
    request_t: np.ndarray
    request_nm: np.ndarray
    sigmas: np.ndarray
    integration: int = EULER
    cylinder_offset: int = 0


class Job(NamedTuple):
    """One run of the plant: its parameters, scale, substeps, noise draws and outputs.

    :class:`Jobs` holds many, each field with a leading job axis.

    Attributes
    ----------
    params
        Drivetrain parameters in the order of :data:`dtid.simulator.parameters.NAMES`, then the
        mechanisms' (:data:`dtid.simulator.mechanisms.EXTRA_NAMES`), SI units.
    request_scale
        Factor on the request values (a unit chirp scaled to an amplitude).
    n_sub
        Substeps per angle step (>= 1).
    cv_noise
        Standard normal draws, one per working stroke started.
    speed_noise
        Standard normal draws, one per speed sample.
    torque_noise
        Standard normal draws, one per stroke reported.
    out_speed
        Output (n_max, 5), columns :data:`SPEED_COLUMNS`, from row 0.
    out_torque
        Output (n_max, 3), columns :data:`TORQUE_COLUMNS`, from row 0.
    """

    params: np.ndarray
    request_scale: float
    n_sub: int
    cv_noise: np.ndarray
    speed_noise: np.ndarray
    torque_noise: np.ndarray
    out_speed: np.ndarray
    out_torque: np.ndarray


class Jobs(NamedTuple):
    """Many :class:`Job` s for :func:`run_plant_batch`: each field of a job with a leading job
    axis (``request_scale`` and ``n_sub`` as arrays), but the noise draws: jobs share their
    rows (common random numbers), and ``noise_row`` gives each job's row of ``cv_noise``,
    ``speed_noise`` and ``torque_noise``."""

    params: np.ndarray
    request_scale: np.ndarray
    n_sub: np.ndarray
    noise_row: np.ndarray
    cv_noise: np.ndarray
    speed_noise: np.ndarray
    torque_noise: np.ndarray
    out_speed: np.ndarray
    out_torque: np.ndarray


@numba.njit(cache=True, nogil=True)
def initial_state(params: np.ndarray, loop: Loop, test_nm: float) -> np.ndarray:
    """The plant at rest at its reference speed, t = 0, before the first angle step.

    All masses turn at the first reference speed w_set, the couplings are relaxed and the
    engine delivers the plant's mean load at that speed, T_loss on J1 plus a gearbox drag's
    d3 * w_set on J3 (N*m): every cylinder holds it, the integrator holds what balances it
    with the drive's mean (load / K - mean drive, within the controller's limits) and the ECU's
    request is that plus ``test_nm``, the test torque held at t = 0 (N*m). Without the drag's
    share the plant starts that torque short: a vehicle's idle controller takes it up within
    seconds, the identification's slow speed-tracking loop not within a run (2 N*m left a model
    of the reference 40 rpm below its recording).
    """
    controller, reference, drive = loop.controller, loop.reference, loop.drive
    t_loss, gain = params[10], params[11]
    u_min, u_max = controller[C_U_MIN], controller[C_U_MAX]
    w_set = reference[0] / RPM_PER_RAD_S
    load = t_loss + params[P_D3] * w_set
    mean_drive = np.mean(drive) if drive.shape[0] > 0 else 0.0
    state = np.zeros(STATE_SIZE)
    state[S_W1] = w_set
    state[S_W2] = w_set
    state[S_W3] = w_set
    state[S_W4] = w_set
    state[S_LAG] = load
    integral = min(max(load / gain - mean_drive, u_min), u_max)
    state[S_INTEGRAL] = integral
    state[S_REQUEST] = integral + test_nm
    state[S_LAST_MEASURED] = reference[0]
    state[O_HELD:O_WINDOW] = load
    state[O_WINDOW:O_INVERSES] = w_set
    state[O_INVERSES:O_COMMANDS] = 1.0 / w_set
    state[O_COMMANDS:O_REQUESTS] = integral
    state[O_REQUESTS:] = state[S_REQUEST]
    state[S_WINDOW_SUM] = N_WIN * w_set
    return state


@numba.njit(cache=True, inline="always")
def _torques(
    net: float,
    delta12: float,
    delta23: float,
    delta14: float,
    backlash: float,
    w1: float,
    w2: float,
    w3: float,
    w4: float,
    coupling: tuple,
) -> tuple[float, float, float, float]:
    """Net smooth torque on J1, J2, J3 and J4, N*m (Coulomb friction is the step's impulse).

    Parameters
    ----------
    net
        Engine torque less the loss torque on J1, N*m.
    delta12, delta23, delta14
        Deflections phi1 - phi2, phi2 - phi3 and phi1 - phi4, rad.
    backlash
        The gear play's backlash state, rad.
    w1, w2, w3, w4
        Angular velocities, rad/s.
    coupling
        The DMF's c12, d12, half play, play centre, second stage (stiffness, knee) and
        quadratic damping; the gear coupling's c23, d23, half play and second stage; the
        gearbox drag d3; the belt's c14 and d14 (SI units, in this order; zeros where a
        mechanism is absent).
    """
    c12, d12, half12, shift12, c12_2, knee12, d12_2 = coupling[:7]
    c23, d23, half23, c23_2, knee23, d3, c14, d14 = coupling[7:]
    rate12 = w1 - w2
    centred12 = delta12 - shift12
    torque12 = dmf_smooth_torque(centred12, rate12, c12, d12, half12)
    if c12_2 > 0.0:
        spring12 = centred12 - max(min(centred12, half12), -half12)
        torque12 += second_stage_torque(spring12, c12_2, knee12)
    if d12_2 > 0.0:
        torque12 += d12_2 * rate12 * abs(rate12)
    torque23 = backlash_torque(delta23, w2 - w3, backlash, c23, d23, half23, c23_2, knee23)
    torque14 = c14 * delta14 + d14 * (w1 - w4)  # accessory_mode: J4 on J1 through the belt
    return net - torque12 - torque14, torque12 - torque23, torque23 - d3 * w3, torque14


@numba.njit(cache=True, nogil=True)
def advance(state: np.ndarray, loop: Loop, job: Job, t_end: float) -> tuple[int, int, int]:
    """Advance the plant from ``state`` until its time reaches ``t_end``; update ``state``.

    Parameters
    ----------
    state
        Plant state (:func:`initial_state`), updated in place to the first angle step at or
        after ``t_end``, so that consecutive calls continue one run exactly.
    loop
        The engine, the ECU and what drives it (:class:`Loop`).
    job
        The run's parameters, noise draws (those of this call: one per stroke started, per
        speed sample and per stroke reported) and outputs (:class:`Job`).
    t_end
        Time to advance to, s.

    Returns
    -------
    tuple of int
        Number of speed samples, number of torque samples, status.
    """
    combustion_shape, compression, inertia = loop.combustion_shape, loop.compression, loop.inertia
    controller, reference, drive, sigmas = loop.controller, loop.reference, loop.drive, loop.sigmas
    request_t, request_nm = loop.request_t, loop.request_nm
    params, request_scale, n_sub = job.params, job.request_scale, job.n_sub
    cv_noise, speed_noise, torque_noise = job.cv_noise, job.speed_noise, job.torque_noise
    out_speed, out_torque = job.out_speed, job.out_torque
    j1, j2, j3 = params[0], params[1], params[2]
    c12, c23, d12, d23 = params[3], params[4], params[5], params[6]
    tc12, half12, half23 = params[7], 0.5 * params[8], 0.5 * params[9]
    t_loss, gain = params[10], params[11]
    j4, c14, d14 = params[P_J4], params[P_C14], params[P_D14]
    if j4 > 0.0 and belt_is_rigid(j1, j4, c14):  # accessory_mode: moves with the crank
        j1, j4 = j1 + j4, 0.0
    inv1, inv2, inv3 = 1.0 / j1, 1.0 / j2, 1.0 / j3
    c12_2, knee12, d12_2 = params[P_C12_2], params[P_KNEE12], params[P_D12_2]
    shift12 = params[P_ASYM12] * half12  # the free play's centre, asymmetric_play
    tc12_2, phi12_f = params[P_TC12_2], params[P_PHI12_F]
    c23_2, knee23, d3 = params[P_C23_2], params[P_KNEE23], params[P_D3]
    inv4 = 1.0 / j4 if j4 > 0.0 else 0.0
    belt_c, belt_d = (c14, d14) if j4 > 0.0 else (0.0, 0.0)
    dmf = (c12, d12, half12, shift12, c12_2, knee12, d12_2)
    coupling = (*dmf, c23, d23, half23, c23_2, knee23, d3, belt_c, belt_d)
    verlet = loop.integration == VERLET
    odd = loop.cylinder_offset
    tau_m, sensor_gain, share = params[P_TAU_M], params[P_G_T], params[P_SHARE]
    kp, ki, kd, d_tau = controller[C_KP], controller[C_KI], controller[C_KD], controller[C_D_TAU]
    u_min, u_max, closed = controller[C_U_MIN], controller[C_U_MAX], controller[C_CLOSED] > 0.5
    delay, latch, e_tau = int(controller[C_DELAY]), int(controller[C_LATCH]), controller[C_E_TAU]
    sigma_cv, sigma_speed, sigma_torque = sigmas[0], sigmas[1], sigmas[2]
    by_times = sigmas.shape[0] > 3 and sigmas[3] > 0.5

    w_set = controller[C_SETPOINT] / RPM_PER_RAD_S
    w_min, w_max = MIN_SPEED_RATIO * w_set, MAX_SPEED_RATIO * w_set
    t = state[S_T]
    t_control = state[S_T_CONTROL]
    step = int(state[S_STEP])
    w1, w2, w3 = state[S_W1], state[S_W2], state[S_W3]
    w4, delta14, lagged = state[S_W4], state[S_DELTA14], state[S_LAG]
    delta12, delta23, backlash = state[S_DELTA12], state[S_DELTA23], state[S_BACKLASH]
    integral, request = state[S_INTEGRAL], state[S_REQUEST]
    derivative, last_measured = state[S_DERIVATIVE], state[S_LAST_MEASURED]
    error = state[S_ERROR]
    window_sum, window_pos = state[S_WINDOW_SUM], int(state[S_WINDOW_POS])
    ring_pos = int(state[S_RING_POS])
    held = state[O_HELD:O_WINDOW]  # views: updated in place
    window = state[O_WINDOW:O_INVERSES]
    inverses = state[O_INVERSES:O_COMMANDS]
    commands = state[O_COMMANDS:O_REQUESTS]
    requests = state[O_REQUESTS:]
    n_requests = request_t.shape[0]
    received = 0  # requests received so far
    n_reference, n_drive = reference.shape[0], drive.shape[0]

    # each cylinder's combustion shape (eq. 2) at each angle of the cycle, looked up once here
    # rather than by a modulo per cylinder and step (an eighth of the step's time)
    firing_shape = np.empty((STEPS_PER_CYCLE, N_CYL))
    for angle in range(STEPS_PER_CYCLE):
        for cylinder in range(N_CYL):
            shifted = (angle - cylinder * STEPS_PER_STROKE) % STEPS_PER_CYCLE
            firing_shape[angle, cylinder] = combustion_shape[shifted]

    n_speed = 0
    n_torque = 0
    n_started = 0
    max_speed = min(out_speed.shape[0], speed_noise.shape[0])
    max_strokes = min(out_torque.shape[0], cv_noise.shape[0], torque_noise.shape[0])
    status = STATUS_OK
    while t < t_end:
        angle_index = step % STEPS_PER_CYCLE
        if step % STEPS_PER_SPEED_SAMPLE == 0 and step > 0:
            if n_speed >= max_speed:
                status = STATUS_BUFFER_FULL
                break
            if by_times:  # a tooth timer: the window's angle over its time
                window_time = 0.0
                for k in range(N_WIN):
                    window_time += inverses[k]
                mean_speed = N_WIN / window_time
            else:
                mean_speed = window_sum / N_WIN
            measured = mean_speed * RPM_PER_RAD_S + sigma_speed * speed_noise[n_speed]
            sample = min(step // STEPS_PER_SPEED_SAMPLE, n_reference) - 1
            elapsed = t - t_control
            if closed:
                error += (reference[sample] - measured - error) * (
                    1.0 if e_tau <= 0.0 else elapsed / (e_tau + elapsed)
                )
                integral = min(max(integral + ki * error * elapsed, u_min), u_max)
                if kd > 0.0 and elapsed > 0.0:
                    rate = (last_measured - measured) / elapsed
                    derivative += (rate - derivative) * elapsed / (d_tau + elapsed)
                command = min(max(kp * error + integral + kd * derivative, u_min), u_max)
            else:
                command = integral
            last_measured = measured
            t_control = t
            ring_pos = (ring_pos + 1) % N_RING
            commands[ring_pos] = command
            while received < n_requests and request_t[received] <= t:
                received += 1
            test = request_scale * request_nm[received - 1] if received > 0 else 0.0
            request = commands[(ring_pos - delay) % N_RING] + test
            requests[ring_pos] = request
            out_speed[n_speed, 0] = t
            out_speed[n_speed, 1] = measured
            out_speed[n_speed, 2] = request
            if n_drive > 0:  # T_ecu as the next stroke would take it
                out_speed[n_speed, 2] += drive[min((step + 1) // STEPS_PER_STROKE, n_drive - 1)]
            out_speed[n_speed, 3] = delta12
            out_speed[n_speed, 4] = delta23
            n_speed += 1
        if step % STEPS_PER_STROKE == 0:
            stroke = step // STEPS_PER_STROKE
            if n_started >= max_strokes:
                status = STATUS_BUFFER_FULL
                break
            if stroke > 0:
                finished = (stroke - 1) % N_CYL
                out_torque[n_torque, 0] = t
                out_torque[n_torque, 1] = (
                    sensor_gain * held[finished] + sigma_torque * torque_noise[n_torque]
                )
                out_torque[n_torque, 2] = finished
                n_torque += 1
            latched = requests[(ring_pos - latch) % N_RING]
            if n_drive > 0:
                latched += drive[min(stroke, n_drive - 1)]
            target = gain * latched
            if tau_m > 0.0:  # torque_lag: one stroke of pi towards the target
                stroke_s = STEPS_PER_STROKE * STEP_RAD / w1
                lagged += (target - lagged) * (1.0 - math.exp(-stroke_s / tau_m))
                target = lagged
            if share != 0.0:  # cylinder_imbalance: the first cylinder's excess
                odd_one = (stroke + odd) % N_CYL == 0
                target *= 1.0 + share if odd_one else 1.0 - share / (N_CYL - 1)
            held[stroke % N_CYL] = target * (1.0 + sigma_cv * cv_noise[n_started])
            n_started += 1

        if w1 < w_min or w1 > w_max:
            status = STATUS_SPEED_RANGE
            break
        dt = STEP_RAD / w1
        engine = compression[angle_index] + inertia[angle_index] * w1 * w1
        for cylinder in range(N_CYL):
            engine += held[cylinder] * firing_shape[angle_index, cylinder]
        net = engine - t_loss
        h = dt if n_sub == 1 else dt / n_sub  # the same bits; no division on the common path
        drift = 0.5 * h if verlet else 0.0  # before the kick; h - drift after it
        for _ in range(n_sub):
            mid12, mid23, mid14 = delta12, delta23, delta14
            if verlet:
                mid12 += drift * (w1 - w2)
                mid23 += drift * (w2 - w3)
                mid14 += drift * (w1 - w4)
            f1, f2, f3, f4 = _torques(net, mid12, mid23, mid14, backlash, w1, w2, w3, w4, coupling)
            if verlet:  # the forces at the midpoint velocities, predicted with these
                f1, f2, f3, f4 = _torques(
                    net,
                    mid12,
                    mid23,
                    mid14,
                    backlash,
                    w1 + drift * inv1 * f1,
                    w2 + drift * inv2 * f2,
                    w3 + drift * inv3 * f3,
                    w4 + drift * inv4 * f4,
                    coupling,
                )
            w1 += h * inv1 * f1
            w2 += h * inv2 * f2
            w3 += h * inv3 * f3
            if j4 > 0.0:
                w4 += h * inv4 * f4
            friction = tc12
            if tc12_2 > 0.0 and abs(mid12 - shift12) > phi12_f:  # friction_hysteresis
                friction += tc12_2
            impulse = friction_impulse(w1 - w2, inv1, inv2, friction, h)
            w1 -= impulse * inv1
            w2 += impulse * inv2
            delta12 = mid12 + (h - drift) * (w1 - w2)
            if j4 > 0.0:
                delta14 = mid14 + (h - drift) * (w1 - w4)
            delta23_old = delta23
            delta23 = mid23 + (h - drift) * (w2 - w3)
            backlash = backlash_update(delta23, delta23_old, backlash, c23, d23, half23, h)

        window_sum += w1 - window[window_pos]
        window[window_pos] = w1
        if by_times:
            inverses[window_pos] = 1.0 / w1
        window_pos = (window_pos + 1) % N_WIN
        t += dt
        step += 1
    state[S_T], state[S_T_CONTROL], state[S_STEP] = t, t_control, step
    state[S_W1], state[S_W2], state[S_W3] = w1, w2, w3
    state[S_W4], state[S_DELTA14], state[S_LAG] = w4, delta14, lagged
    state[S_DELTA12], state[S_DELTA23], state[S_BACKLASH] = delta12, delta23, backlash
    state[S_INTEGRAL], state[S_REQUEST] = integral, request
    state[S_DERIVATIVE], state[S_LAST_MEASURED] = derivative, last_measured
    state[S_ERROR] = error
    state[S_WINDOW_SUM], state[S_WINDOW_POS] = window_sum, window_pos
    state[S_RING_POS] = ring_pos
    return n_speed, n_torque, status


@numba.njit(cache=True, nogil=True)
def run_plant(loop: Loop, job: Job, t_end: float) -> tuple[int, int, int]:
    """Simulate one test from rest at the set-point; fill the job's outputs.

    :func:`initial_state` followed by one :func:`advance` to ``t_end``; see there for the
    parameters.

    Returns
    -------
    tuple of int
        Number of speed samples, number of torque samples, status.
    """
    request_t, request_nm = loop.request_t, loop.request_nm
    n_zero = 0  # requests received before the first step
    while n_zero < request_t.shape[0] and request_t[n_zero] <= 0.0:
        n_zero += 1
    test = job.request_scale * request_nm[n_zero - 1] if n_zero > 0 else 0.0
    state = initial_state(job.params, loop, test)
    return advance(state, loop, job, t_end)


@numba.njit(cache=True, parallel=True, nogil=True)
def run_plant_batch(loop: Loop, jobs: Jobs, t_end: float, counts: np.ndarray) -> None:
    """Run :func:`run_plant` for many jobs in parallel over the cores.

    All jobs share the ``loop``; ``counts`` (n, 3) receives each job's speed count, torque
    count and status.
    """
    for j in numba.prange(jobs.params.shape[0]):
        row = jobs.noise_row[j]
        job = Job(
            jobs.params[j],
            jobs.request_scale[j],
            jobs.n_sub[j],
            jobs.cv_noise[row],
            jobs.speed_noise[row],
            jobs.torque_noise[row],
            jobs.out_speed[j],
            jobs.out_torque[j],
        )
        n_speed, n_torque, status = run_plant(loop, job, t_end)
        counts[j, 0] = n_speed
        counts[j, 1] = n_torque
        counts[j, 2] = status
