"""The model repeats a recorded test with the vehicle's own idle loop, whatever that loop is.

The recordings come from vehicles whose idle controllers and ECU timings the model side does not
share: a slower and a faster PI, a PI whose output reaches the request three crank events late
and whose strokes latch an older request, and a PID with a filtered speed error (not a PI). The
model, driven by each recording's own torque request, must repeat its |G_DRV| at the true
drivetrain; the product's own PI imposed instead is measurably wrong on some of them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dtid.acquisition.plan import TestPlan
from dtid.identification.model.idle_loop import (
    MEASURED_TORQUE,
    RECORDED_REQUEST,
    idle_loop,
    latch,
    stroke_gain,
)
from dtid.identification.model.response import model_drv_db
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import truncated, warn_unrepeatable
from dtid.identification.samples.testdata import TestData, from_simulation
from dtid.identification.search.objective import FAILED_NRMSE, nrmse
from dtid.simulator.controller import IdleController
from dtid.simulator.kernel import SPEED_AVERAGES
from dtid.simulator.mechanisms import Effects
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_data import VehicleData

ECUS = {
    "slow PI": IdleController(kp_nm_per_rpm=0.06, ki_nm_per_rpm_s=0.05),
    "fast PI": IdleController(kp_nm_per_rpm=0.5, ki_nm_per_rpm_s=1.0),
    "PI, delayed": IdleController(delay_samples=3, latch_samples=2),
    "PID": IdleController(
        kp_nm_per_rpm=0.25, ki_nm_per_rpm_s=0.4, kd_nm_per_rpm_s=0.01, error_tau_s=0.02
    ),
}
PLAN = TestPlan(
    amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=20.0, f1_hz=1.0, f2_hz=15.0
)


@pytest.fixture(scope="module", params=list(ECUS))
def vehicle(request: pytest.FixtureRequest, reference: DrivetrainParameters) -> tuple:
    controller = ECUS[request.param]
    options = SimulationOptions.clean(controller=controller)
    data = from_simulation(simulate(reference, PLAN, options))
    return request.param, controller, MeasuredTest.from_data(request.param, data, 0.25)


REPEATED_DB = 0.6
"""How closely a clean recording's |G_DRV| is repeated at the truth, dB: the free play's jump
near the resonance turns the smallest difference (the model's tracking torque, a crank event's
offset of the strokes) into a few tenths of a decibel at the 10 N*m peak."""


def _deviations(
    params: DrivetrainParameters, measured: MeasuredTest, **changes: object
) -> list[np.ndarray]:
    """The model's |G_DRV| less the measured, per run, dB."""
    test = dataclasses.replace(measured.model_test([0, 1]), **changes)
    curves = model_drv_db(params.as_array()[None], test)
    return [db[0] - e.drv_db for db, e in zip(curves, measured.estimates, strict=True)]


def _worst_db(params: DrivetrainParameters, measured: MeasuredTest, **changes: object) -> float:
    """Largest deviation of the model's |G_DRV| from the measured over both runs, dB."""
    return max(float(np.max(np.abs(d))) for d in _deviations(params, measured, **changes))


def _rms_db(params: DrivetrainParameters, measured: MeasuredTest, **changes: object) -> float:
    """The larger of the two runs' RMS deviation of the model's |G_DRV| from the measured, dB."""
    return max(float(np.sqrt(np.mean(d**2))) for d in _deviations(params, measured, **changes))


def test_the_model_repeats_any_vehicles_loop_at_the_truth(
    reference: DrivetrainParameters, vehicle: tuple
) -> None:
    name, _, measured = vehicle
    assert measured.loop.mode == RECORDED_REQUEST
    assert _worst_db(reference, measured) < REPEATED_DB, name


def test_the_products_own_loop_imposed_is_wrong_on_other_vehicles(
    reference: DrivetrainParameters, vehicle: tuple
) -> None:
    """What the model did before: our PI at the recording's set-point. On the fast PI and the
    PID it misses the free play's resonance by decibels; on the product's own timing it would
    not (that is what made it look right on its own simulator)."""
    name, _, measured = vehicle
    own = _worst_db(reference, measured, loop=None)
    if name in ("fast PI", "PID"):
        assert own > 2 * REPEATED_DB, name
    assert own > _worst_db(reference, measured), name


def test_the_latch_and_the_engine_gain_are_read_off_the_recording(
    reference: DrivetrainParameters, vehicle: tuple
) -> None:
    """The product's engine reports a stroke's torque at its end, two crank events after its
    start; the stroke takes the request formed ``latch_samples`` events before its start."""
    name, controller, measured = vehicle
    assert measured.loop.latch_samples == 2 + controller.latch_samples, name
    assert measured.loop.gain == pytest.approx(reference.K, rel=1e-6)
    assert measured.loop.residual_nm < 1e-6


