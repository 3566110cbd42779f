"""Crank-synchronous roles told from time-periodic ones (``samples/crank_sampling.py``).

Analytic cases first: sample times made from a known engine speed, one sample every pi/2 of
crank angle, against a message sent every 10 or 20 ms. Then a recording as a production ECU
would broadcast it: the reference vehicle's simulated test with its engine speed re-sent every
10 ms (the last crank-synchronous value held, no crank counter), which the identification once
read as crank-synchronous and ended with a model that could not idle through any run.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import can
import numpy as np
import pytest
from json_schemas import validate

from dtid.acquisition.logfile import read_log, write_log
from dtid.acquisition.plan import TestPlan
from dtid.acquisition.stream import samples_roles
from dtid.cli import main
from dtid.dbc.interface import VehicleInterface
from dtid.dbc.loader import load_interface
from dtid.identification.samples.crank_sampling import (
    SPEED_PER_REVOLUTION,
    STROKES_PER_REVOLUTION,
    crank_sampling,
)
from dtid.identification.samples.recording import load_recording
from dtid.identification.service.live import LiveSession
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import simulate
from dtid.simulator.vehicle_frames import simulation_frames

ROOT = Path(__file__).resolve().parents[1]


def _engine(seconds: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """A fine time grid, s, and an engine speed on it, rpm: 800 rpm swept +-3 % at 1.5 Hz."""
    t = np.arange(0.0, seconds, 1e-4)
    return t, 800.0 * (1.0 + 0.03 * np.sin(2 * np.pi * 1.5 * t))


def _every(angle_rad: float, t: np.ndarray, rpm: np.ndarray) -> np.ndarray:
    """Times at which the crank has turned by each further ``angle_rad``, s."""
    angle = np.concatenate(([0.0], np.cumsum(np.diff(t) * rpm[:-1] * math.pi / 30.0)))
    return np.interp(np.arange(angle_rad, angle[-1], angle_rad), angle, t)


def test_crank_synchronous_samples_come_four_and_two_times_a_revolution() -> None:
    t, rpm = _engine()
    for angle, expected in ((math.pi / 2, SPEED_PER_REVOLUTION), (math.pi, STROKES_PER_REVOLUTION)):
        sampling = crank_sampling(_every(angle, t, rpm), t, rpm)
        assert sampling is not None
        assert sampling.per_revolution == pytest.approx(expected, rel=0.01)
        assert sampling.slope == pytest.approx(-1.0, abs=0.1)
        assert sampling.problem("speed", expected) is None


def test_a_time_periodic_message_is_told_even_where_its_rate_matches_the_crank() -> None:
    """100 Hz at 800 rpm is 7.5 samples a revolution; 50 Hz at 750 rpm is exactly four, and
    only the intervals' indifference to the speed gives it away."""
    t, rpm = _engine()
    for period_s, scale, per_revolution in ((0.01, 1.0, 7.5), (0.02, 750 / 800, 4.0)):
        sampling = crank_sampling(np.arange(0.0, 20.0, period_s), t, scale * rpm)
        assert sampling is not None
        assert sampling.per_revolution == pytest.approx(per_revolution, rel=0.01)
        assert sampling.slope == pytest.approx(0.0, abs=0.05)
        problem = sampling.problem("speed", SPEED_PER_REVOLUTION)
        assert problem is not None and "does not follow the engine speed" in problem


def test_a_steady_speed_is_judged_by_the_rate_alone() -> None:
    t = np.arange(0.0, 10.0, 1e-4)
    steady = np.full_like(t, 800.0)
    sampling = crank_sampling(_every(math.pi / 2, t, steady), t, steady)
    assert sampling is not None and sampling.slope is None
    assert sampling.problem("speed", SPEED_PER_REVOLUTION) is None


def _resent(
    frames: list[can.Message], message: str, interface: VehicleInterface
) -> list[can.Message]:
    """``frames`` with ``message`` re-sent every 10 ms, each time its latest value."""
    frame_id = interface.database.get_message_by_name(message).frame_id
    own = [f for f in frames if f.arbitration_id == frame_id]
    times = np.arange(own[0].timestamp, own[-1].timestamp, 0.01)
    latest = np.searchsorted([f.timestamp for f in own], times, side="right") - 1
    resent = [
        can.Message(timestamp=t, arbitration_id=frame_id, data=own[k].data, is_extended_id=False)
        for t, k in zip(times, latest, strict=True)
    ]
    others = [f for f in frames if f.arbitration_id != frame_id]
    return sorted(others + resent, key=lambda f: f.timestamp)


