"""The identification setups 1-4 of section IV-B, on simulated data, with their profiles (Fig. 5).

As in the paper, the reference data come from the simulation model with known parameters (no
noise: these setups are about structural identifiability), every free parameter is bounded by
+-100 % of its true value, so the truth sits at 0.5 of the normalised range, and each profile has
seven equidistant points. The two-mass system of setups 1-3 is the three-mass model with the
clutch coupling removed (c23 = d23 = eps23 = 0, J3 a sliver that hangs free) and no friction.

1. Two masses without free play, one test signal; theta = {J_sum, x, c, d, K}, the FRF taken from
   the torque request so that K scales it (eq. 18).
2. Two masses with free play, one test signal; theta = {J_sum, x, c, d, eps}.
3. As 2 with two test signals.
4. The three-mass system with two test signals; the ten parameters of setup 4.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtid.acquisition.plan import TestPlan
from dtid.identification.frf.closed_loop import estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.model.response import ModelTest
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.analytic import inseparable
from dtid.identification.search.objective import Objective
from dtid.identification.search.parameterization import (
    MIN_INERTIA_FRACTION,
    THETA_NAMES,
    Parameterization,
    theta_from_parameters,
)
from dtid.identification.search.runs import amplitude_levels
from dtid.identification.uncertainty.profile import Profile, profile, with_structure
from dtid.simulator.controller import IdleController
from dtid.simulator.parameters import DrivetrainParameters, reference_parameters
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_data import VehicleData

DETACHED_J3_FRACTION = 0.002
"""J3 of the two-mass setups as a fraction of the total inertia (it hangs free: c23 = 0)."""


@dataclass(frozen=True)
class Setup:
    """One identification setup of section IV-B.

    Attributes
    ----------
    number
        1 to 4.
    truth
        The simulated drivetrain.
    free
        The profiled parameters (setup-4 names; ``x1`` is the paper's x; ``K`` for setup 1).
    amplitudes_nm
        The test signals.
    request_input
        True for setup 1: the FRF from the torque request, so K enters it.
    """

    number: int
    truth: DrivetrainParameters
    free: tuple[str, ...]
    amplitudes_nm: tuple[float, ...]
    request_input: bool = False


def two_mass(reference: DrivetrainParameters, free_play: bool) -> DrivetrainParameters:
    """The reference as a two-mass system: J3 detached, clutch coupling and friction removed."""
    j_sum = reference.J1 + reference.J2 + reference.J3
    return reference.replace(
        J2=reference.J2 + reference.J3 - DETACHED_J3_FRACTION * j_sum,
        J3=DETACHED_J3_FRACTION * j_sum,
        c23=0.0,
        d23=0.0,
        eps23=0.0,
        Tc12=0.0,
        eps12=reference.eps12 if free_play else 0.0,
    )


def setup(number: int, reference: DrivetrainParameters | None = None) -> Setup:
    """Setup 1, 2, 3 or 4 of section IV-B for a reference drivetrain."""
    reference = reference or reference_parameters()
    if number == 1:
        return Setup(
            1, two_mass(reference, False), ("J_sum", "x1", "c12", "d12", "K"), (5.0,), True
        )
    if number == 2:
        return Setup(2, two_mass(reference, True), ("J_sum", "x1", "c12", "d12", "eps12"), (5.0,))
    if number == 3:
        free = ("J_sum", "x1", "c12", "d12", "eps12")
        return Setup(3, two_mass(reference, True), free, (5.0, 10.0))
    if number == 4:
        return Setup(4, reference, THETA_NAMES, (5.0, 10.0))
    raise ValueError(f"setup must be 1, 2, 3 or 4, got {number}")


PAPER_SENSOR = VehicleData(speed_average="speeds")
"""The setups' speed sensor: eq. (9)'s mean of the step speeds, the paper's. Its analysis
(section IV) holds for that linear sensor; a tooth timer (the product's default) adds the step
speeds' variance over their mean, which the pulsation makes at its absolute size, and so breaks
setup 1's scaling of J_sum, c, d and K: its J_sum profile was no longer flat (2026-12-01)."""
SETUP_GENERATIONS = 25
SETUP_POLISH = 300
"""Re-optimisation budget per profile point: compensating moves near the bounds (setup 1) need
more than the default to be found."""


def profile_setup(
    chosen: Setup, points: int = 7, seed: int = 0, duration_s: float = 60.0, refine: int = 0
) -> dict[str, Profile]:
    """Simulate the setup's reference data and profile every free parameter around the truth.

    Setup 2's stiffness and free play get the verdict ``no`` of eq. (22) (one amplitude), as the
    paper concludes, whatever their profiles' intervals. Data and model have the paper's own
    speed sensor, eq. (9) (:data:`PAPER_SENSOR`)."""
    plan = TestPlan(amplitudes_nm=chosen.amplitudes_nm, validation_nm=0.0, duration_s=duration_s)
    options = SimulationOptions.clean(speed_average=PAPER_SENSOR.speed_average)
    data = from_simulation(simulate(chosen.truth, plan, options))
    estimates = tuple(estimate_frf(data, run) for run in find_runs(data.test_torque))
    theta = theta_from_parameters(chosen.truth)
    fixed = {name: theta[name] for name in THETA_NAMES if name not in chosen.free}
    gain = chosen.truth.K
    par = Parameterization.around(
        chosen.truth,
        chosen.truth.T_loss,
        gain,
        fixed=fixed,
        gain_bounds=(MIN_INERTIA_FRACTION * gain, 2 * gain) if "K" in chosen.free else None,
    )
    test = ModelTest(
        data.test_torque,
        estimates,
        IdleController().setpoint_rpm,
        vehicle=PAPER_SENSOR,
        input="request" if chosen.request_input else "torque",
    )
    measured = [e.req_db if chosen.request_input else e.drv_db for e in estimates]
    objective = Objective(par, [test], [measured])
    optimum = par.unit(np.array([[theta[n] for n in THETA_NAMES]]), gain)[0]
    profiles = {
        name: profile(
            objective,
            measured,
            name,
            optimum,
            points=points,
            seed=seed,
            refine=refine,
            generations=SETUP_GENERATIONS,
            polish_evaluations=SETUP_POLISH,
        )
        for name in par.free
    }
    return with_structure(
        profiles, inseparable(par.free, len(amplitude_levels(chosen.amplitudes_nm)))
    )
