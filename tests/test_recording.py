"""Simulated recordings through CAN: every log format and a second DBC give the same FRFs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acquisition.logfile import write_log
from dbc.loader import load_interface
from identification.frf import FrfEstimate, estimate_frf
from identification.recording import _in_time_order, load_recording
from identification.runs import find_runs
from simulator.chirp import TestPlan
from simulator.parameters import DrivetrainParameters
from simulator.simulate import SimulationResult, simulate
from simulator.vehicle_frames import simulation_frames

DATA = Path(__file__).parent / "data"
FORMATS = (".blf", ".asc", ".log")


@pytest.fixture(scope="module")
def short_test(reference: DrivetrainParameters) -> SimulationResult:
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), duration_s=30.0)
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


def test_every_format_gives_the_same_frf(recordings: dict) -> None:
    reference = _frfs(recordings[".blf"])
    assert [e.run.amplitude_nm for e in reference] == pytest.approx([5.0, 10.0])
    for suffix in FORMATS[1:]:
        for a, b in zip(reference, _frfs(recordings[suffix]), strict=True):
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