@pytest.fixture(scope="module")
def periodic(reference: DrivetrainParameters, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference vehicle's 20 s test as simulated (``crank.blf``), with the speed re-sent
    every 10 ms (``periodic.blf``) and with the total torque request so (``request.blf``), and a
    signal map without the crank counters (a periodic message has none)."""
    folder = tmp_path_factory.mktemp("periodic")
    interface = load_interface()
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=20.0)
    frames = simulation_frames(simulate(reference, plan, seed=5), interface)
    write_log(folder / "crank.blf", frames)
    write_log(folder / "periodic.blf", _resent(frames, "EngineSpeed", interface))
    write_log(folder / "request.blf", _resent(frames, "EngineTorqueRequest", interface))
    text = (ROOT / "dbc" / "drivetrain_signals.toml").read_text()
    for counter in ("CrankEventCounter", "RequestCounter"):
        text = text.replace(f'counter = "{counter}"\n', "")
    (folder / "signals.toml").write_text(text)
    return folder


def test_a_time_periodic_speed_is_refused_and_inspect_says_why(
    periodic: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording, signals = periodic / "periodic.blf", periodic / "signals.toml"
    assert main(["identify", str(recording), "--signals", str(signals)]) == 2
    error = capsys.readouterr().err
    assert "the speed role comes 6.0 times a crank revolution" in error
    assert "does not follow the engine speed" in error
    out = periodic / "inspect.json"
    assert main(["inspect", str(recording), "--signals", str(signals), "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    validate(document, "inspect")
    assert set(document["sampling"]) == {"speed"}  # the mean torque still comes per stroke
    assert "frf, identify and diagnose refuse" in capsys.readouterr().out


def test_a_time_periodic_torque_request_is_left_out_with_a_warning(
    periodic: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A periodic request cannot be latched stroke by stroke: the model is driven by the
    measured torque instead, as for a recording without the role, and the log says why."""
    interface = load_interface(signals=periodic / "signals.toml")
    with caplog.at_level("WARNING"):
        data = load_recording(periodic / "request.blf", interface).test_data()
    assert data.torque_request is None
    assert "the torque_request role comes 6.0 times a crank revolution" in caplog.text
    assert "driven by the measured mean torque instead" in caplog.text


def test_the_live_worker_says_once_that_it_left_the_request_out(
    periodic: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The worker reads its growing session again at every block: the request left out is
    warned about once a session, not never (it reads without :meth:`test_data`'s warnings)
    and not at every read."""
    interface = load_interface(signals=periodic / "signals.toml")
    frames = read_log(periodic / "request.blf")
    plan = {"amplitudes_nm": [5.0, 10.0]}
    start = {"kind": "session", "session": "s1", "log_path": "request.blf", "plan": plan}
    live = LiveSession({**start, "seq": 0, "log_start_s": frames[0].timestamp}, interface)
    times = np.array([f.timestamp for f in frames])
    reads = []
    with caplog.at_level("WARNING"):
        for lo in np.arange(times[0], times[-1] + 0.25, 0.25):
            a, b = np.searchsorted(times, [lo, lo + 0.25])
            roles = samples_roles(interface.decode(frames[a:b]))
            live.apply({"kind": "samples", "roles": roles, "frames": int(b - a)})
            if lo - times[0] > 5.0 and len(reads) < 3:  # three reads as the blocks come
                reads.append(live.test_data())
    assert all(data.torque_request is None for data in reads)
    assert caplog.text.count("the torque_request role comes 6.0 times a crank revolution") == 1


def test_a_speed_of_no_running_engine_points_to_the_dbc() -> None:
    """A DBC that is not the vehicle's decodes another message as the speed (an independent
    recording read with the product's DBC: 33 rpm at 28 Hz): the problem says so."""
    times = np.arange(0.0, 10.0, 1 / 28.3)
    sampling = crank_sampling(times, times, np.full_like(times, 33.0) + 0.5 * np.sin(times))
    assert sampling is not None
    problem = sampling.problem("speed", 4.0)
    assert problem is not None and "it reads 33 rpm, no running engine's speed" in problem
    assert "give the vehicle's DBC with --dbc" in problem


def test_a_speed_in_the_wrong_unit_is_named_by_its_own_timing(
    periodic: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The crank-synchronous speed mapped with its value in rad/s read as rpm (a scale of
    pi/30): its samples' timing says the crank turns 9.55 times faster than the values do.
    Before the check, `dtid frf` read K 4.1 and an engine lag of 0.34 s from it, silently."""
    text = (periodic / "signals.toml").read_text()
    speed = 'signal = "EngineSpeedFiltered"\n'
    (periodic / "radps.toml").write_text(text.replace(speed, speed + "scale = 0.10472\n"))
    argv = ["frf", str(periodic / "crank.blf"), "--signals", str(periodic / "radps.toml")]
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert "the speed role comes 38.2 times a crank revolution" in error
    assert "the speed's values are 0.105 times what the samples' timing implies" in error
    assert "another signal" not in error  # its timing is the crank's: the unit is what is off
    assert (
        main(["frf", str(periodic / "crank.blf"), "--signals", str(periodic / "signals.toml")]) == 0
    )


def test_the_strokes_of_a_three_cylinder_engine_are_named() -> None:
    """A three-cylinder four-stroke engine fires every 4*pi/3: its mean torque comes 1.5 times a
    revolution, which the four-cylinder model cannot read."""
    t, rpm = _engine()
    sampling = crank_sampling(_every(4 * math.pi / 3, t, rpm), t, rpm)
    assert sampling is not None and sampling.per_revolution == pytest.approx(1.5, rel=0.01)
    problem = sampling.problem("mean_torque", STROKES_PER_REVOLUTION)
    assert problem is not None and "a four-stroke engine of 3 cylinders" in problem
