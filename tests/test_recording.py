"""Simulated recordings through CAN: every log format and a second DBC give the same FRFs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from dtid.acquisition.logfile import write_log
from dtid.acquisition.plan import TestPlan
from dtid.acquisition.plan import tool_requests as plan_requests
from dtid.dbc.loader import load_interface
from dtid.dbc.roles import DEFAULT_REQUEST_TIMEOUT_S
from dtid.errors import AnalysisError
from dtid.identification.frf.closed_loop import FrfEstimate, estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.recording import _in_time_order, load_recording
from dtid.identification.samples.testdata import Series, from_simulation
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, SimulationResult, replay_batch, simulate
from dtid.simulator.vehicle_frames import simulation_frames

DATA = Path(__file__).parent / "data"
FORMATS = (".blf", ".asc", ".log", ".mf4", ".trc", ".csv")


@pytest.fixture(scope="module")
def short_test(reference: DrivetrainParameters) -> SimulationResult:
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=30.0)
    return simulate(reference, plan, seed=3)


def _frfs(path: Path, dbc: Path | None = None, signals: Path | None = None) -> list[FrfEstimate]:
    data = load_recording(path, load_interface(dbc, signals)).test_data()
    return [estimate_frf(data, run) for run in find_runs(data.test_torque)]


@pytest.fixture(scope="module")
def recordings(short_test: SimulationResult, tmp_path_factory: pytest.TempPathFactory) -> dict:
    folder = tmp_path_factory.mktemp("recordings")
    frames = simulation_frames(short_test, load_interface())
    paths = {}
    for suffix in FORMATS:
        paths[suffix] = folder / f"test{suffix}"
        write_log(paths[suffix], frames)
    return paths


@pytest.fixture(scope="module")
def blf_frfs(recordings: dict) -> list[FrfEstimate]:
    reference = _frfs(recordings[".blf"])
    assert [e.run.amplitude_nm for e in reference] == pytest.approx([5.0, 10.0])
    return reference


@pytest.mark.parametrize("suffix", FORMATS[1:])
def test_every_format_gives_the_same_frf(recordings: dict, blf_frfs: list, suffix: str) -> None:
    """The same test read from each format: its FRFs agree with the BLF's to the formats' time
    resolution (1 us in ASC, candump and TRC)."""
    for a, b in zip(blf_frfs, _frfs(recordings[suffix]), strict=True):
        np.testing.assert_array_equal(a.frequency_hz, b.frequency_hz)
        np.testing.assert_allclose(a.drv_db, b.drv_db, atol=1e-3)
        np.testing.assert_allclose(a.eng_db, b.eng_db, atol=1e-3)
        np.testing.assert_allclose(a.coherence, b.coherence, atol=1e-4)


def test_the_recording_holds_what_was_simulated(
    recordings: dict, short_test: SimulationResult
) -> None:
    """CAN quantisation (0.125 rpm, 0.01 N*m) is all that separates recording and simulation."""
    recording = load_recording(recordings[".blf"], load_interface())
    speed = recording.roles["speed"]
    np.testing.assert_allclose(speed.timestamps, short_test.speed_t, atol=1e-6)
    np.testing.assert_allclose(speed.values, short_test.speed_rpm, atol=0.0625 + 1e-9)
    torque = recording.roles["mean_torque"]
    np.testing.assert_allclose(torque.values, short_test.mean_torque_nm, atol=0.005 + 1e-9)
    np.testing.assert_array_equal(torque.extra["cylinder"], short_test.cylinder)
    counter = speed.extra["counter"]
    assert (np.diff(counter) % 65536 == 1).all()


def test_a_second_dbc_via_its_map_gives_the_same_frf(
    short_test: SimulationResult, recordings: dict, tmp_path: Path
) -> None:
    """Other names, extended IDs, speed in rad/s, torque in % of 450 N*m: same FRFs."""
    dbc, signals = DATA / "other_vehicle.dbc", DATA / "other_vehicle_signals.toml"
    path = tmp_path / "other.blf"
    write_log(path, simulation_frames(short_test, load_interface(dbc, signals)))
    for a, b in zip(_frfs(recordings[".blf"]), _frfs(path, dbc, signals), strict=True):
        np.testing.assert_allclose(a.drv_db, b.drv_db, atol=0.01)
        np.testing.assert_allclose(a.coherence, b.coherence, atol=1e-3)


def test_frames_out_of_time_order_are_sorted(
    short_test: SimulationResult, caplog: pytest.LogCaptureFixture
) -> None:
    """A logger that wrote a speed frame late: the series is sorted, with a warning."""
    interface = load_interface()
    frames = simulation_frames(short_test, interface)
    speed_id = interface.database.get_message_by_name("EngineSpeed").frame_id
    first, second = [i for i, f in enumerate(frames) if f.arbitration_id == speed_id][100:102]
    late = list(frames)
    late[first], late[second] = late[second], late[first]
    with caplog.at_level("WARNING"):
        fixed = _in_time_order(interface.decode(late)["speed"], 0.0, Path("late.log"))
    assert "out of time order" in caplog.text
    expected = interface.decode(frames)["speed"]
    np.testing.assert_array_equal(fixed.timestamps, np.round(expected.timestamps, 6))
    np.testing.assert_array_equal(fixed.values, expected.values)


def test_a_pause_in_the_requests_is_read_as_the_ecu_applied_it(
    reference: DrivetrainParameters, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The tool stalls for 0.3 s mid-chirp: its log holds no requests then, and the ECU applied
    the last one for its timeout and zero after. The recording's test torque is what the ECU
    applied, so the FRF is the one of the plant's true input; holding the last request (what
    the log alone says) gives another."""
    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=20.0)
    t, value = plan_requests(plan)
    stall = (t > plan.settle_s + 8.0) & (t < plan.settle_s + 8.3)
    last = np.flatnonzero(stall)[0] - 1
    applied_t = np.insert(t[~stall], last + 1, t[last] + DEFAULT_REQUEST_TIMEOUT_S)
    applied = np.insert(value[~stall], last + 1, 0.0)
    options = SimulationOptions.clean()
    batch = replay_batch(
        reference.as_array()[None], applied_t, applied, np.ones(1), plan.end_s, options
    )
    result = SimulationResult.from_outputs(
        batch.speed[0, : batch.n_speed[0]],
        batch.torque[0, : batch.n_torque[0]],
        (t[~stall], value[~stall]),
        reference,
        plan,
        options,
    )
    path = tmp_path / "stalled.blf"
    write_log(path, simulation_frames(result, load_interface()))
    with caplog.at_level("WARNING"):
        data = load_recording(path, load_interface()).test_data()
    assert "1 pause(s) in the test-torque requests" in caplog.text
    times, values = data.test_torque.t, data.test_torque.value
    dropped = np.flatnonzero(
        np.isclose(np.diff(times), DEFAULT_REQUEST_TIMEOUT_S, atol=1e-6)
        & (values[1:] == 0.0)
        & (values[:-1] != 0.0)
    )
    assert len(dropped) == 1  # zero from the timeout on, to the next request 0.25 s later
    assert times[dropped[0] + 2] - times[dropped[0] + 1] == pytest.approx(0.25, abs=0.011)

    def frf_with(requests: Series) -> np.ndarray:
        test = dataclasses.replace(data, test_torque=requests)
        return estimate_frf(test, find_runs(test.test_torque)[0]).drv_db

    read = frf_with(data.test_torque)
    true = frf_with(Series(applied_t, applied))
    held = frf_with(Series(t[~stall], value[~stall]))
    np.testing.assert_allclose(read, true, atol=0.01)
    assert np.abs(held - true).max() > 0.1


