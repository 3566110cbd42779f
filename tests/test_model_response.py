"""Model side of the identification: parameterisation, objective, and the replayed test."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dtid.acquisition.plan import TestPlan
from dtid.identification.frf.closed_loop import estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.model.response import SETTLE_S, ModelTest, model_drv_db
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.testdata import TestData, from_simulation
from dtid.identification.search.objective import FAILED_NRMSE, nrmse, summed_nrmse
from dtid.identification.search.parameterization import (
    THETA_NAMES,
    Parameterization,
    theta_from_parameters,
    theta_to_arrays,
)
from dtid.simulator.mechanisms import BY_NAME, MECHANISMS, Effects, kernel_parameters
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, simulate


def test_theta_round_trip(reference: DrivetrainParameters) -> None:
    theta = theta_from_parameters(reference)
    arrays = theta_to_arrays(np.array([[theta[n] for n in THETA_NAMES]]), 15.0, 0.9)
    np.testing.assert_allclose(arrays[0], reference.as_array(), rtol=1e-12)


def test_normalisation_round_trip_and_fixing(reference: DrivetrainParameters) -> None:
    par = Parameterization.around(reference, 15.0, 0.9, fixed={"Tc12": 0.25})
    assert "Tc12" not in par.free and len(par.free) == 9
    unit = np.random.default_rng(0).uniform(size=(5, 9))
    theta = par.theta(unit)
    np.testing.assert_allclose(par.unit(theta), unit, atol=1e-12)
    assert (theta[:, THETA_NAMES.index("Tc12")] == 0.25).all()
    # +-100 % bounds, narrowed where an inertia would vanish
    c12 = THETA_NAMES.index("c12")
    assert (par.lower[c12], par.upper[c12]) == (0.0, 2 * reference.c12)
    assert 0 < par.lower[0] and 0 < par.lower[1] < par.upper[1] < 1


def test_nrmse_eq16() -> None:
    measured = np.array([-10.0, -12.0, -20.0, -15.0])
    assert nrmse(measured, measured)[0] == 0.0
    assert nrmse(measured, np.full(4, measured.mean()))[0] == pytest.approx(1.0)
    assert nrmse(measured, np.full(4, np.nan))[0] == FAILED_NRMSE
    assert summed_nrmse([measured, measured], [measured + 0.0, measured])[0] == 0.0


def test_model_replays_a_clean_recording_exactly(reference: DrivetrainParameters) -> None:
    """Same parameters, same requests, same estimator: the model's |G_DRV| is the measured one."""
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=30.0)
    data = from_simulation(simulate(reference, plan, SimulationOptions.clean()))
    runs = find_runs(data.test_torque)
    measured = [estimate_frf(data, run) for run in runs]
    test = ModelTest(data.test_torque, tuple(measured), 1000.0)
    other = reference.replace(c12=0.8 * reference.c12)
    model = model_drv_db(np.stack([reference.as_array(), other.as_array()]), test)
    for estimate, db in zip(measured, model, strict=True):
        np.testing.assert_allclose(db[0], estimate.drv_db, atol=1e-4)
        assert np.abs(db[1] - estimate.drv_db).max() > 1.0  # a softer DMF is seen


def test_each_row_depends_on_its_own_parameters_only(reference: DrivetrainParameters) -> None:
    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=20.0)
    data = from_simulation(simulate(reference, plan))
    test = ModelTest(
        data.test_torque, (estimate_frf(data, find_runs(data.test_torque)[0]),), 1000.0
    )
    alone = model_drv_db(reference.as_array()[None], test)[0][0]
    others = np.stack([reference.as_array() * np.r_[np.full(10, f), 1, 1] for f in (0.7, 1.3)])
    crowd = model_drv_db(np.vstack([others, reference.as_array()]), test)[0][-1]
    np.testing.assert_array_equal(alone, crowd)


def test_each_row_depends_on_its_own_parameters_only_when_the_drive_is_recorded(
    reference_measured: MeasuredTest, reference: DrivetrainParameters
) -> None:
    """The same to the bit, alone or beside other sets and one that cannot idle, on the path
    that drives the model stroke by stroke with the recording (all sets share the recorded
    test torque's transform)."""
    test = reference_measured.model_test([1])
    assert test.loop is not None
    alone = model_drv_db(reference.as_array()[None], test)[0][0]
    others = [reference.as_array() * np.r_[np.full(10, f), 1, 1] for f in (0.7, 1.3)]
    stalling = reference.replace(T_loss=3000.0).as_array()
    crowd = model_drv_db(np.vstack([*others, stalling, reference.as_array()]), test)[0]
    np.testing.assert_array_equal(alone, crowd[-1])
    assert np.isnan(crowd[2]).all() and np.isfinite(crowd[:2]).all()


def test_a_set_that_cannot_idle_gets_nan(reference: DrivetrainParameters) -> None:
    plan = TestPlan(amplitudes_nm=(5.0,), validation_nm=0.0, duration_s=10.0)
    data = from_simulation(simulate(reference, plan, SimulationOptions.clean()))
    runs = find_runs(data.test_torque)
    test = ModelTest(data.test_torque, (estimate_frf(data, runs[0], resolution_hz=1.0),), 1000.0)
    stalling = reference.replace(T_loss=3000.0).as_array()
    db = model_drv_db(np.stack([reference.as_array(), stalling]), test)[0]
    assert np.isfinite(db[0]).all() and np.isnan(db[1]).all()


