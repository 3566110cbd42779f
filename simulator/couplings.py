"""Physics of the two drivetrain couplings of eq. (6), shared by every integrator.

* DMF, J1-J2: arc spring with a symmetric free play (dead zone, eq. 7), viscous damping acting
  always, and Coulomb friction Tc12 * sign(d delta12/dt).
* Clutch/gear, J2-J3: spring-damper in series with gear play, the physical backlash model of
  Nordin, Galic and Gutman (1997), the paper's ref. [15]. Its state is the backlash position
  b in [-eps23/2, +eps23/2]; the shaft twist is delta23 - b. Inside the gap the backlash moves so
  that the spring-damper transmits no torque, c (delta - b) + d (d delta/dt - db/dt) = 0, i.e. the
  twist relaxes with rate c/d; in contact b sits on a stop and the torque may only push.

Coulomb friction is applied as an impulse after the smooth forces of a time step (Moreau's
time-stepping): the friction impulse removes the relative velocity if at most Tc12 * h can do it
(stick), otherwise it is Tc12 * h against the sliding direction (slip). This is exact for stick,
needs no regularised sign and is stable at any step.

All functions are numba-compiled and callable from Python as well.
"""

from __future__ import annotations

import math

import numba


@numba.njit(cache=True, inline="always")
def dead_zone(delta: float, half_play: float) -> float:
    """Spring deflection beyond a symmetric free play, eq. (7): delta - eps(delta), rad."""
    if delta > half_play:
        return delta - half_play
    if delta < -half_play:
        return delta + half_play
    return 0.0


@numba.njit(cache=True, inline="always")
def dmf_smooth_torque(
    delta12: float, rate12: float, c12: float, d12: float, half_play12: float
) -> float:
    """DMF torque from J1 to J2 without friction, N*m.

    Parameters
    ----------
    delta12
        Deflection phi1 - phi2, rad.
    rate12
        Its time derivative, rad/s.
    c12, d12
        Arc-spring stiffness, N*m/rad, and damping, N*m*s/rad.
    half_play12
        Half the free-play width, rad.
    """
    return c12 * dead_zone(delta12, half_play12) + d12 * rate12


@numba.njit(cache=True, inline="always")
def second_stage_torque(deflection: float, stiffness: float, knee: float) -> float:
    """Torque of a spring's second stage: ``stiffness`` times the deflection beyond ``knee``,
    N*m (the ``progressive_spring`` and ``clutch_two_stage`` mechanisms).

    Parameters
    ----------
    deflection
        The first stage's spring deflection (beyond any free play), rad.
    stiffness
        Stiffness the second stage adds, N*m/rad (0: none).
    knee
        Deflection where it engages, rad.
    """
    if stiffness <= 0.0:
        return 0.0
    return stiffness * dead_zone(deflection, knee)


BELT_RIGID_HZ = 100.0
"""Belt mode (Hz) above which an accessory moves with the crank: :func:`belt_is_rigid`."""


@numba.njit(cache=True, inline="always")
def belt_is_rigid(j1: float, j4: float, c14: float) -> bool:
    """Whether a belt-driven accessory (``accessory_mode``) is lumped into the crank's inertia.

    Its belt mode, sqrt(c14 (1/J4 + 1/J1)), above :data:`BELT_RIGID_HZ`: below 15 Hz such a
    mode adds J4 (1 + (f/f4)^2) to J1, within 2.3 % of J4 itself, while the explicit step
    would need ever more substeps to follow it (a search passing J4 -> 0 at a finite belt
    stiffness asked for thousands per step).

    Parameters
    ----------
    j1, j4
        Crank-side and accessory inertia, kg*m^2 (j4 > 0).
    c14
        Belt stiffness reflected to the crank, N*m/rad.
    """
    limit = 2.0 * math.pi * BELT_RIGID_HZ
    return c14 * (1.0 / j4 + 1.0 / j1) > limit * limit


@numba.njit(cache=True, inline="always")
def friction_impulse(
    rate12: float, inv_j1: float, inv_j2: float, friction: float, h: float
) -> float:
    """Coulomb friction impulse from J1 to J2 over a step, N*m*s (Moreau time-stepping).

    Parameters
    ----------
    rate12
        Relative velocity omega1 - omega2 after the smooth forces of the step, rad/s.
    inv_j1, inv_j2
        Inverse inertias, 1/(kg*m^2).
    friction
        Coulomb torque Tc12, N*m.
    h
        Time step, s.

    Returns
    -------
    float
        Impulse P: omega1 -= P/J1, omega2 += P/J2. It sticks the two masses together when
        |P| <= Tc12 * h suffices, and is +-Tc12 * h otherwise.
    """
    stick = rate12 / (inv_j1 + inv_j2)
    limit = friction * h
    if stick > limit:
        return limit
    if stick < -limit:
        return -limit
    return stick


@numba.njit(cache=True, inline="always")
def backlash_torque(
    delta23: float,
    rate23: float,
    backlash: float,
    c23: float,
    d23: float,
    half_play23: float,
    c23_2: float = 0.0,
    knee23: float = 0.0,
) -> float:
    """Torque from J2 to J3 through the spring-damper in series with gear play, N*m.

    Parameters
    ----------
    delta23
        Deflection phi2 - phi3, rad.
    rate23
        Its time derivative, rad/s.
    backlash
        Backlash state b, rad, within [-half_play23, +half_play23].
    c23, d23
        Stiffness, N*m/rad, and damping, N*m*s/rad, of the coupling.
    half_play23
        Half the gear-play width, rad.
    c23_2, knee23
        A second stage (``clutch_two_stage``): stiffness added beyond a twist of ``knee23``,
        N*m/rad and rad; none by default.
    """
    twist = delta23 - backlash
    torque = c23 * twist + second_stage_torque(twist, c23_2, knee23) + d23 * rate23
    if half_play23 <= 0.0:
        return torque
    if backlash >= half_play23:
        return max(torque, 0.0)
    if backlash <= -half_play23:
        return min(torque, 0.0)
    return 0.0


@numba.njit(cache=True, inline="always")
def backlash_update(
    delta23_new: float,
    delta23_old: float,
    backlash: float,
    c23: float,
    d23: float,
    half_play23: float,
    h: float,
) -> float:
    """Advance the backlash state over a step in which delta23 went from old to new.

    Inside the gap the twist delta - b relaxes exactly as exp(-c23/d23 * h) (zero torque); if
    that would carry b past a stop, b rests on the stop (contact). With d23 = 0 the twist vanishes
    at once and the coupling is a dead-zone spring.

    Returns
    -------
    float
        The new backlash state b, rad.
    """
    if half_play23 <= 0.0:
        return 0.0
    twist = delta23_old - backlash
    if d23 > 0.0:
        twist *= math.exp(-c23 / d23 * h)
    else:
        twist = 0.0
    candidate = delta23_new - twist
    if candidate > half_play23:
        return half_play23
    if candidate < -half_play23:
        return -half_play23
    return candidate
