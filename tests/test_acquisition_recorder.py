"""The raw log of a session: formats, never overwriting, and what a ``kill -9`` leaves."""

from __future__ import annotations

import hashlib
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from dtid.acquisition.logfile import read_log
from dtid.acquisition.metadata import read_metadata, session_metadata, sidecar_path
from dtid.acquisition.recorder import Recorder, new_session_directory
from dtid.dbc.loader import load_interface
from dtid.dbc.resources import DEFAULT_DBC
from dtid.errors import RecordingError

ROOT = Path(__file__).resolve().parents[1]
FORMATS = ("blf", "asc", "log", "mf4")


def frames(start: float, n: int) -> list[can.Message]:
    """``n`` frames 1 ms apart from ``start``: received ones and every fifth one sent."""
    return [
        can.Message(
            timestamp=start + 0.001 * (i + 1),
            arbitration_id=0x6A0 if i % 5 == 0 else 0x1A0 + i % 3,
            is_extended_id=False,
            is_rx=i % 5 != 0,
            data=bytes([i % 256, i // 256 % 256, 1, 2, 3, 4, 5, 6]),
            channel="vcan0",
        )
        for i in range(n)
    ]


def key(frame: can.Message) -> tuple[int, bool, bytes, bool]:
    return frame.arbitration_id, frame.is_extended_id, bytes(frame.data), frame.is_rx


@pytest.mark.parametrize("fmt", FORMATS)
def test_log_reads_back_every_frame(tmp_path: Path, fmt: str) -> None:
    start = time.time()
    written = frames(start, 300)
    recorder = Recorder(tmp_path / f"test.{fmt}", start, 0.5, "vcan0")
    for frame in written:
        recorder.write(frame)
    recorder.close()
    assert recorder.frames == 300 and recorder.first_timestamp == written[0].timestamp
    assert recorder.failure is None
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"test.{fmt}"]  # an mf4 journal: gone
    back = read_log(recorder.path)
    assert [key(f) for f in back] == [key(f) for f in written]
    origin = start if fmt == "asc" else 0.0  # ASC times are relative to the session start
    times = [f.timestamp + origin for f in back]
    assert times == pytest.approx([f.timestamp for f in written], abs=2e-6)


def test_existing_log_is_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "test.blf"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError, match="exists"):
        Recorder(path, time.time(), 0.5)
    assert path.read_bytes() == b"precious"


def test_unsupported_suffix_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="unsupported"):
        Recorder(tmp_path / "test.csv", time.time(), 0.5)
    assert not (tmp_path / "test.csv").exists()


@pytest.mark.parametrize("fmt", FORMATS)
def test_metadata_travels_with_the_log(tmp_path: Path, fmt: str) -> None:
    """The session's metadata is beside the log from the start (not closed), and at the end
    carries what the log kept; an .mf4 file holds it in its header, no sidecar left."""
    start = time.time()
    path = tmp_path / f"session.{fmt}"
    metadata = session_metadata(
        session="session", started_s=start, source="test", interface=load_interface()
    )
    recorder = Recorder(path, start, 0.5, "vcan0", metadata)
    written = recorder.journal or path
    during = read_metadata(written)
    assert during is not None and during["integrity"]["closed"] is False
    for frame in frames(start, 120):
        recorder.write(frame)
    recorder.close()
    after = read_metadata(path)
    assert after is not None
    assert after["integrity"] == {"frames": 120, "lost": 0, "closed": True, "failure": None}
    assert after["interface"]["roles"]["speed"] == "EngineSpeed.EngineSpeedFiltered"
    assert (
        after["interface"]["dbc"]["sha256"] == hashlib.sha256(DEFAULT_DBC.read_bytes()).hexdigest()
    )
    assert sidecar_path(path).exists() == (fmt != "mf4")
    assert not any(p.name.startswith("session.journal") for p in tmp_path.iterdir())


def test_each_session_gets_its_own_directory(tmp_path: Path) -> None:
    now = 1_800_000_000.0
    first = new_session_directory(tmp_path / "runs", now)
    second = new_session_directory(tmp_path / "runs", now)
    assert first.name == "20270115T080000Z"
    assert second.name == "20270115T080000Z-2"
    assert first.is_dir() and second.is_dir()
    (tmp_path / "afile").touch()  # said "File exists"
    with pytest.raises(RecordingError, match="afile is a file, not a folder"):
        new_session_directory(tmp_path / "afile", now)


KILLED_WRITER = """
import os, signal, sys
sys.path.insert(0, {root!r})
sys.path.insert(0, {tests!r})
from test_acquisition_recorder import frames
from dtid.acquisition.recorder import Recorder
start = {start!r}
recorder = Recorder(__import__("pathlib").Path({path!r}), start, 60.0, "vcan0")
written = frames(start, {flushed} + {unflushed})
for frame in written[:{flushed}]:
    recorder.write(frame)
recorder.flush()
for frame in written[{flushed}:]:
    recorder.write(frame)
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("unflushed", [50, 6000])
def test_log_survives_sigkill(tmp_path: Path, fmt: str, unflushed: int) -> None:
    """Frames up to the last flush survive a kill -9; 6000 more frames make the BLF writer
    write containers on its own after the flush (a file cut in the middle of its data)."""
    start = time.time()
    path = tmp_path / f"killed.{fmt}"
    flushed = 400
    script = KILLED_WRITER.format(
        root=str(ROOT),
        tests=str(ROOT / "tests"),
        start=start,
        path=str(path),
        flushed=flushed,
        unflushed=unflushed,
    )
    result = subprocess.run([sys.executable, "-c", script], check=False, capture_output=True)
    assert result.returncode == -signal.SIGKILL, result.stderr.decode()
    if fmt == "mf4":  # never converted: the session is in its journal
        assert not path.exists()
        path = path.with_name("killed.journal.blf")
    back = read_log(path)
    written = frames(start, flushed + unflushed)
    assert flushed <= len(back) <= len(written)
    assert [key(f) for f in back] == [key(f) for f in written[: len(back)]]
    if fmt != "asc":  # absolute times, also in a BLF file its writer never closed
        assert back[0].timestamp == pytest.approx(written[0].timestamp, abs=2e-6)


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_log_removed_while_recording_is_saved_again_and_fails(tmp_path: Path, fmt: str) -> None:
    """A session folder deleted during the test (a cleanup script, an operator's rm -rf): the
    writes went on into a file without a name, the daemon said "completed" and nothing was on
    disk. The next flush now sees it, writes the frames so far back to the log's path and
    fails the recorder, which stops the test (log_write)."""
    import shutil

    start = time.time()
    folder = tmp_path / "session"
    folder.mkdir()
    metadata = session_metadata(
        session="session", started_s=start, source="test", interface=load_interface()
    )
    recorder = Recorder(folder / f"session.{fmt}", start, 0.5, "vcan0", metadata)
    written = frames(start, 200)
    for frame in written[:150]:
        recorder.write(frame)
    shutil.rmtree(folder)
    recorder.flush()
    assert recorder.failure is not None and "was removed while the test recorded it" in (
        recorder.failure
    )
    assert "150 frames written before were saved to it again" in recorder.failure
    for frame in written[150:]:
        recorder.write(frame)
    recorder.close()
    assert recorder.lost == 50
    back = read_log(recorder.path)
    assert [key(f) for f in back] == [key(f) for f in written[:150]]
    after = read_metadata(recorder.path)
    assert after is not None
    assert after["integrity"]["frames"] == 150 and after["integrity"]["lost"] == 50
    assert "was removed" in after["integrity"]["failure"]
