"""Tests of CAN recording files: round trip per format, timestamps, overwrite and damaged files."""

import gc
import logging
import sys

import can
import numpy as np
import pytest

from dtid.acquisition.logfile import SUPPORTED_SUFFIXES, read_log, read_log_checked, write_log
from dtid.acquisition.metadata import read_metadata, sidecar_path
from dtid.errors import RecordingError

FORMATS = [".blf", ".asc", ".log", ".mf4", ".trc", ".csv"]
TEXT_FORMATS = [".asc", ".log", ".trc", ".csv"]
# Timestamp error relative to the first frame measured with python-can 4.6, s.
TIME_RESOLUTION = {
    ".blf": 1e-8,
    ".asc": 1e-6,
    ".log": 1e-6,
    ".mf4": 1e-9,
    ".trc": 1e-6,
    ".csv": 1e-9,
}


def make_frames(count=20000, start=0.0, seed=0):
    """Frames over 200 s with standard and extended IDs and every classical DLC."""
    rng = np.random.default_rng(seed)
    times = start + np.sort(rng.uniform(0.0, 200.0, count))
    times[0] = start
    frames = []
    for index, timestamp in enumerate(times):
        extended = index % 5 == 0
        frames.append(
            can.Message(
                timestamp=float(timestamp),
                arbitration_id=int(rng.integers(0, 0x1FFFFFFF if extended else 0x7FF)),
                is_extended_id=extended,
                data=bytes(rng.integers(0, 256, index % 9, dtype=np.uint8)),
            )
        )
    return frames


