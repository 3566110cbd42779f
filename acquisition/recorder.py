"""The raw CAN log of a test session, written with python-can's writers and safe against a crash.

Every frame the daemon receives and every frame it sends (``is_rx`` False) is written here before
anything else reads it; the log alone is enough to redo every result offline. Formats by suffix:
``.blf`` (default), ``.asc``, ``.log`` (candump -L) and ``.mf4``, as :mod:`dtid.acquisition.logfile`
reads them. The session's metadata (:mod:`dtid.acquisition.metadata`) goes into a sidecar
``<log>.json`` when the session starts and again, with the log's integrity, when it ends; for
.mf4 into the file's header.

MF4 cannot be written crash-safe: python-can's writer (asammdf) keeps the frames in a temporary
file and writes the MF4 file only when stopped, so a killed daemon would leave nothing. An .mf4
session is therefore recorded in a crash-safe BLF journal (``<name>.journal.blf``) and converted
when it ends; the journal is removed only once the MF4 file holds every one of its frames. A
session that dies leaves the journal, readable by every command.

Crash safety: python-can's writers keep frames in memory (the BLF writer up to a 128 KiB
container; the text writers in Python's file buffer) and complete the file only when stopped. The
recorder therefore checkpoints at least every ``flush_period_s``: it writes what is buffered and
hands it to the kernel (which is what survives a ``kill -9``), and a helper thread ``fsync``-s it
to the disk (what survives a power loss, a little later), so the receive loop never waits for the
disk. Either loses at most the frames of the last period.

For BLF this alone is not enough: python-can writes the file header (start time, file size) only
when it closes the file, so a file never closed has no start time and its frames read back
shifted by an unknown offset. The BLF writer here sets the start time when it opens the file (the
daemon's start, truncated to the millisecond as BLF stores it) and rewrites the header at each
checkpoint with the start time and the file size of a file still being written (the header size,
python-can's own mark of an open file). :func:`dtid.acquisition.logfile.read_log` reads such a file
up to the last complete frame, with a warning, however the writing was cut (also in the middle of a
container); the frames before the cut keep their absolute timestamps. On a clean close the header
gets the true size, as python-can writes it.

A log never replaces an existing file: each test gets its own session directory named from the
UTC time, and the log is created exclusively.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import threading
import time
from pathlib import Path
from typing import IO, Any, BinaryIO

import can
from can.io.blf import FILE_HEADER_SIZE
from can.io.generic import FileIOMessageWriter

from dtid.acquisition.metadata import journal_path, sidecar_path, with_integrity, write_sidecar
from dtid.acquisition.mf4 import BulkMF4Writer, frame_count
from dtid.errors import RecordingError

logger = logging.getLogger(__name__)

SUFFIXES = (".blf", ".asc", ".log", ".mf4")
"""Log formats the recorder writes, by suffix."""
COMPRESSION_LEVEL = 1
"""zlib level of the BLF containers: fastest. Measured on ECU frames: 1.8 instead of 2.7 us per
frame written (python-can's default, level 6), for a file 3 % larger (7.1 bytes per frame)."""
_CHANNEL_TOKEN = re.compile(r"^[\w.:-]+$")


def new_session_directory(parent: Path, now_s: float | None = None) -> Path:
    """Create the directory of a new test session under ``parent``.

    Parameters
    ----------
    parent
        ``[output] directory``; created if missing.
    now_s
        Time the name is taken from, s since the Unix epoch (UTC); now if omitted.

    Returns
    -------
    Path
        ``parent/YYYYmmddTHHMMSSZ``, with ``-2``, ``-3``, ... appended when that exists already.

    Raises
    ------
    RecordingError
        If the directory cannot be created.
    """
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(now_s))
    if parent.exists() and not parent.is_dir():
        raise RecordingError(f"{parent} is a file, not a folder: give a folder for the sessions")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        number = 1
        while True:
            candidate = parent / (stamp if number == 1 else f"{stamp}-{number}")
            try:
                candidate.mkdir()
            except FileExistsError:
                number += 1
                continue
            return candidate
    except OSError as error:
        raise RecordingError(
            f"cannot create a session directory in {parent}: {error.strerror or error}"
        ) from error


class CrashSafeBLFWriter(can.BLFWriter):
    """python-can's BLF writer with a start time from the first byte and header checkpoints.

    Parameters
    ----------
    file
        Binary file opened for writing (seekable).
    start_s
        Start time of the log, s since the Unix epoch; no frame may be older.
    """

    def __init__(self, file: BinaryIO, start_s: float) -> None:
        super().__init__(file, compression_level=COMPRESSION_LEVEL)
        self.start_timestamp = int(start_s * 1000) / 1000  # BLF keeps milliseconds
        self._rewrite_header(FILE_HEADER_SIZE)

    def _rewrite_header(self, declared_size: int) -> None:
        position = self.file.tell()
        self.file.seek(0)
        self._write_header(declared_size)
        self.file.seek(position)

    def checkpoint(self) -> None:
        """Write the buffered frames as a container and update the header (file still open)."""
        self._flush()
        self._rewrite_header(FILE_HEADER_SIZE)


