"""Profile likelihood: a decoupled parameter is flat, a stiffness has a closed interval."""

from __future__ import annotations

import numpy as np
import pytest

from identification.identify import Objective, SearchSettings, engine_gain, identify, split_runs
from identification.parameterization import THETA_NAMES, Parameterization, theta_from_parameters
from identification.profile import THRESHOLD, _interval_and_verdict, profile
from identification.test_setup import MeasuredTest
from identification.testdata import from_simulation
from simulator.chirp import TestPlan
from simulator.parameters import DrivetrainParameters
from simulator.simulate import SimulationOptions, simulate


def test_interval_from_threshold_crossings() -> None:
    values = np.linspace(0, 6, 7)
    stat = np.array([9.0, 4.0, 1.0, 0.0, 1.0, 2.0, 3.0])
    (lower, upper), verdict = _interval_and_verdict(values, stat, 3.0)
    assert lower == pytest.approx(2 - (THRESHOLD - 1.0) / (4.0 - 1.0))  # between 1 and 2
    assert upper is None and verdict == "structural"
    (lower, upper), verdict = _interval_and_verdict(values, np.zeros(7), 3.0)
    assert (lower, upper, verdict) == (None, None, "no")
    stat = np.array([9.0, 5.0, 1.0, 0.0, 1.0, 5.0, 9.0])
    (lower, upper), verdict = _interval_and_verdict(values, stat, 3.0)
    assert verdict == "practical" and 1 < lower < 2 and 4 < upper < 5


@pytest.fixture(scope="module")
def decoupled(reference: DrivetrainParameters) -> tuple:
    """Linear two-mass plant: J3 hangs free (c23 = d23 = eps23 = 0), the truth is the prior."""
    truth = reference.replace(eps12=0.0, eps23=0.0, Tc12=0.0, c23=0.0, d23=0.0)
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), duration_s=30.0)
    measured = MeasuredTest.from_data(
        "two-mass", from_simulation(simulate(truth, plan, SimulationOptions.clean())), 0.25
    )
    return truth, measured


def test_profiles_tell_identifiable_from_decoupled(decoupled: tuple) -> None:
    truth, measured = decoupled
    theta = theta_from_parameters(truth)
    free = ("c12", "eps23")
    fixed = {n: theta[n] for n in THETA_NAMES if n not in free}
    prior = truth.replace(eps23=0.01)  # bounds of eps23: 0 .. 0.02 rad
    par = Parameterization.around(prior, measured.idle_torque_nm, engine_gain([measured]), fixed)
    ident, _ = split_runs([measured])
    test = measured.model_test(ident[0])
    measured_db = [measured.estimates[i].drv_db for i in ident[0]]
    objective = Objective(par, [test], [measured_db])
    optimum = par.unit(np.array([[theta[n] if n != "eps23" else 0.01 for n in THETA_NAMES]]))[0]
    kwargs = {"points": 5, "generations": 3, "popsize": 4, "polish_evaluations": 30}
    stiffness = profile(objective, measured_db, "c12", optimum, **kwargs)
    play = profile(objective, measured_db, "eps23", optimum, **kwargs)
    assert stiffness.verdict == "practical"
    lower, upper = stiffness.interval
    assert lower < truth.c12 < upper and upper - lower < 0.5 * truth.c12
    assert play.verdict == "no"  # J3 is decoupled: its gear play cannot matter
    assert np.ptp(play.objective) < 1e-3


@pytest.mark.slow
def test_interval_contains_the_truth_on_noisy_data(reference: DrivetrainParameters) -> None:
    """Realistic noise: identify c12 and d12, then the 95 % profile interval holds the truth."""
    truth = reference.replace(eps12=0.0, eps23=0.0, Tc12=0.0, c23=0.0, d23=0.0)
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), duration_s=30.0)
    measured = MeasuredTest.from_data(
        "noisy", from_simulation(simulate(truth, plan, SimulationOptions(), seed=4)), 0.25
    )
    theta = theta_from_parameters(truth)
    fixed = {n: theta[n] for n in THETA_NAMES if n not in ("c12", "d12")}
    par = Parameterization.around(truth, measured.idle_torque_nm, engine_gain([measured]), fixed)
    ident, valid = split_runs([measured])
    result = identify(
        [measured],
        par,
        ident,
        valid,
        SearchSettings(popsize=6, generations=10, polish_evaluations=60),
    )
    test = measured.model_test(ident[0])
    measured_db = [measured.estimates[i].drv_db for i in ident[0]]
    stiffness = profile(
        Objective(par, [test], [measured_db]),
        measured_db,
        "c12",
        result.unit,
        points=5,
        generations=3,
        popsize=4,
        polish_evaluations=30,
    )
    lower, upper = stiffness.interval
    assert stiffness.verdict == "practical"
    assert lower < truth.c12 < upper


def test_interval_is_ordered_when_the_minimum_is_off_the_optimum() -> None:
    values = np.linspace(0, 6, 7)
    stat = np.array([9.0, 5.0, 0.0, 1.0, 2.0, 5.0, 9.0])  # minimum at 2
    (lower, upper), verdict = _interval_and_verdict(values, stat, 2.0)
    assert verdict == "practical" and lower < 2.0 < upper