@pytest.fixture(scope="module")
def reference_measured(reference_data: TestData) -> MeasuredTest:
    return MeasuredTest.from_data("reference", reference_data, 0.25)


def test_set_point_is_the_speeds_time_mean(reference_measured: MeasuredTest) -> None:
    """The controller's integral makes the speed's time mean its set-point, chirps included."""
    assert reference_measured.setpoint_rpm == pytest.approx(1000.0, abs=0.02)


def test_each_run_is_replayed_from_a_stroke_settle_s_before_it(
    reference_measured: MeasuredTest,
) -> None:
    test = reference_measured.model_test([1, 2])
    loop = reference_measured.loop
    stroke_s = 2 * float(np.median(np.diff(loop.t)))
    assert [r.runs for r in test.replays] == [(0,), (1,)]
    for replay, estimate in zip(test.replays, test.estimates, strict=True):
        wanted = estimate.run.start_s - SETTLE_S
        assert replay.start_event is not None
        assert (replay.start_event - loop.first_stroke) % 2 == 0  # a stroke starts there
        assert wanted - 1.3 * stroke_s < replay.offset_s <= wanted + 0.3 * stroke_s


def test_the_vehicles_strokes_are_repeated(
    reference: DrivetrainParameters, reference_measured: MeasuredTest
) -> None:
    """At 10 N*m the stroke-sampled chirp's alias meets the free play's harmonic near f_s/3
    (11 Hz at 1000 rpm): with each model stroke taking the request the vehicle's stroke took,
    the model at the truth follows the measured peak; with the strokes a crank event off, so
    that they take the other requests, it misses it by over a decibel."""
    test = reference_measured.model_test([2])
    measured = reference_measured.estimates[2].drv_db
    in_phase = model_drv_db(reference.as_array()[None], test)[0][0]
    loop = reference_measured.loop
    shifted = dataclasses.replace(
        test, loop=dataclasses.replace(loop, first_stroke=loop.first_stroke + 1)
    )
    out_of_phase = model_drv_db(reference.as_array()[None], shifted)[0][0]
    assert np.abs(in_phase - measured).max() < 0.6
    assert np.abs(out_of_phase - measured).max() > 1.0


REPLAYED_ALIKE_DB = 0.15
"""Median over the bins of the |dB| by which the replay of a clean recording at its truth may
depart from the recording's |G_DRV| when a mechanism is concealed: at most 0.092 dB across the
library at the middle of each typical range (2026-12-04, an AVX-512 host; the RMS 0.01-0.16 dB
on the host of 2026-12-03, 0.31 dB for the progressive spring at 10 N*m on this one, from a few
bins at 9-12 Hz where the stroke alias meets the hardening spring's jump, which the last bits of
the host's arithmetic move). A fault of the replay moves most bins: the drag's start out of
balance was 2.9 dB RMS off, and leaving the mechanism out of the replay moves the median by
0.20-2.9 dB in the worse of the two runs."""
DEPARTS_DB = 0.6
"""RMS dB by which the replay without the concealed mechanism must at least depart: the smallest
measured is the cylinder imbalance's 0.81 dB at 5 N*m."""


@pytest.mark.parametrize(
    "mechanism",
    [m.name for m in MECHANISMS if m.name not in ("torque_lag", "torque_sensor_gain")],
)
def test_the_replay_at_the_truth_repeats_a_clean_recording_with_any_mechanism(
    reference: DrivetrainParameters, mechanism: str
) -> None:
    """The replay (recorded request, the model's own speed tracking, a start from rest 3 s
    before each run) must hold each mechanism's physics as the vehicle does: at the truth with
    the concealed mechanism it repeats a noise-free recording's |G_DRV| within
    REPLAYED_ALIKE_DB (median over the bins) at 5 and 10 N*m, and without the mechanism it
    departs by DEPARTS_DB RMS (bar the asymmetric play, which no mean torque shows in neutral).
    A start 2.1 N*m out of the drag's balance was 2.9 dB off. (The torque lag is replayed
    through its measured lag, the sensor gain scales the measurement alone:
    tests/test_idle_loop.py and tests/test_mechanisms.py.)"""
    spec = BY_NAME[mechanism]
    effects = Effects({q.name: 0.5 * sum(q.typical) for q in spec.parameters})
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=20.0)
    options = dataclasses.replace(SimulationOptions.clean(), effects=effects)
    data = from_simulation(simulate(reference, plan, options))
    measured = MeasuredTest.from_data("clean", data, 0.25)
    truth = reference.as_array()
    rows = np.stack([kernel_parameters(truth), kernel_parameters(truth, effects)])
    model = model_drv_db(rows, measured.model_test([0, 1]))
    departures = [np.abs(db - e.drv_db) for e, db in zip(measured.estimates, model, strict=True)]
    median = np.array([np.median(d, axis=1) for d in departures])  # (runs, [without, with])
    rms = np.array([np.sqrt(np.mean(d**2, axis=1)) for d in departures])
    assert (median[:, 1] < REPLAYED_ALIKE_DB).all(), median
    if mechanism != "asymmetric_play":
        assert rms[:, 0].max() > DEPARTS_DB, rms
