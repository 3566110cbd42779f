"""Tests of the vehicle CAN interface: product DBC, checksum, signal maps, decode and encode."""

import json
import logging
import math
import tomllib
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from dtid.acquisition.logfile import read_log
from dtid.dbc import (
    DEFAULT_DBC,
    DEFAULT_SIGNAL_MAP,
    REQUIRED_ROLES,
    apply_checksum,
    compute_checksum,
    load_database,
    load_signal_map,
    verify_checksum,
)
from dtid.dbc.loader import load_interface
from dtid.dbc.role_candidates import SHOWN, describe_candidates, signals_by_unit
from dtid.dbc.roles import DEFAULT_REQUEST_TIMEOUT_S
from dtid.errors import ConfigError, DbcError

PRODUCT_MESSAGES = {
    "EngineSpeed": (0x1A0, "ECU"),
    "EngineMeanTorque": (0x1A1, "ECU"),
    "EngineTorqueRequest": (0x1A2, "ECU"),
    "TestTorqueRequest": (0x6A0, "TOOL"),
    "ToolHeartbeat": (0x6A1, "TOOL"),
}


@pytest.fixture(scope="module")
def database():
    return load_database(DEFAULT_DBC)


@pytest.fixture(scope="module")
def interface(database):
    return load_signal_map(DEFAULT_SIGNAL_MAP).bind(database, DEFAULT_DBC)