@pytest.mark.parametrize("sensor", SPEED_AVERAGES)
def test_a_lagging_engines_strokes_are_read_through_its_lag(
    reference: DrivetrainParameters, sensor: str
) -> None:
    """A clean recording of an engine lagging 50 ms: read at once, the strokes' slope gives K
    half its value (0.44 for 0.9), a later latch and a residual of 2.7 N*m; read through the lag
    (the kernel's recurrence, stroke times from the reports), the product's latch (three
    events), K to 0.1 % (slope 0.7 %) and a residual of 0.03 N*m, 0.13 % of the torque's
    swing. The lag measured (``engine_lag = "measured"``) is fitted to the strokes: 0.0494 s
    with either speed sensor, where T/T_ecu's fit read 0.0528 s with a tooth timer and 0.0488 s
    with eq. (9)'s, and the model then repeats |G_DRV| at the truth to 0.05-0.07 dB RMS (from
    T/T_ecu's lag 0.20-0.25 dB RMS with a tooth timer; 2026-12-03 and 2026-12-04). Its worst
    bin is the host's: 0.13-0.22 dB on one host, 0.37 dB with a tooth timer on an AVX-512 host
    (one bin near the stroke alias, where the free play's jump turns the last bits of the host's
    arithmetic into tenths of a decibel), so the RMS is asserted."""
    options = SimulationOptions.clean(effects=Effects({"tau_m": 0.05}), speed_average=sensor)
    data = from_simulation(simulate(reference, PLAN, options))
    prompt, lagging = idle_loop(data), idle_loop(data, 0.05)
    swing = np.ptp(lagging.stroke_torque_nm)
    assert prompt.engine_gain()[0] < 0.6 * reference.K and prompt.residual_nm > 0.05 * swing
    assert lagging.latch_samples == 2 + IdleController().latch_samples
    assert lagging.gain == pytest.approx(reference.K, rel=2e-3)
    assert lagging.engine_gain()[0] == pytest.approx(reference.K, rel=1e-2)
    assert lagging.residual_nm < 0.005 * swing
    vehicle = VehicleData(engine_lag="measured", speed_average=sensor)
    measured = MeasuredTest.from_data("lag", data, 0.25, vehicle)
    assert measured.loop.lag_s == pytest.approx(0.05, rel=0.03)
    assert _rms_db(reference, measured) < REPEATED_DB / 5


def test_k_is_read_off_the_strokes_not_off_the_mean_of_g_eng(
    reference: DrivetrainParameters, vehicle: tuple
) -> None:
    """Eq. (3) stroke by stroke gives K to rounding on a clean recording, whatever the ECU. Eq.
    (24)'s mean |G_ENG| is K times the transfer of the strokes' sample-and-hold after the ECU's
    latch, which the controller shapes: measured +0.4 % (slow PI), -2.1 % (fast PI), +0.9 %
    (delayed PI), -2.1 % (PID)."""
    name, _, measured = vehicle
    assert measured.loop.engine_gain()[0] == pytest.approx(reference.K, rel=1e-6), name
    eq24 = np.mean([e.engine_gain for e in measured.estimates])
    if name in ("fast PI", "PID"):
        assert abs(eq24 / reference.K - 1) > 0.01, name


def test_stroke_gain_keeps_k_under_an_offset_and_noise() -> None:
    """A request that leaves out 3 N*m of the indicated torque, K = 0.92, a 2 % combustion
    variation and 0.3 N*m of sensor noise: the slope is K, the weight the request's spread."""
    rng = np.random.default_rng(5)
    latched = 15 + 10 * np.sin(np.arange(3000) * 0.05) + 0.5 * rng.standard_normal(3000)
    delivered = 0.92 * latched * (1 + 0.02 * rng.standard_normal(3000))
    k, weight = stroke_gain(latched, 3.0 + delivered + 0.3 * rng.standard_normal(3000))
    assert k == pytest.approx(0.92, rel=3e-3)
    assert weight == pytest.approx(np.sum((latched - latched.mean()) ** 2))


def test_latch_on_noisy_strokes() -> None:
    """Each stroke took the request of three events before its report, times K = 0.9, plus
    0.4 N*m of noise: the lag, K and the noise come back."""
    rng = np.random.default_rng(3)
    request = 15 + 5 * np.sin(np.arange(4000) * 0.7)
    strokes = np.arange(10, 4000, 2)
    torque = 0.9 * request[strokes - 3] + 0.4 * rng.standard_normal(len(strokes))
    lag, gain, residual = latch(request, strokes, torque)
    assert lag == 3
    assert gain == pytest.approx(0.9, rel=2e-3)
    assert residual == pytest.approx(0.4, rel=0.05)