def test_a_torque_request_without_the_test_torque_is_left_out(
    short_test: SimulationResult, caplog: pytest.LogCaptureFixture
) -> None:
    """An ECU that reports its base request (its idle controller's alone) instead of the total
    T_ecu: the request moves 0.1-0.2 N*m per N*m of test torque instead of about 1, so it is
    left out with a warning and the measured torque drives the model. Kept, it drove the model
    without any chirp: NRMSE 1.0-1.2 at the truth, and eq. (24) read K 6.4."""
    data = from_simulation(short_test)
    assert data.torque_request is not None
    held = np.searchsorted(data.test_torque.t, data.torque_request.t, side="right") - 1
    test = np.where(held >= 0, data.test_torque.value[np.clip(held, 0, None)], 0.0)
    base = Series(data.torque_request.t, data.torque_request.value - test)
    for request, left_out in ((data.torque_request, False), (base, True)):
        caplog.clear()
        with caplog.at_level("WARNING"):
            measured = MeasuredTest.from_data(
                "test", dataclasses.replace(data, torque_request=request), 0.25
            )
        assert measured.loop.by_request != left_out
        assert ("leaves out the test torque" in caplog.text) == left_out
    assert "moves 0.1" in caplog.text


def test_a_brake_torque_mapped_as_the_mean_torque_is_named(short_test: SimulationResult) -> None:
    """The indicated mean torque less the engine's loss (a brake or net torque, as many ECUs put
    on the bus): about zero at idle, so the loss torque came out negative and the search
    stopped on "T_loss = -0.018 is not physical" of a parameter set nobody gave."""
    data = from_simulation(short_test)
    net = Series(data.mean_torque.t, data.mean_torque.value - short_test.parameters.T_loss)
    with pytest.raises(AnalysisError, match="this looks like a brake or net torque"):
        MeasuredTest.from_data("net", dataclasses.replace(data, mean_torque=net), 0.25)