def write_map(tmp_path, text, name="map.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def crc8_sae_j1850(data):
    """Bitwise reference: polynomial 0x1D, initial value 0xFF, final XOR 0xFF, not reflected."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


# --- product DBC --------------------------------------------------------------------------------


def test_default_files_are_packaged():
    assert isinstance(DEFAULT_DBC, Path) and DEFAULT_DBC.is_file()
    assert isinstance(DEFAULT_SIGNAL_MAP, Path) and DEFAULT_SIGNAL_MAP.is_file()


def test_product_dbc_loads_strictly_without_warning(caplog):
    cantools.database.load_file(DEFAULT_DBC, strict=True)
    with caplog.at_level(logging.WARNING):
        load_database(DEFAULT_DBC)
    assert not caplog.records


def test_product_dbc_layout(database):
    assert {message.name for message in database.messages} == set(PRODUCT_MESSAGES)
    for name, (frame_id, sender) in PRODUCT_MESSAGES.items():
        message = database.get_message_by_name(name)
        assert (message.frame_id, message.senders) == (frame_id, [sender])
        assert message.length == 8 and not message.is_extended_frame and not message.is_fd
        assert message.comment
        for signal in message.signals:
            assert signal.byte_order == "little_endian"
            assert signal.minimum is not None and signal.maximum is not None
            assert signal.comment
    test_torque = database.get_message_by_name("TestTorqueRequest")
    assert "CRC-8/SAE-J1850" in test_torque.comment and "bytes 1..7" in test_torque.comment
    checksum = test_torque.get_signal_by_name("Checksum")
    assert (checksum.start, checksum.length) == (0, 8)
    state = database.get_message_by_name("ToolHeartbeat").get_signal_by_name("ToolState")
    assert dict(state.choices) == {0: "idle", 1: "settling", 2: "chirp", 3: "abort", 4: "done"}


# --- checksum -----------------------------------------------------------------------------------


def test_checksum_is_crc8_sae_j1850_over_bytes_1_to_7():
    rng = np.random.default_rng(0)
    for _ in range(50):
        payload = bytes(rng.integers(0, 256, 8, dtype=np.uint8))
        assert compute_checksum(payload) == crc8_sae_j1850(payload[1:])
        protected = apply_checksum(payload)
        assert protected[1:] == payload[1:] and verify_checksum(protected)


def test_checksum_fails_on_any_flipped_bit(interface):
    payload = bytes(interface.encode("test_torque", 12.5, 0.0, counter=3, enable=1).data)
    assert verify_checksum(payload)
    for bit in range(64):
        damaged = bytearray(payload)
        damaged[bit // 8] ^= 1 << (bit % 8)
        assert not verify_checksum(damaged), bit


def test_checksum_needs_8_bytes():
    with pytest.raises(ValueError, match="8 bytes"):
        compute_checksum(bytes(7))
    assert not verify_checksum(bytes(7))


def test_explicit_checksum_is_sent_as_given(interface):
    frame = interface.encode("test_torque", 1.0, 0.0, counter=1, enable=1, checksum=0x55)
    assert frame.data[0] == 0x55 and not verify_checksum(frame.data)


# --- encode and decode --------------------------------------------------------------------------


def random_value(signal, rng):
    low, high = signal.minimum, signal.maximum
    if signal.scale == 1 and float(low).is_integer():
        return int(rng.integers(int(low), int(high) + 1))
    return float(rng.uniform(low, high))


@pytest.mark.parametrize(
    "role", ["speed", "mean_torque", "test_torque", "torque_request", "heartbeat"]
)
def test_round_trip_of_every_signal(interface, database, role):
    spec = interface.signal_map.roles[role]
    message = database.get_message_by_name(spec.message)
    extra = spec.extra_signals()
    rng = np.random.default_rng(1)
    values = [message.get_signal_by_name(spec.signal).minimum]
    values += [message.get_signal_by_name(spec.signal).maximum]
    frames, expected = [], []
    for index in range(200):
        given = {
            signal.name: random_value(signal, rng)
            for signal in message.signals
            if signal.name not in (spec.signal, spec.checksum)
        }
        signal = message.get_signal_by_name(spec.signal)
        value = values[index] if index < len(values) else random_value(signal, rng)
        frames.append(interface.encode(role, value, 0.01 * index, **given))
        expected.append((value, given))
    series = interface.decode(frames)[role]
    assert series.n_bad == 0
    np.testing.assert_array_equal(series.timestamps, 0.01 * np.arange(200))
    step = message.get_signal_by_name(spec.signal).scale
    for index, (value, given) in enumerate(expected):
        assert abs(series.values[index] - value) <= step
        decoded = database.decode_message(message.frame_id, frames[index].data)
        for name, sent in given.items():
            assert abs(decoded[name] - sent) <= message.get_signal_by_name(name).scale, name
        for key, name in extra.items():
            if key == "checksum":
                assert series.extra[key][index] == compute_checksum(frames[index].data)
            else:
                assert series.extra[key][index] == given[name]


def test_encoded_frame_carries_dbc_id_and_timestamp(interface):
    frame = interface.encode("test_torque", -2.5, 12.34, counter=15, enable=1)
    assert (frame.arbitration_id, frame.is_extended_id, frame.dlc) == (0x6A0, False, 8)
    assert frame.timestamp == 12.34


def test_unset_signals_default_to_zero_or_minimum(tmp_path):
    dbc = tmp_path / "offset.dbc"
    dbc.write_text(
        'BO_ 291 M: 8 ECU\n SG_ Speed : 0|16@1+ (1,0) [0|8000] "rpm" TOOL\n'
        ' SG_ Gear : 16|4@1+ (1,0) [1|8] "" TOOL\n'
        ' SG_ Temp : 24|8@1+ (1,-40) [-40|215] "degC" TOOL\n'
    )
    signal_map = load_signal_map(write_map(tmp_path, '[speed]\nmessage = "M"\nsignal = "Speed"\n'))
    database = load_database(dbc)
    frame = signal_map.bind(database, dbc).encode("speed", 900.0, 0.0)
    assert database.decode_message("M", frame.data) == {"Speed": 900, "Gear": 1, "Temp": 0}


def test_encode_rejects_out_of_range_value(interface):
    with pytest.raises(ConfigError, match=r"role 'test_torque' = 400 N\*m.*TestTorque"):
        interface.encode("test_torque", 400.0, 0.0)


def test_encode_rejects_unknown_signal(interface):
    with pytest.raises(ValueError, match="'Bogus'"):
        interface.encode("speed", 800.0, 0.0, Bogus=1)


def test_decode_counts_bad_frames_and_ignores_other_frames(interface, caplog):
    good = [interface.encode("speed", 800.0 + k, 0.015 * k, counter=k) for k in range(10)]
    # python-can's Message defaults to an extended ID
    short = can.Message(timestamp=0.2, arbitration_id=0x1A0, is_extended_id=False, data=bytes(7))
    extended = can.Message(timestamp=0.3, arbitration_id=0x1A0, data=bytes(8))
    remote = can.Message(
        timestamp=0.4, arbitration_id=0x1A0, is_extended_id=False, is_remote_frame=True, dlc=8
    )
    error = can.Message(timestamp=0.5, is_error_frame=True)
    other = can.Message(timestamp=0.6, arbitration_id=0x123, is_extended_id=False, data=bytes(8))
    with caplog.at_level(logging.WARNING):
        series = interface.decode([*good, short, extended, remote, error, other])
    speed = series["speed"]
    assert speed.n_bad == 1 and "skipped 1 of 11 frames of message 'EngineSpeed'" in caplog.text
    np.testing.assert_allclose(speed.values, 800.0 + np.arange(10))
    np.testing.assert_array_equal(speed.extra["counter"], np.arange(10))
    assert speed.extra["counter"].dtype == np.int64
    assert series["mean_torque"].values.size == 0 and series["mean_torque"].n_bad == 0
    assert list(series) == ["speed", "mean_torque", "test_torque", "torque_request", "heartbeat"]


def test_values_the_dbc_names_are_not_measurements(tmp_path, caplog):
    """A production DBC names the raw values that say "no measurement", outside the signal's
    range (Ford's engine speed: range 0-16383.5 rpm, 65535 "Invalid" decoded 16383.75 rpm);
    decoded as numbers they would be engine speeds. They are left out with a warning; a named
    value inside the range (0 "Stopped") and the heartbeat's states stay."""
    dbc = tmp_path / "named.dbc"
    dbc.write_text(
        'BO_ 416 Speed: 8 ECU\n SG_ N : 0|16@1+ (0.25,0) [0|16383.25] "rpm" TOOL\n'
        ' SG_ State : 16|8@1+ (1,0) [0|255] "" TOOL\n\n'
        'VAL_ 416 N 65535 "Invalid" 65534 "Init" 0 "Stopped" ;\n'
        'VAL_ 416 State 0 "idle" 2 "chirp" ;\n'
    )
    text = '[speed]\nmessage = "Speed"\nsignal = "N"\n'
    text += '[heartbeat]\nmessage = "Speed"\nsignal = "State"\n'
    interface = load_signal_map(write_map(tmp_path, text)).bind(load_database(dbc), dbc)
    values = [16383.75, 800.0, 16383.5, 801.0, 16383.75, 0.0]
    frames = [interface.encode("speed", v, 0.015 * k) for k, v in enumerate(values)]
    for frame in frames:
        frame.data[2] = 2  # State "chirp"
    with caplog.at_level(logging.WARNING):
        series = interface.decode(frames)
    np.testing.assert_array_equal(series["speed"].values, [800.0, 801.0, 0.0])
    np.testing.assert_allclose(series["speed"].timestamps, [0.015, 0.045, 0.075])
    assert series["speed"].n_bad == 0 and series["speed"].not_measured == 3
    assert "left out 2 'Invalid', 1 'Init' of 6 frames of message 'Speed'" in caplog.text
    np.testing.assert_array_equal(series["heartbeat"].values, [2.0] * 6)
    # dtid inspect counts them beside the frames it could not decode
    from json_schemas import validate

    from dtid.acquisition.logfile import write_log
    from dtid.cli import main

    write_log(tmp_path / "named.asc", frames)
    out, signals = tmp_path / "inspect.json", tmp_path / "map.toml"
    argv = ["inspect", str(tmp_path / "named.asc"), "--dbc", str(dbc), "--signals", str(signals)]
    assert main([*argv, "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    validate(document, "inspect")
    assert document["roles"]["speed"]["not_measured"] == 3
    assert document["roles"]["speed"]["count"] == 3


def test_a_validity_flag_leaves_out_the_frames_it_marks(tmp_path, caplog):
    """The map's ``valid`` names the ECU's flag of the value; a frame whose flag is not among
    ``valid_values`` ([1] unless given) carries no measurement."""
    dbc = tmp_path / "flag.dbc"
    dbc.write_text(
        'BO_ 416 Speed: 8 ECU\n SG_ N : 0|16@1+ (0.25,0) [0|16383.75] "rpm" TOOL\n'
        ' SG_ Valid : 16|2@1+ (1,0) [0|3] "" TOOL\n'
    )
    frames = [
        can.Message(
            timestamp=0.015 * k,
            arbitration_id=416,
            is_extended_id=False,
            data=bytes([int(4 * (800 + k)) & 0xFF, int(4 * (800 + k)) >> 8, flag, 0, 0, 0, 0, 0]),
        )
        for k, flag in enumerate([0, 1, 1, 2, 1, 0])
    ]
    speed = '[speed]\nmessage = "Speed"\nsignal = "N"\nvalid = "Valid"\n'
    for extra, kept in (("", [801, 802, 804]), ("valid_values = [1, 2]\n", [801, 802, 803, 804])):
        signal_map = load_signal_map(write_map(tmp_path, speed + extra))
        with caplog.at_level(logging.WARNING):
            series = signal_map.bind(load_database(dbc), dbc).decode(frames)["speed"]
        np.testing.assert_array_equal(series.values, kept)
        assert series.not_measured == 6 - len(kept)
    assert "left out 2 with Valid = 0, 1 with Valid = 2 of 6 frames" in caplog.text
    for text, match in (
        ('[speed]\nmessage = "A"\nsignal = "B"\nvalid_values = [1]\n', "without 'valid'"),
        (speed + "valid_values = 1\n", "must list the raw values"),
        (speed + "valid_values = [-1]\n", "must list the raw values"),
        ('[test_torque]\nmessage = "A"\nsignal = "B"\nvalid = "C"\n', "unknown key 'valid'"),
        ("# roles to come\n", "maps no role: it needs a table for each of speed"),  # was: "no
        # speed frames found" once the recording had been read
    ):
        with pytest.raises(ConfigError, match=match):
            load_signal_map(write_map(tmp_path, text))


def test_the_independent_speed_flag_reads_every_frame_valid(tmp_path):
    """The independent recordings' EMS_EngSpdValid is 1 on every frame: read through the
    flag, the speed is the same series."""
    folder = Path(__file__).resolve().parents[2] / "shared" / "independent" / "vehicle_2"
    if not folder.is_dir():
        pytest.skip(f"independent recordings not present in {folder}")

    text = (folder / "signals.toml").read_text()
    flagged = write_map(tmp_path, text.replace("[speed]", '[speed]\nvalid = "EMS_EngSpdValid"'))
    frames = read_log(folder / "run_A5.asc")
    plain = load_interface(folder / "oem_vehicle.dbc", folder / "signals.toml").decode(frames)
    through = load_interface(folder / "oem_vehicle.dbc", flagged).decode(frames)
    np.testing.assert_array_equal(through["speed"].values, plain["speed"].values)
    assert len(plain["speed"].values) > 3000


def test_extended_ids_are_respected(tmp_path):
    dbc = tmp_path / "extended.dbc"
    dbc.write_text(
        'BO_ 2147484064 Speed: 8 ECU\n SG_ N : 0|16@1+ (0.25,0) [0|16383.75] "rpm" TOOL\n'
    )
    signal_map = load_signal_map(write_map(tmp_path, '[speed]\nmessage = "Speed"\nsignal = "N"\n'))
    interface = signal_map.bind(load_database(dbc), dbc)
    frame = interface.encode("speed", 750.0, 1.0)
    assert frame.is_extended_id and frame.arbitration_id == 0x1A0
    standard = can.Message(
        timestamp=2.0, arbitration_id=0x1A0, is_extended_id=False, data=frame.data
    )
    speed = interface.decode([frame, standard])["speed"]
    assert speed.values.tolist() == [750.0] and speed.timestamps.tolist() == [1.0]


def test_checksum_of_a_foreign_message_is_not_computed(tmp_path, caplog):
    dbc = tmp_path / "foreign.dbc"
    dbc.write_text(DEFAULT_DBC.read_text().replace("BO_ 1696 ", "BO_ 1700 "))
    with caplog.at_level(logging.WARNING):
        interface = load_signal_map(DEFAULT_SIGNAL_MAP).bind(load_database(dbc), dbc)
    assert "not the checksum of the product's own DBC" in caplog.text
    assert interface.encode("test_torque", 5.0, 0.0, counter=1).data[0] == 0


def test_unit_and_scale(tmp_path, database):
    path = write_map(
        tmp_path,
        '[speed]\nmessage = "EngineSpeed"\nsignal = "EngineSpeedFiltered"\n'
        'unit = "rad/s"\nscale = 0.5\n'
        '[mean_torque]\nmessage = "EngineMeanTorque"\nsignal = "MeanTorque"\nscale = 4.5\n'
        'unit = "N*m"\n',
    )
    interface = load_signal_map(path).bind(database, DEFAULT_DBC)
    speed_gain = 0.5 * 60.0 / (2.0 * math.pi)
    assert interface.signal_map.roles["speed"].gain == pytest.approx(speed_gain)
    speed = interface.encode("speed", 1000.0, 0.0)
    torque = interface.encode("mean_torque", 45.0, 0.0)
    signal = database.decode_message("EngineSpeed", speed.data)["EngineSpeedFiltered"]
    assert signal == pytest.approx(1000.0 / speed_gain, abs=0.125)
    assert database.decode_message("EngineMeanTorque", torque.data)["MeanTorque"] == 10.0
    series = interface.decode([speed, torque])
    assert series["speed"].values[0] == pytest.approx(1000.0, abs=0.125 * speed_gain)
    assert series["mean_torque"].values[0] == pytest.approx(45.0)


# --- signal maps --------------------------------------------------------------------------------


def test_default_map_maps_every_role():
    signal_map = load_signal_map(DEFAULT_SIGNAL_MAP)
    assert signal_map.present_roles() == (
        "speed",
        "mean_torque",
        "test_torque",
        "torque_request",
        "heartbeat",
    )
    assert signal_map.missing_roles() == ()
    test_torque = signal_map.roles["test_torque"]
    assert test_torque.extra_signals() == {
        "counter": "AliveCounter",
        "enable": "TestEnable",
        "checksum": "Checksum",
    }
    assert signal_map.roles["speed"].counter == "CrankEventCounter"
    assert signal_map.roles["mean_torque"].cylinder == "CylinderIndex"


def test_partial_map_reports_missing_roles(tmp_path, database):
    path = write_map(tmp_path, '[speed]\nmessage = "EngineSpeed"\nsignal = "EngineSpeedFiltered"\n')
    signal_map = load_signal_map(path)
    interface = signal_map.bind(database, DEFAULT_DBC)
    assert interface.present_roles() == ("speed",)
    assert interface.missing_roles() == ("mean_torque", "test_torque")
    assert signal_map.missing_roles((*REQUIRED_ROLES, "torque_request"))[-1] == "torque_request"
    signal_map.require("speed")
    with pytest.raises(ConfigError, match=r"map.toml lacks role 'mean_torque', 'test_torque'"):
        signal_map.require()
    with pytest.raises(ConfigError, match=r"lacks role 'test_torque'.*\[test_torque\]"):
        interface.encode("test_torque", 1.0, 0.0)
    assert list(interface.decode([])) == ["speed"]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            '[sped]\nmessage = "A"\nsignal = "B"\n',
            r"map.toml: unknown role \[sped\] \(did you mean 'speed'\?\)",
        ),
        (
            '[speed]\nmessage = "A"\nsignl = "B"\n',
            r"role 'speed' has unknown key 'signl' \(did you mean 'signal'\?\)",
        ),
        (
            '[heartbeat]\nmessage = "A"\nsignal = "B"\nscale = 2\n',
            r"role 'heartbeat' has unknown key 'scale'",
        ),
        ('[speed]\nmessage = "A"\n', r"role 'speed' lacks key 'signal'; add signal = "),
        (
            '[speed]\nmessage = 5\nsignal = "B"\n',
            r"role 'speed' key 'message' must be a non-empty string.*integer 5",
        ),
        (
            '[speed]\nmessage = "A"\nsignal = "B"\ncounter = ""\n',
            r"role 'speed' key 'counter' must be a non-empty string",
        ),
        ('speed = "A"\n', r"role 'speed' must be a table"),
        (
            '[speed]\nmessage = "A"\nsignal = "B"\nunit = "rad/sec"\n',
            r"role 'speed' key 'unit' is 'rad/sec'.*'rpm', 'rad/s'",
        ),
        (
            '[mean_torque]\nmessage = "A"\nsignal = "B"\nunit = "rpm"\n',
            r"role 'mean_torque' key 'unit' is 'rpm'.*'N\*m'",
        ),
        (
            '[mean_torque]\nmessage = "A"\nsignal = "B"\nscale = 0\n',
            r"role 'mean_torque' key 'scale' must be a finite number > 0, got 0",
        ),
        (
            '[mean_torque]\nmessage = "A"\nsignal = "B"\nscale = -4.5\n',
            r"key 'scale' must be a finite number > 0",
        ),
        (
            '[mean_torque]\nmessage = "A"\nsignal = "B"\nscale = nan\n',
            r"key 'scale' must be a finite number > 0",
        ),
        (
            '[mean_torque]\nmessage = "A"\nsignal = "B"\nscale = inf\n',
            r"key 'scale' must be a finite number > 0",
        ),
        (
            '[mean_torque]\nmessage = "A"\nsignal = "B"\nscale = "4.5"\n',
            r"key 'scale' must be a number, got string",
        ),
        (
            '[mean_torque]\nmessage = "A"\nsignal = "B"\nscale = true\n',
            r"key 'scale' must be a number, got boolean",
        ),
        (
            '[speed]\nmessage = "A"\nsignal = "B"\ntimeout_s = 0.05\n',
            r"role 'speed' has unknown key 'timeout_s'",
        ),
        (
            '[test_torque]\nmessage = "A"\nsignal = "B"\ntimeout_s = 0\n',
            r"key 'timeout_s' must be a number of seconds > 0, got integer 0",
        ),
        (
            '[test_torque]\nmessage = "A"\nsignal = "B"\ntimeout_s = "50 ms"\n',
            r"key 'timeout_s' must be a number of seconds > 0, got string",
        ),
        ("[speed\n", r"map.toml is not valid TOML"),
    ],
)
def test_signal_map_errors(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_signal_map(write_map(tmp_path, text))


def test_request_timeout_is_the_default_unless_the_map_gives_it(tmp_path):
    text = '[test_torque]\nmessage = "A"\nsignal = "B"\n'
    default = load_signal_map(write_map(tmp_path, text)).roles["test_torque"]
    assert default.timeout_s == DEFAULT_REQUEST_TIMEOUT_S
    given = load_signal_map(write_map(tmp_path, text + "timeout_s = 0.2\n")).roles["test_torque"]
    assert given.timeout_s == 0.2


def test_missing_signal_map(tmp_path):
    with pytest.raises(ConfigError, match=r"signal map .*nope.toml does not exist"):
        load_signal_map(tmp_path / "nope.toml")


def test_unknown_message_is_reported_with_suggestions(tmp_path, database):
    path = write_map(tmp_path, '[speed]\nmessage = "EngineSped"\nsignal = "EngineSpeedFiltered"\n')
    with pytest.raises(
        DbcError,
        match=r"map.toml: role 'speed' names message 'EngineSped' which is not in "
        r".*drivetrain.dbc; messages with similar names: EngineSpeed",
    ):
        load_signal_map(path).bind(database, DEFAULT_DBC)


def test_unknown_signal_is_reported_with_suggestions(tmp_path, database):
    path = write_map(
        tmp_path,
        '[speed]\nmessage = "EngineSpeed"\nsignal = "EngineSpeedFiltered"\n'
        'counter = "CrankCounter"\n',
    )
    with pytest.raises(
        DbcError,
        match=r"role 'speed' names signal 'CrankCounter' \(key 'counter'\) which is not in message "
        r"'EngineSpeed' of .*; signals with similar names: CrankEventCounter",
    ):
        load_signal_map(path).bind(database, DEFAULT_DBC)


# --- load_database ------------------------------------------------------------------------------


def test_load_database_errors(tmp_path):
    with pytest.raises(DbcError, match=r"CAN database .*missing.dbc does not exist"):
        load_database(tmp_path / "missing.dbc")
    with pytest.raises(DbcError, match="is a directory"):
        load_database(tmp_path)
    garbage = tmp_path / "garbage.dbc"
    garbage.write_bytes(b"garbage\nmore garbage\n")
    with pytest.raises(
        DbcError, match=r"garbage.dbc is not a valid DBC file: Invalid syntax"
    ) as info:
        load_database(garbage)
    assert "\n" not in str(info.value)
    garbage.write_bytes(b"\x00\x01garbage\nmore garbage\n")
    with pytest.raises(DbcError, match=r"garbage.dbc is a binary file, not a DBC"):
        load_database(garbage)
    empty = tmp_path / "empty.dbc"
    empty.write_text('VERSION ""\n\nBS_:\n\nBU_: A\n')
    with pytest.raises(DbcError, match="defines no messages"):
        load_database(empty)


# --- third-party DBCs and logs ------------------------------------------------------------------


def test_vw_pq_loads_only_leniently_and_binds(realdata, tmp_path, caplog):
    path = realdata / "opendbc_vw_pq.dbc"
    with pytest.raises(cantools.database.UnsupportedDatabaseFormatError):
        cantools.database.load_file(path, strict=True)
    with caplog.at_level(logging.WARNING):
        database = load_database(path)
    assert "opendbc_vw_pq.dbc: strict checking rejected the database (The signals" in caplog.text
    signal_map = load_signal_map(
        write_map(
            tmp_path,
            '[speed]\nmessage = "Motor_1"\nsignal = "Motordrehzahl"\n'
            '[mean_torque]\nmessage = "Motor_1"\nsignal = "inneres_Motor_Moment"\nscale = 3.0\n',
        )
    )
    interface = signal_map.bind(database, path)
    frames = [interface.encode("speed", 850.0, 0.0), interface.encode("mean_torque", 39.0, 0.01)]
    assert frames[0].arbitration_id == 0x280
    series = interface.decode(frames)  # each frame sets one role's signal, the other is 0
    assert series["speed"].values.tolist() == [850.0, 0.0]
    assert series["mean_torque"].values[1] == pytest.approx(39.0, abs=0.39 * 3.0)


def test_bmw_e9x_binds_engine_speed_and_torque(realdata, tmp_path):
    path = realdata / "opendbc_bmw_e9x_e8x.dbc"
    signal_map = load_signal_map(
        write_map(
            tmp_path,
            '[speed]\nmessage = "AccPedal"\nsignal = "EngineSpeed"\n'
            '[mean_torque]\nmessage = "EngineAndBrake"\nsignal = "EngineTorque"\n',
        )
    )
    interface = signal_map.bind(load_database(path), path)
    frames = [interface.encode("speed", 760.0, 0.0), interface.encode("mean_torque", -12.5, 0.0)]
    series = interface.decode(frames)
    assert series["speed"].values.tolist() == [760.0]
    assert series["mean_torque"].values.tolist() == [-12.5]


def test_hyundai_kia_decodes_genesis_log(realdata, tmp_path):
    path = realdata / "opendbc_hyundai_kia_generic.dbc"
    signal_map = load_signal_map(
        write_map(
            tmp_path,
            '[speed]\nmessage = "EMS11"\nsignal = "N"\n'
            '[mean_torque]\nmessage = "EMS11"\nsignal = "TQI_ACOR"\nscale = 4.5\n',
        )
    )
    interface = signal_map.bind(load_database(path), path)
    assert interface.missing_roles() == ("test_torque",)
    frames = read_log(realdata / "genesis_autolog.log")
    assert len(frames) == 55314
    series = interface.decode(frames)
    speed, torque = series["speed"], series["mean_torque"]
    assert speed.n_bad == 0 and speed.values.size > 3000
    assert 600.0 <= speed.values.min() and speed.values.max() <= 2500.0
    rate = 1.0 / np.median(np.diff(speed.timestamps))
    assert 90.0 < rate < 110.0
    np.testing.assert_array_equal(torque.timestamps, speed.timestamps)
    assert 0.0 <= torque.values.min() and torque.values.max() <= 450.0


def test_ford_dbc_loads(realdata):
    database = load_database(realdata / "ford_lincoln_base_pt.dbc")
    assert len(database.messages) == 331


# --- a foreign DBC: its candidate signals for the roles -------------------------------------------

FOREIGN_DBC = """VERSION ""
BS_:
BU_: EMS TCU
BO_ 256 Motor_1: 8 EMS
 SG_ Motordrehzahl : 0|16@1+ (0.25,0) [0|16383] "U/min" TCU
 SG_ Fahrpedal : 16|8@1+ (0.4,0) [0|100] "%" TCU
 SG_ Moment_Ist : 24|16@1+ (0.1,0) [0|500] " Nm " TCU
BO_ 257 Raeder: 8 EMS
 SG_ Rad_VL : 0|16@1+ (0.01,0) [0|600] "rad/s" TCU
 SG_ Drehzahl_Soll : 16|16@1+ (1,0) [0|8000] "RPM" TCU
"""


def test_a_foreign_dbc_is_answered_with_its_signals_in_a_speeds_and_a_torques_unit(tmp_path):
    path = tmp_path / "foreign.dbc"
    path.write_text(FOREIGN_DBC)
    # the engine speeds (U/min, RPM) before the wheel's rad/s; the pedal's % is none
    assert signals_by_unit(load_database(path)) == {
        "rpm": [
            ("Motor_1.Motordrehzahl", "rpm"),
            ("Raeder.Drehzahl_Soll", "rpm"),
            ("Raeder.Rad_VL", "rad/s"),
        ],
        "N*m": [("Motor_1.Moment_Ist", "N*m")],
    }
    with pytest.raises(DbcError) as error:
        load_interface(dbc=path)
    said = str(error.value)
    assert "is not the product's DBC: pass a signal map for it with --signals" in said
    assert (
        "speed (rpm): Motor_1.Motordrehzahl, Raeder.Drehzahl_Soll, Raeder.Rad_VL (unit = "
        '"rad/s"); mean_torque, test_torque, torque_request (N*m): Motor_1.Moment_Ist (many'
    ) in said
    assert "Fahrpedal" not in said


def test_a_long_list_of_candidates_is_cut_and_a_dbc_without_any_says_so(tmp_path):
    many = "".join(
        f'BO_ {300 + k} M{k}: 8 EMS\n SG_ N{k} : 0|16@1+ (1,0) [0|8000] "rpm" TCU\n'
        for k in range(SHOWN + 3)
    )
    path = tmp_path / "many.dbc"
    path.write_text('VERSION ""\nBS_:\nBU_: EMS TCU\n' + many)
    said = describe_candidates(load_database(path), ("speed", "mean_torque", "heartbeat"))
    assert (
        said.startswith("speed (rpm): M0.N0, M1.N1, ")
        and f"M{SHOWN - 1}.N{SHOWN - 1} and 3 more" in said
    )
    assert f"M{SHOWN}.N{SHOWN}" not in said
    assert "; mean_torque (N*m): none (many ECUs give their torques in %" in said


def test_the_independent_vehicles_own_map_is_among_the_candidates_for_their_dbc():
    """The independent source wrote a signal map for its OEM DBC: every signal it maps is
    offered for its role when that DBC comes without a map."""
    folder = Path(__file__).resolve().parents[2] / "shared" / "independent" / "vehicle_1"
    if not folder.is_dir():
        pytest.skip(f"independent recordings not present in {folder}")
    with pytest.raises(DbcError) as error:
        load_interface(dbc=folder / "oem_vehicle.dbc")
    said = str(error.value)
    mapped = tomllib.loads((folder / "signals.toml").read_text())
    roles = ("speed", "mean_torque", "test_torque", "torque_request")
    for role in roles:
        assert f"{mapped[role]['message']}.{mapped[role]['signal']}" in said, role