class Recorder:
    """Write a session's frames to its raw log.

    Parameters
    ----------
    path
        The log; its suffix selects the format. Must not exist.
    start_s
        Start time of the session, s (bus time); no recorded frame is older. BLF stores it as the
        file's start time, ASC writes its times relative to it.
    flush_period_s
        Longest wall time a written frame may stay in memory, s.
    channel
        Channel name written into candump logs (the bus channel when it is a plain name).
    metadata
        The session's metadata (:func:`dtid.acquisition.metadata.session_metadata`); None for
        none.

    Attributes
    ----------
    path : Path
        The log (for .mf4: the file written when the session ends).
    journal : Path or None
        For .mf4: the BLF written during the session; None otherwise.
    outcome : dict or None
        How the test ended (status, reason, health), set by the daemon before :meth:`close`
        and written into the metadata.
    frames : int
        Frames written (after a failure: those flushed before it, which the log keeps).
    first_timestamp : float or None
        Timestamp of the first frame written, s; None before it.

    Raises
    ------
    RecordingError
        If the suffix is not supported, the file exists or cannot be created.
    """

    def __init__(
        self,
        path: Path,
        start_s: float,
        flush_period_s: float,
        channel: str = "can0",
        metadata: dict[str, Any] | None = None,
    ) -> None:
        suffix = path.suffix.lower()
        if suffix not in SUFFIXES:
            raise RecordingError(
                f"log {path}: unsupported format '{path.suffix}'; use one of {', '.join(SUFFIXES)}"
            )
        if suffix == ".mf4" and path.exists():
            raise RecordingError(f"log {path} exists already; it is never overwritten")
        self.journal = journal_path(path) if suffix == ".mf4" else None
        written = self.journal or path
        # readable too: a log removed while it is written is copied back from it (_rescue)
        mode, encoding = ("x+b", None) if written.suffix == ".blf" else ("x+", "ascii")
        try:
            file = written.open(mode, encoding=encoding)
        except FileExistsError as error:
            raise RecordingError(
                f"log {written} exists already; it is never overwritten"
            ) from error
        except OSError as error:
            raise RecordingError(
                f"cannot create log {written}: {error.strerror or error}"
            ) from error
        self.path = path
        self.frames = 0
        self._flushed_frames = 0
        self.first_timestamp: float | None = None
        self.failure: str | None = None
        self.lost = 0
        self._metadata = metadata
        self.outcome: dict[str, Any] | None = None
        if metadata is not None:
            write_sidecar(written, with_integrity(metadata, 0, 0, False, None))
        if written.suffix == ".blf":
            self._writer: FileIOMessageWriter = CrashSafeBLFWriter(file, start_s)
        elif suffix == ".asc":
            self._writer = can.ASCWriter(file)
            self._writer.log_event("Start of measurement", start_s)  # times relative to start
        else:
            name = channel if _CHANNEL_TOKEN.match(channel) else "can0"
            self._writer = can.CanutilsLogWriter(file, channel=name)
        self._write = self._writer.on_message_received
        self._sync = _BackgroundSync(file.fileno())
        self._flush_period_s = flush_period_s
        self._next_flush = time.monotonic() + flush_period_s
        self.flush()

    def write(self, frame: can.Message) -> None:
        """Write one frame (its ``channel`` is cleared: the log holds one bus).

        Never raises: once the file cannot be written (a full disk, a removed directory) the
        recorder keeps what it wrote, sets :attr:`failure` and counts the frames it could not
        write in :attr:`lost`; the daemon stops the test when it sees the failure.
        """
        if self.failure is not None:
            self.lost += 1
            return
        frame.channel = None
        try:
            self._write(frame)
        except OSError as error:
            self._fail(error)
            self.lost += 1
            return
        if self.first_timestamp is None:
            self.first_timestamp = frame.timestamp
        self.frames += 1

    def _fail(self, error: OSError) -> None:
        if self.failure is None:
            # the frames since the last flush were in the writer's buffers: counted as lost,
            # not as kept (on a full disk the daemon had said 4092 kept, the file held 3677)
            self.lost += self.frames - self._flushed_frames
            self.frames = self._flushed_frames
            self.failure = f"cannot write the log {self.path}: {error.strerror or error}"
            logger.error("%s; the %d frames flushed before are kept", self.failure, self.frames)

    def flush_if_due(self) -> bool:
        """Flush when ``flush_period_s`` has passed since the last flush; True if it did."""
        if time.monotonic() < self._next_flush:
            return False
        self.flush()
        return True

    def flush(self) -> None:
        """Hand every written frame to the kernel, and have the disk sync started."""
        self._next_flush = time.monotonic() + self._flush_period_s
        if self.failure is not None:
            return
        writer = self._writer
        try:
            if isinstance(writer, CrashSafeBLFWriter):
                writer.checkpoint()
            writer.file.flush()
        except OSError as error:
            self._fail(error)
            return
        if _removed(writer.file):
            self._rescue()
            return
        self._flushed_frames = self.frames
        self._sync.request()

    def _rescue(self) -> None:
        """The log was removed while it was written (its folder deleted): the frames so far,
        still in the open file, are written back to its path, and the recorder fails, so that
        the daemon stops the test (``log_write``). Writing on would record into a file nobody
        can open: a test that then said "completed" had left nothing on disk."""
        written = self.journal or self.path
        file = self._writer.file
        try:
            written.parent.mkdir(parents=True, exist_ok=True)
            with written.open("xb") as copy:
                _copy_open_file(file.fileno(), copy.fileno())
                os.fsync(copy.fileno())
        except OSError as error:
            kept = f"the {self.frames} frames written could not be saved: {error.strerror or error}"
        else:
            kept = f"the {self.frames} frames written before were saved to it again"
        self.failure = f"the log {written} was removed while the test recorded it; {kept}"
        logger.error("%s", self.failure)

    def close(self) -> None:
        """Complete the file (BLF header with the true size, ASC end line), close and sync it;
        write the metadata with the log's integrity; convert an .mf4 session's journal."""
        if self._writer.file.closed:
            return
        self._sync.close()
        written = self.journal or self.path
        try:
            self._writer.stop()
            with written.open("rb") as file:
                os.fsync(file.fileno())
        except OSError as error:
            self._fail(error)
            with contextlib.suppress(OSError):
                self._writer.file.close()
        metadata = self._metadata
        if metadata is not None:
            metadata = with_integrity(
                metadata, self.frames, self.lost, self.failure is None, self.failure
            )
            metadata["outcome"] = self.outcome
        if self.journal is not None and self.frames:
            self._convert_journal(metadata)
        elif metadata is not None:
            try:
                write_sidecar(written, metadata)
            except RecordingError as error:
                logger.error("%s", error)

    def _convert_journal(self, metadata: dict[str, Any] | None) -> None:
        """Write the .mf4 file from the journal; remove the journal once the file holds all."""
        journal = self.journal
        assert journal is not None
        try:
            with can.BLFReader(journal) as reader:
                frames = iter(reader)
                first = next(frames)
                writer = BulkMF4Writer(self.path, first.timestamp, metadata)
                with writer:
                    writer.on_message_received(first)
                    for frame in frames:
                        writer.on_message_received(frame)
            with self.path.open("rb") as file:
                os.fsync(file.fileno())
            held = frame_count(self.path)
        except (OSError, RecordingError, ValueError) as error:
            reason = getattr(error, "strerror", None) or error
            self.failure = self.failure or (
                f"cannot write the MF4 file {self.path} ({reason}); the recording is kept in "
                f"its journal {journal}"
            )
            logger.error("%s", self.failure)
            return
        if held != self.frames:
            self.failure = self.failure or (
                f"the MF4 file {self.path} holds {held} of the {self.frames} frames recorded; "
                f"the recording is kept in its journal {journal}"
            )
            logger.error("%s", self.failure)
            return
        journal.unlink()
        sidecar_path(journal).unlink(missing_ok=True)
        logger.info("wrote %s (%d frames) from its journal", self.path, held)