def same_frames(read, written):
    return [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in read] == [
        (m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in written
    ]


@pytest.fixture(scope="module")
def frames():
    return make_frames()


@pytest.fixture(scope="module")
def written(tmp_path_factory, frames):
    """One complete recording per format, shared by the tests that damage copies of it."""
    folder = tmp_path_factory.mktemp("recordings")
    paths = {suffix: folder / f"complete{suffix}" for suffix in FORMATS}
    for path in paths.values():
        write_log(path, frames)
    return paths


def damaged_copy(tmp_path, source, data):
    path = tmp_path / f"damaged{source.suffix}"
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("suffix", FORMATS)
@pytest.mark.parametrize("start", [0.0, 1_700_000_000.0])
def test_round_trip(tmp_path, suffix, start):
    frames = make_frames(start=start, seed=1)
    path = tmp_path / f"recording{suffix}"
    assert write_log(path, frames) == len(frames)
    read = read_log(path)
    assert same_frames(read, frames)
    assert [m.dlc for m in read] == [m.dlc for m in frames]
    times = np.array([m.timestamp for m in read])
    expected = np.array([m.timestamp for m in frames])
    error = np.abs((times - times[0]) - (expected - expected[0]))
    assert error.max() <= TIME_RESOLUTION[suffix]
    if start == 0.0:  # a simulated recording comes back starting at t = 0
        assert abs(times[0]) <= TIME_RESOLUTION[suffix]


def test_frames_are_written_in_time_order(tmp_path):
    frames = make_frames(count=100)
    path = tmp_path / "shuffled.log"
    write_log(path, frames[::-1])
    assert same_frames(read_log(path), frames)


@pytest.mark.parametrize("suffix", FORMATS)
def test_existing_file_is_never_overwritten(tmp_path, suffix):
    path = tmp_path / f"recording{suffix}"
    first, second = make_frames(count=50, seed=2), make_frames(count=60, seed=3)
    write_log(path, first)
    content = path.read_bytes()
    with pytest.raises(RecordingError, match=r"recording .* already exists; .*--force"):
        write_log(path, second)
    assert path.read_bytes() == content
    write_log(path, second, overwrite=True)
    assert same_frames(read_log(path), second)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


def test_failed_write_leaves_nothing_behind(tmp_path, monkeypatch):
    with pytest.raises(RecordingError, match=r"cannot write recording .*missing"):
        write_log(tmp_path / "missing" / "recording.blf", make_frames(count=5))
    path = tmp_path / "recording.blf"
    write_log(path, make_frames(count=5))
    content = path.read_bytes()

    def disk_full(writer, message):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(can.BLFWriter, "on_message_received", disk_full)
    with pytest.raises(RecordingError, match=r"cannot write recording .*No space left on device"):
        write_log(tmp_path / "new.blf", make_frames(count=5))
    with pytest.raises(RecordingError, match="No space left on device"):
        write_log(path, make_frames(count=5, seed=5), overwrite=True)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
    assert path.read_bytes() == content


def test_write_errors(tmp_path):
    with pytest.raises(RecordingError, match="no CAN frames to write"):
        write_log(tmp_path / "empty.blf", [])
    with pytest.raises(
        RecordingError,
        match=r"unsupported format '.txt'; supported suffixes are .asc, .blf, .csv, .log, .mf4, "
        r"\.trc",
    ):
        write_log(tmp_path / "recording.txt", make_frames(count=5))
    assert SUPPORTED_SUFFIXES == (".asc", ".blf", ".csv", ".log", ".mf4", ".trc")


def test_read_errors(tmp_path):
    with pytest.raises(RecordingError, match=r"recording .*missing.blf does not exist"):
        read_log(tmp_path / "missing.blf")
    (tmp_path / "recording.mdf").touch()
    with pytest.raises(RecordingError, match=r"supported suffixes are \.asc, \.blf, \.csv"):
        read_log(tmp_path / "recording.mdf")
    for name in ("folder.log", "session"):  # a folder without a suffix too, not "format ''"
        (tmp_path / name).mkdir()
        with pytest.raises(RecordingError, match="is a directory: give the recordings in it"):
            read_log(tmp_path / name)


@pytest.mark.parametrize(
    ("name", "content"),
    [
        ("empty.log", b""),
        ("blank.log", b"\n\n"),
        ("header.asc", b"date Mon Jan 1 00:00:00.000 2024\nbase hex  timestamps absolute\n"),
    ],
)
def test_file_without_frames(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=r"holds no (readable )?CAN frames"):
        read_log(path)


# --- damaged files ------------------------------------------------------------------------------


def test_blf_cut_in_the_middle_reads_frames_before_the_cut(tmp_path, written, frames, caplog):
    data = written[".blf"].read_bytes()
    for cut in (len(data) // 2, len(data) - 1):
        with caplog.at_level(logging.WARNING):
            read = read_log(damaged_copy(tmp_path, written[".blf"], data[:cut]))
        assert 0 < len(read) <= len(frames) and same_frames(read, frames[: len(read)])
        assert f"is cut short ({cut} of {len(data)} bytes)" in caplog.text
    assert len(read) == len(frames)  # only padding was cut


@pytest.mark.parametrize(
    ("cut", "match"), [(40, "broken header"), (200, r"no readable CAN frames \(is cut short")]
)
def test_blf_cut_before_the_first_frame(tmp_path, written, cut, match):
    data = written[".blf"].read_bytes()
    with pytest.raises(RecordingError, match=match):
        read_log(damaged_copy(tmp_path, written[".blf"], data[:cut]))


def test_blf_never_closed_is_read_with_warning(tmp_path, frames, caplog):
    path = tmp_path / "crashed.blf"
    writer = can.BLFWriter(path)
    for frame in frames:
        writer.on_message_received(frame)
    writer.file.flush()  # the process dies here: containers on disk, header never completed
    data = path.read_bytes()
    writer.stop()
    with caplog.at_level(logging.WARNING):
        read = read_log(damaged_copy(tmp_path, path, data))
    assert 0 < len(read) < len(frames) and same_frames(read, frames[: len(read)])
    assert "was not closed by its writer" in caplog.text


def is_subsequence(read, frames):
    """True when ``read`` is ``frames`` with some left out, in order (compared by content)."""
    key = [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in frames]
    position = 0
    for m in read:
        wanted = (m.arbitration_id, m.is_extended_id, bytes(m.data))
        while position < len(key) and key[position] != wanted:
            position += 1
        if position == len(key):
            return False
        position += 1
    return True


def test_blf_damaged_in_the_middle_loses_that_container_only(tmp_path, written, frames, caplog):
    data = bytearray(written[".blf"].read_bytes())
    data[len(data) // 2 : len(data) // 2 + 64] = bytes(range(64))
    with caplog.at_level(logging.WARNING):
        read, integrity = read_log_checked(damaged_copy(tmp_path, written[".blf"], bytes(data)))
    (damage,) = integrity.damaged
    lost = len(frames) - len(read)
    assert 0 < lost < 0.2 * len(frames)  # one container of several
    assert abs(damage.frames_lost - lost) < 0.1 * lost + 5  # the estimate
    assert is_subsequence(read, frames)
    assert damage.after_s < damage.before_s
    assert "is damaged: 1 part(s) skipped" in caplog.text and damage.where in caplog.text
    assert integrity.cut is None


@pytest.mark.parametrize("suffix", FORMATS)
def test_garbage_file_is_an_error(tmp_path, suffix):
    path = tmp_path / f"garbage{suffix}"
    path.write_bytes(np.random.default_rng(4).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(RecordingError, match=f"garbage{suffix}") as info:
        read_log(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("suffix", TEXT_FORMATS)
def test_text_log_cut_in_a_line_drops_that_line(tmp_path, written, frames, suffix, caplog):
    data = written[suffix].read_bytes()
    # line end of the last frame
    end = data.rfind(b"\nEnd TriggerBlock") if suffix == ".asc" else len(data) - 1
    for cut in (len(data) // 2, end - 6):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            read = read_log(damaged_copy(tmp_path, written[suffix], data[:cut]))
        assert "ends in an incomplete line" in caplog.text
        assert 0 < len(read) < len(frames) and same_frames(read, frames[: len(read)])
    assert len(read) == len(frames) - 1


def test_asc_without_end_of_triggerblock_warns(tmp_path, written, frames, caplog):
    data = written[".asc"].read_bytes()
    cut = data.rfind(b"End TriggerBlock")
    with caplog.at_level(logging.WARNING):
        read = read_log(damaged_copy(tmp_path, written[".asc"], data[:cut]))
    assert len(read) == len(frames) and "lacks its closing 'End TriggerBlock'" in caplog.text


@pytest.mark.parametrize("suffix", TEXT_FORMATS)
def test_text_log_with_binary_bytes_loses_that_line_only(tmp_path, written, frames, suffix, caplog):
    data = written[suffix].read_bytes()
    middle = data.find(b"\n", len(data) // 2) + 1
    line = data[:middle].count(b"\n") + 1
    damaged = data[:middle] + b"\x00\x17\x80garbage\n" + data[middle:]
    with caplog.at_level(logging.WARNING):
        read, integrity = read_log_checked(damaged_copy(tmp_path, written[suffix], damaged))
    assert same_frames(read, frames)
    assert [d.where for d in integrity.damaged] == [f"line {line}"]
    assert f"line {line}: about 1 frame(s) lost" in caplog.text


@pytest.mark.parametrize(
    ("suffix", "malformed"),
    [
        (".log", b"(12.5) can0 this is not a frame\n"),
        (".trc", b"   999   12.000 DT  1  zzzz Rx -  8  00 00\n"),
        (".csv", b"12.5,0xZZZ,0,0,0,8,not base64\n"),
        (".log", b"(nan) can0 1A0#781F000000000000\n"),  # python-can reads it, time and all
    ],
)
def test_malformed_line_loses_that_line_only(tmp_path, written, frames, suffix, malformed, caplog):
    data = written[suffix].read_bytes()
    middle = data.find(b"\n", len(data) // 2) + 1
    line = data[:middle].count(b"\n") + 1
    damaged = data[:middle] + malformed + data[middle:]
    with caplog.at_level(logging.WARNING):
        read, integrity = read_log_checked(damaged_copy(tmp_path, written[suffix], damaged))
    assert same_frames(read, frames)
    assert [d.where for d in integrity.damaged] == [f"line {line}"]


def test_asc_garbage_lines_are_counted_not_dropped_silently(tmp_path, written, frames, caplog):
    """20 lines spoiled: garbage text, a payload that is not hex, a line cut short; 20 frames
    fewer, each line named."""
    lines = written[".asc"].read_bytes().split(b"\n")
    frame_lines = [i for i, line in enumerate(lines) if line.strip()[:1].isdigit()]
    spoiled = frame_lines[101::901][:20]  # every DLC among them
    for n, i in enumerate(spoiled):
        if n % 3 == 0:
            lines[i] = b"#~ garbage @@ not a line of this log"
        elif n % 3 == 1:
            lines[i] = lines[i].replace(b" d ", b" d zz ", 1)
        else:
            head, payload = lines[i].split(b" d ", 1)
            fields = payload.split()
            # a line cut short: its last data byte missing (a DLC 0 line: the DLC itself)
            lines[i] = head + b" d " + b" ".join(fields[:-1] if len(fields) > 1 else [b"9"])
    with caplog.at_level(logging.WARNING):
        read, integrity = read_log_checked(
            damaged_copy(tmp_path, written[".asc"], b"\n".join(lines))
        )
    assert len(read) == len(frames) - 20
    assert [d.where for d in integrity.damaged] == [f"line {i + 1}" for i in spoiled]
    assert is_subsequence(read, frames)


def test_real_candump_log(tmp_path, realdata):
    frames = read_log(realdata / "genesis_autolog.log")
    assert len(frames) == 55314 and not any(frame.is_extended_id for frame in frames)
    assert frames[0].timestamp == pytest.approx(1600279140.020108)
    path = tmp_path / "genesis.blf"
    write_log(path, frames)
    assert same_frames(read_log(path), frames)


# --- MF4 ----------------------------------------------------------------------------------------


def test_mf4_written_by_python_can_itself_is_read(tmp_path, frames):
    """An .mf4 file from python-can's own writer (one frame at a time, its own start time), as
    another tool built on it would leave: the same frames."""
    path = tmp_path / "other-tool.mf4"
    with can.Logger(path) as writer:
        for frame in frames[:3000]:
            writer.on_message_received(frame)
    read = read_log(path)
    assert same_frames(read, frames[:3000])
    times = np.array([m.timestamp for m in read]) - np.array([m.timestamp for m in frames[:3000]])
    assert np.abs(times).max() < 1e-6  # its times relative to the wall clock: 0.2 us kept


@pytest.mark.parametrize("damage", ["cut", "zeroed"])
def test_damaged_mf4_is_refused_in_one_line(tmp_path, written, damage, capfd):
    data = bytearray(written[".mf4"].read_bytes())
    if damage == "cut":
        data = data[: len(data) // 2]
    else:
        data[len(data) // 2 : len(data) // 2 + 64] = bytes(64)
    path = damaged_copy(tmp_path, written[".mf4"], bytes(data))
    with pytest.raises(RecordingError, match=r"damaged.mf4 is not a readable MF4 file") as info:
        read_log(path)
    message = str(info.value)
    assert "\n" not in message and "journal" in message
    complaints: list[object] = []
    hook, sys.unraisablehook = sys.unraisablehook, complaints.append
    try:  # the error held asammdf's half-built objects: freed, they complained after it
        del info
        gc.collect()
    finally:
        sys.unraisablehook = hook
    assert not complaints
    assert "Traceback" not in capfd.readouterr().err  # asammdf's own complaints are kept quiet


# --- metadata -----------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", FORMATS)
def test_metadata_written_with_a_log_reads_back(tmp_path, suffix):
    """In the .mf4 header, in a sidecar for the others; a recording overwritten without
    metadata loses the sidecar that described the old one."""
    path = tmp_path / f"recording{suffix}"
    metadata = {"schema": "dtid-recording-metadata/1", "session": 's <&> "1"', "plan": [1, 2]}
    write_log(path, make_frames(count=50), metadata=metadata)
    integrity = {"frames": 50, "lost": 0, "closed": True, "failure": None}
    assert read_metadata(path) == {**metadata, "integrity": integrity}
    assert sidecar_path(path).exists() == (suffix != ".mf4")
    write_log(path, make_frames(count=50, seed=7), overwrite=True)
    assert read_metadata(path) is None
    assert not sidecar_path(path).exists()


def test_unreadable_sidecar_is_named(tmp_path):
    path = tmp_path / "recording.blf"
    write_log(path, make_frames(count=5))
    sidecar_path(path).write_text("{not json")
    with pytest.raises(RecordingError, match=r"recording.blf.json of recording .* not readable"):
        read_metadata(path)
