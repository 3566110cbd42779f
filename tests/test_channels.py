"""Recordings of several buses (``identification/samples/channels.py``): a role's message found
on more than one channel is refused unless the signal map names the role's channel, and with it
named, that channel's frames alone are decoded."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from json_schemas import validate

from dtid.acquisition.logfile import recorded_channel, write_log
from dtid.acquisition.plan import TestPlan
from dtid.cli import main
from dtid.dbc.loader import load_interface
from dtid.errors import AnalysisError, ConfigError
from dtid.identification.samples.recording import load_recording
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import simulate
from dtid.simulator.vehicle_frames import simulation_frames

ROOT = Path(__file__).resolve().parents[1]
SIGNALS = (ROOT / "dbc" / "drivetrain_signals.toml").read_text()


def _map(folder: Path, name: str, speed_channel: str | None) -> Path:
    """The product's signal map with the speed role's ``channel`` line (none when None)."""
    text = (
        SIGNALS
        if speed_channel is None
        else SIGNALS.replace("[speed]", f"[speed]\nchannel = {speed_channel}", 1)
    )
    path = folder / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def two_buses(reference: DrivetrainParameters, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 12 s test on bus 1 (``one.asc``), and the same with the engine speed forwarded by a
    gateway onto bus 2 0.3 ms later (``two.asc``, ``two.log``: candump names can0 and can1)."""
    folder = tmp_path_factory.mktemp("buses")
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=12.0)
    frames = simulation_frames(simulate(reference, plan, seed=2), load_interface())
    speed_id = load_interface().frame_key("speed")[0]
    for frame in frames:
        frame.channel = 0
    forwarded = []
    for frame in frames:
        if frame.arbitration_id == speed_id:
            twin = copy.copy(frame)
            twin.channel, twin.timestamp = 1, frame.timestamp + 3e-4
            forwarded.append(twin)
    both = sorted(frames + forwarded, key=lambda f: f.timestamp)
    write_log(folder / "one.asc", frames)
    write_log(folder / "two.asc", both)
    for frame in both:
        frame.channel = f"can{frame.channel}"
    write_log(folder / "two.log", both)
    return folder


def test_a_message_on_two_buses_is_shown_by_inspect_and_refused_by_the_analysis(
    two_buses: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = load_recording(two_buses / "two.asc", load_interface())
    assert recording.channels["speed"] == {"1": 2199, "2": 2199}
    assert recording.channels["mean_torque"] == {"1": 1099}
    with pytest.raises(AnalysisError) as raised:
        recording.test_data()
    message = str(raised.value)
    assert "role speed ('EngineSpeed', ID 0x" in message
    assert "comes on channels 1 (2199 frames), 2 (2199 frames)" in message
    assert "channel = 1" in message
    out = two_buses / "inspect.json"
    assert main(["inspect", str(two_buses / "two.asc"), "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    validate(document, "inspect")
    assert list(document["channel_problems"]) == ["speed"]
    assert "comes on channels 1 (2199 frames), 2 (2199 frames)" in capsys.readouterr().out
    signals = _map(two_buses, "bus2.toml", "2")
    assert main(["inspect", str(two_buses / "two.asc"), "--signals", str(signals)]) == 0
    printed = capsys.readouterr().out
    assert (
        "speed: its message is on channels 1 (2199 frames), 2 (2199 frames); the signal" in printed
    )
    assert main(["frf", str(two_buses / "two.asc")]) == 2
    assert "comes on channels 1" in capsys.readouterr().err


def test_the_named_channel_alone_is_decoded(two_buses: Path) -> None:
    """Bus 1 named: the speed is the one-bus recording's to the bit; bus 2: the gateway's copy,
    0.3 ms later, the same values."""
    alone = load_recording(two_buses / "one.asc", load_interface()).roles["speed"]
    for name, channel, delay in (("bus1.toml", "1", 0.0), ("bus2.toml", "2", 3e-4)):
        interface = load_interface(signals=_map(two_buses, name, channel))
        speed = load_recording(two_buses / "two.asc", interface).roles["speed"]
        np.testing.assert_array_equal(speed.values, alone.values)
        np.testing.assert_allclose(speed.timestamps, alone.timestamps + delay, atol=2e-6)
    interface = load_interface(signals=_map(two_buses, "can1.toml", '"can1"'))
    speed = load_recording(two_buses / "two.log", interface).roles["speed"]
    np.testing.assert_array_equal(speed.values, alone.values)


def test_a_wrong_or_useless_channel_is_named(two_buses: Path, capsys) -> None:
    interface = load_interface(signals=_map(two_buses, "bus3.toml", "3"))
    with pytest.raises(AnalysisError, match=r"is not on channel '3'.* but on 1 .*, 2 "):
        load_recording(two_buses / "two.asc", interface).test_data()
    signals = _map(two_buses, "bad.toml", "-1")
    assert main(["inspect", str(two_buses / "one.asc"), "--signals", str(signals)]) == 2
    assert "key 'channel' must be the recording's bus channel" in capsys.readouterr().err
    # a one-bus recording is read whatever channel the map names
    interface = load_interface(signals=_map(two_buses, "bus1.toml", "1"))
    assert len(load_recording(two_buses / "one.asc", interface).roles["speed"].values) > 100


def test_channels_are_named_as_the_file_counts_them() -> None:
    assert recorded_channel(0, ".asc") == recorded_channel(0, ".blf") == "1"
    assert recorded_channel(2, ".trc") == recorded_channel(2, ".mf4") == "2"
    assert recorded_channel("can1", ".log") == "can1"
    assert recorded_channel(None, ".csv") is None


def test_the_roles_of_one_message_read_one_channel(tmp_path: Path) -> None:
    (tmp_path / "m.toml").write_text(
        '[speed]\nmessage = "EngineSpeed"\nsignal = "EngineSpeedFiltered"\nchannel = 1\n'
        '[heartbeat]\nmessage = "EngineSpeed"\nsignal = "CrankEventCounter"\nchannel = 2\n'
    )
    with pytest.raises(ConfigError, match="roles of message 'EngineSpeed' name different"):
        load_interface(signals=tmp_path / "m.toml")