def _removed(file: IO[Any]) -> bool:
    """Whether an open file no longer has a name in any folder (it, or its folder, was
    removed)."""
    return os.fstat(file.fileno()).st_nlink == 0


def _copy_open_file(source: int, target: int) -> None:
    """Copy the whole content of the open file ``source`` to ``target`` (file descriptors)."""
    offset, size = 0, os.fstat(source).st_size
    while offset < size:
        chunk = os.pread(source, min(1 << 20, size - offset), offset)
        if not chunk:
            break
        os.write(target, chunk)
        offset += len(chunk)


class _BackgroundSync:
    """``fsync`` a file in a thread of its own whenever asked (at most one sync at a time).

    A sync takes 0.3 to 8 ms on this machine's disk; in the receive loop it would hold up the
    frames behind it.
    """

    def __init__(self, fileno: int) -> None:
        self._fileno = fileno
        self._wanted = threading.Event()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="dtid-fsync", daemon=True)
        self._thread.start()

    def request(self) -> None:
        """Sync soon (what was handed to the kernel by now)."""
        self._wanted.set()

    def close(self) -> None:
        """Stop the thread (before the file is closed)."""
        self._closing = True
        self._wanted.set()
        self._thread.join()

    def _run(self) -> None:
        while True:
            self._wanted.wait()
            self._wanted.clear()
            if self._closing:
                return
            try:
                os.fsync(self._fileno)
            except OSError as error:
                logger.error("cannot sync the log to disk: %s", error)
