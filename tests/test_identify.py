"""Identification core: K and T_loss from the data, and the search on a reduced problem."""

from __future__ import annotations

import pytest

from identification.identify import SearchSettings, engine_gain, identify, split_runs
from identification.parameterization import THETA_NAMES, Parameterization, theta_from_parameters
from identification.start_values import start_theta
from identification.test_setup import MeasuredTest
from identification.testdata import from_simulation
from simulator.chirp import TestPlan
from simulator.parameters import DrivetrainParameters
from simulator.simulate import SimulationOptions, simulate


@pytest.fixture(scope="module")
def softer_dmf(reference: DrivetrainParameters) -> tuple[DrivetrainParameters, MeasuredTest]:
    truth = reference.replace(c12=1.2 * reference.c12, eps12=1.2 * reference.eps12)
    plan = TestPlan(amplitudes_nm=(2.0, 5.0, 10.0), duration_s=30.0)
    data = from_simulation(simulate(truth, plan, SimulationOptions.clean()))
    return truth, MeasuredTest.from_data("clean", data, 0.25)


def test_operating_point_and_split(softer_dmf: tuple) -> None:
    truth, measured = softer_dmf
    assert engine_gain([measured]) == pytest.approx(truth.K, rel=0.01)
    assert measured.idle_torque_nm == pytest.approx(truth.T_loss, rel=0.01)
    ident, valid = split_runs([measured])
    assert [measured.estimates[i].run.amplitude_nm for i in ident[0]] == pytest.approx([5, 10])
    assert [measured.estimates[i].run.amplitude_nm for i in valid[0]] == pytest.approx([2])


def _identify_two(
    reference: DrivetrainParameters,
    truth: DrivetrainParameters,
    measured: MeasuredTest,
    free: tuple[str, str],
):
    theta = theta_from_parameters(truth)
    fixed = {name: theta[name] for name in THETA_NAMES if name not in free}
    par = Parameterization.around(
        reference, measured.idle_torque_nm, engine_gain([measured]), fixed=fixed
    )
    ident, valid = split_runs([measured])
    start = start_theta([measured.estimates[i] for i in ident[0]], reference)
    return identify(
        [measured],
        par,
        ident,
        valid,
        SearchSettings(popsize=8, generations=12, polish_evaluations=80),
        start=start,
    )


def test_linear_stiffness_and_damping_recovered(reference: DrivetrainParameters) -> None:
    """Without free play and friction the objective is smooth: c12 and d12 come back exactly."""
    linear = reference.replace(eps12=0.0, eps23=0.0, Tc12=0.0)
    truth = linear.replace(c12=1.3 * linear.c12, d12=0.7 * linear.d12)
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), duration_s=30.0)
    data = from_simulation(simulate(truth, plan, SimulationOptions.clean()))
    measured = MeasuredTest.from_data("linear", data, 0.25)
    result = _identify_two(linear, truth, measured, ("c12", "d12"))
    assert result.theta["c12"] == pytest.approx(truth.c12, rel=1e-3)
    assert result.theta["d12"] == pytest.approx(truth.d12, rel=1e-2)  # the shallowest profile
    assert max(result.fit_nrmse.values()) < 0.01


def test_stiffness_and_play_recovered_with_the_rest_fixed(
    reference: DrivetrainParameters, softer_dmf: tuple
) -> None:
    """Two amplitudes separate c12 from eps12 (eq. 23): both come back from a 20 % offset."""
    truth, measured = softer_dmf
    result = _identify_two(reference, truth, measured, ("c12", "eps12"))
    assert result.theta["c12"] == pytest.approx(truth.c12, rel=0.05)
    assert result.theta["eps12"] == pytest.approx(truth.eps12, rel=0.05)
    assert max(result.fit_nrmse.values()) < 0.1
    assert result.validation_nrmse and max(result.validation_nrmse.values()) < 0.2