def test_without_a_torque_request_the_measured_torque_drives_the_model(
    reference: DrivetrainParameters,
) -> None:
    """No T_ecu on the bus: the measured strokes drive the model (K is in them), so a wrong K
    changes nothing, and the model still repeats the recording."""
    data = from_simulation(simulate(reference, PLAN, SimulationOptions.clean()))
    bare = MeasuredTest.from_data(
        "no request", TestData(data.speed, data.mean_torque, data.test_torque), 0.25
    )
    assert bare.loop.mode == MEASURED_TORQUE
    assert _worst_db(reference, bare) < REPEATED_DB
    assert _worst_db(reference.replace(K=0.5), bare) == _worst_db(reference, bare)


LIGHT_FLYWHEEL = DrivetrainParameters(
    J1=0.0905,
    J2=0.1168,
    J3=0.0318,
    c12=336.3,
    c23=79.0,
    d12=1.23,
    d23=0.391,
    Tc12=0.396,
    eps12=0.0203,
    eps23=0.0165,
    T_loss=17.3,
    K=0.986,
)
"""A drivetrain whose primary flywheel is lighter than its secondary (J1 < J2): with a PI of too
much gain and a stroke's delay at 790 rpm its idle hunts."""


HOT_PI = IdleController(
    kp_nm_per_rpm=0.48,
    ki_nm_per_rpm_s=0.25,
    delay_samples=1,
    latch_samples=2,
    error_tau_s=0.0135,
)
"""A PI of too much gain (Kp 0.48 N*m/rpm, a sample's delay, a two-sample latch): the idle of
:data:`LIGHT_FLYWHEEL` hunts under it."""


def _idle_data(controller: IdleController) -> TestData:
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=30.0)
    options = SimulationOptions(controller=dataclasses.replace(controller, setpoint_rpm=790.0))
    return from_simulation(simulate(LIGHT_FLYWHEEL, plan, options, seed=7))


def _idle_test(controller: IdleController) -> MeasuredTest:
    return MeasuredTest.from_data("light flywheel", _idle_data(controller), 0.25)


def test_an_idle_loop_that_hunts_scatters_the_idle_speed_as_much_as_a_chirp_moves_it() -> None:
    """The same vehicle and noise under the reference's loop and under a hot PI: a steady idle
    scatters by a fraction of the 5 N*m chirp's speed movement, the hunting one by more than
    half of it."""
    for controller, steady in ((IdleController(), True), (HOT_PI, False)):
        test = _idle_test(controller)
        run = test.estimates[0].run
        speed = test.data.speed
        moved = np.std(speed.value[(speed.t > run.start_s) & (speed.t < run.end_s)])
        assert (test.idle_speed_sd_rpm < 0.3 * moved) == steady, (test.idle_speed_sd_rpm, moved)
        assert (test.idle_speed_sd_rpm > 0.5 * moved) != steady


def test_a_run_the_model_cannot_idle_through_is_named_with_the_idle_scatter(
    caplog: pytest.LogCaptureFixture,
) -> None:
    test = _idle_test(IdleController())
    scores = {"light flywheel @ 2 N*m": FAILED_NRMSE, "light flywheel @ 5 N*m": 0.04}
    with caplog.at_level("WARNING"):
        warn_unrepeatable(scores, [test])
    assert len(caplog.records) == 1
    message = caplog.records[0].getMessage()
    assert "could not idle through light flywheel @ 2 N*m" in message
    assert f"scatters by {test.idle_speed_sd_rpm:.1f} rpm" in message


def test_a_hunting_idle_recording_that_ends_in_a_request_trough_is_repeated() -> None:
    """A hunting idle's request swings by tens of N*m, and a recording cut after the last run
    (as the identification cuts before a validation chirp) can end in a trough, far below the
    idle's load. The model holds that request past the recording's end, and its engine stalls
    there (the randomised trial's truth 34, before 2026-12-06: the model at the truth failed
    its 10 N*m run, eq. 17 10.04, and the search ended 42 % off). The runs are repeated at the
    truth all the same (NRMSE 0.053 and 0.033 at the truth)."""
    data = _idle_data(HOT_PI)
    request = data.torque_request
    assert request is not None
    last = MeasuredTest.from_data("hot", data, 0.25).estimates[-1].run
    near_end = (request.t > last.end_s + 0.5) & (request.t < last.end_s + 2.0)
    trough = int(np.flatnonzero(near_end)[np.argmin(request.value[near_end])])
    assert request.value[trough] < LIGHT_FLYWHEEL.T_loss - 10.0  # it hunts
    test = MeasuredTest.from_data("hot", truncated(data, float(request.t[trough + 1])), 0.25)
    curves = model_drv_db(LIGHT_FLYWHEEL.as_array()[None], test.model_test([0, 1]))
    scores = [nrmse(e.drv_db, db)[0] for e, db in zip(test.estimates, curves, strict=True)]
    assert max(scores) < 0.1, scores
