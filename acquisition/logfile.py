"""Reading and writing CAN recordings with python-can, the format chosen by the file suffix.

Supported formats and what they preserve of the frame timestamps (measured with python-can 4.6):

``.blf`` (Vector binary logging format)
    Each frame stores nanoseconds since a start time kept in the header with millisecond
    resolution; Unix-epoch timestamps come back absolute, times relative to the first frame to
    1 ns. For timestamps that are not Unix times (simulated recordings starting near 0 s) the
    header holds no start time: the times come back shifted by the first frame's time truncated
    to whole milliseconds (0 s for a recording that starts at 0.0 s), so relative times are exact
    to 1 ns but a sub-millisecond absolute offset is lost.
``.asc`` (Vector ASCII)
    Times relative to the first frame with 1 us resolution; the first frame reads back at 0 s.
``.log`` (Linux candump -L)
    Absolute times with 1 us resolution.
``.mf4`` (ASAM MDF 4, as INCA, CANape and Vector loggers record; python-can through asammdf)
    Times relative to the file's start time as 64-bit floats: exact for a recording written
    here (:mod:`dtid.acquisition.mf4`), absolute. The session's metadata travels in the header.
``.trc`` (PEAK PCAN trace, versions 1.x and 2.x)
    Times relative to a start time in the header, in ms with 1 us resolution.
``.csv`` (python-can's CSV: timestamp, arbitration_id, extended, remote, error, dlc, data)
    Times as written, absolute.

The candump and CSV formats do not keep the direction of a frame (``is_rx``); the others do.

Decoding makes times relative to the first frame, so an absolute offset is harmless.
"""

import io
import logging
import math
import os
import re
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from operator import attrgetter
from pathlib import Path
from typing import Any

import can
from can.io.blf import (
    FILE_HEADER_SIZE,
    LOG_CONTAINER,
    LOG_CONTAINER_STRUCT,
    NO_COMPRESSION,
    OBJ_HEADER_BASE_STRUCT,
    ZLIB_DEFLATE,
    BLFParseError,
)

from dtid.acquisition.metadata import sidecar_path, with_integrity, write_sidecar
from dtid.acquisition.mf4 import BulkMF4Writer, read_mf4
from dtid.errors import RecordingError

logger = logging.getLogger(__name__)

_WRITERS = {
    ".asc": can.ASCWriter,
    ".blf": can.BLFWriter,
    ".csv": can.CSVWriter,
    ".log": can.CanutilsLogWriter,
    ".mf4": BulkMF4Writer,
    ".trc": can.TRCWriter,
}
_TEXT_READERS = {
    ".asc": can.ASCReader,
    ".csv": can.CSVReader,
    ".log": can.CanutilsLogReader,
    ".trc": can.TRCReader,
}
#: Suffixes of the recording formats read and written.
SUPPORTED_SUFFIXES: tuple[str, ...] = tuple(sorted(_WRITERS))

ONE_BASED_CHANNELS = (".asc", ".blf")
"""Formats whose channels python-can's readers number from 0 where the file counts from 1."""


def recorded_channel(channel: object, suffix: str) -> str | None:
    """A frame's bus channel (``can.Message.channel`` as read) as a recording of format
    ``suffix`` names it; None where the format keeps none (.csv).

    python-can's readers number an .asc or .blf file's channels from 0 (its writers add the 1
    back), where the file, and the Vector tools that show it, count from 1; a .trc or .mf4
    file's number and a candump log's interface name (``can1``) are kept as the file gives them.
    """
    if channel is None:
        return None
    if suffix.lower() in ONE_BASED_CHANNELS and isinstance(channel, int):
        return str(channel + 1)
    return str(channel)


# Last line of a complete ASC file, lower case.
_ASC_END = "end triggerblock"
# Characters that never occur in a text CAN log (control characters but tab, CR and LF).
_CONTROL_CHARACTER = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")
# Errors python-can's BLF reader raises on a cut or damaged file.
_BLF_ERRORS = (BLFParseError, struct.error, zlib.error, ValueError, EOFError)


def recordings_in(folder: str | os.PathLike[str]) -> list[Path]:
    """The recordings in a folder (a session directory): its files of a supported format, by
    name; hidden and partial files left out."""
    return sorted(
        p
        for p in Path(folder).iterdir()
        if p.is_file() and p.suffix.lower() in SUPPORTED_SUFFIXES and not p.name.startswith(".")
    )


def _reason(error: BaseException) -> str:
    return " ".join(str(error).split()) or type(error).__name__


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _WRITERS:
        raise RecordingError(
            f"recording {path}: unsupported format '{path.suffix}'; "
            f"supported suffixes are {', '.join(SUPPORTED_SUFFIXES)}"
        )
    return suffix


def write_log(
    path: str | os.PathLike[str],
    messages: Iterable[can.Message],
    *,
    overwrite: bool = False,
    metadata: dict[str, Any] | None = None,
) -> int:
    """Write CAN frames to a recording file.

    The frames are written in timestamp order (a stable sort; the formats cannot store time
    going backwards). They are first written to a temporary file beside ``path`` that replaces
    ``path`` only when complete, so a failed write neither leaves a half-written recording nor
    destroys an existing one.

    Parameters
    ----------
    path : str or os.PathLike
        The file; its suffix (one of :data:`SUPPORTED_SUFFIXES`) selects the format.
    messages : Iterable[can.Message]
        The frames, timestamps in s.
    overwrite : bool, optional
        Replace an existing file. Default False.
    metadata : dict, optional
        The session's metadata (:mod:`dtid.acquisition.metadata`), its ``integrity`` set to the
        frames written: in the header of an .mf4 file, in the sidecar ``<path>.json`` of the
        others. Without it, a sidecar left by an
        overwritten recording is removed (it described another recording).

    Returns
    -------
    int
        Number of frames written.

    Raises
    ------
    RecordingError
        If the suffix is not supported, there are no frames, the file exists and ``overwrite`` is
        False, or the file cannot be written.
    """
    path = Path(path)
    suffix = _suffix(path)
    frames = sorted(messages, key=attrgetter("timestamp"))
    if not frames:
        raise RecordingError(f"no CAN frames to write to {path}")
    if metadata is not None:
        metadata = with_integrity(metadata, len(frames), 0, True, None)
    reserved = False
    if not overwrite:
        try:
            path.open("x").close()  # reserve the name; the complete file replaces it below
        except FileExistsError as error:
            raise RecordingError(
                f"recording {path} already exists; choose another name or pass --force to "
                "overwrite it"
            ) from error
        except OSError as error:
            raise RecordingError(
                f"cannot write recording {path}: {error.strerror or error}"
            ) from error
        reserved = True
    temporary = path.with_name(f".{path.name}.{os.getpid()}.partial")
    complete = False
    try:
        if suffix == ".mf4":
            writer = BulkMF4Writer(temporary, frames[0].timestamp, metadata)
        else:
            writer = _WRITERS[suffix](temporary)
        with writer:
            for frame in frames:
                if type(frame.timestamp) is not float:  # python-can's CSV writes its repr
                    frame.timestamp = float(frame.timestamp)
                writer.on_message_received(frame)
        temporary.replace(path)
        complete = True
        if metadata is not None and suffix != ".mf4":
            write_sidecar(path, metadata)
        else:
            sidecar_path(path).unlink(missing_ok=True)
    except OSError as error:
        raise RecordingError(f"cannot write recording {path}: {error.strerror or error}") from error
    finally:
        if not complete:
            temporary.unlink(missing_ok=True)
            if reserved:
                path.unlink(missing_ok=True)
    logger.info("wrote %d frames to %s", len(frames), path)
    return len(frames)


@dataclass(frozen=True)
class Damage:
    """A damaged part of a recording, skipped.

    Attributes
    ----------
    where
        Where in the file: ``bytes A-B`` (a BLF container) or ``line N``.
    frames_lost
        Frames it held (estimated for a BLF container from its uncompressed size).
    after_s, before_s
        Timestamps of the intact frames just before and just after it, s (None at the file's
        start or end).
    """

    where: str
    frames_lost: int
    after_s: float | None = None
    before_s: float | None = None

    def describe(self) -> str:
        """One line for a warning or `dtid inspect`."""
        span = (
            f"between {self.after_s:.3f} s and {self.before_s:.3f} s"
            if self.after_s is not None and self.before_s is not None
            else "at the start"
            if self.before_s is not None
            else "at the end"
        )
        return f"{self.where}: about {self.frames_lost} frame(s) lost {span}"


@dataclass(frozen=True)
class Integrity:
    """What of a recording was read: intact, cut short, damaged parts skipped.

    Attributes
    ----------
    cut
        Why the file ends early (cut short, never closed, an incomplete last line), or None.
    damaged
        The damaged parts skipped, in file order.
    """

    cut: str | None = None
    damaged: tuple[Damage, ...] = ()

    @property
    def intact(self) -> bool:
        """True when nothing was cut or skipped."""
        return self.cut is None and not self.damaged

    def as_dict(self) -> dict[str, object]:
        """For `dtid inspect --json`."""
        return {
            "intact": self.intact,
            "cut": self.cut,
            "damaged": [
                {
                    "where": d.where,
                    "frames_lost": d.frames_lost,
                    "after_s": d.after_s,
                    "before_s": d.before_s,
                }
                for d in self.damaged
            ],
        }


def read_log(path: str | os.PathLike[str]) -> list[can.Message]:
    """Read the CAN frames of a recording file, with a warning for whatever was cut or damaged
    (:func:`read_log_checked`)."""
    return read_log_checked(path)[0]


def read_log_checked(path: str | os.PathLike[str]) -> tuple[list[can.Message], Integrity]:
    """Read the CAN frames of a recording file, and what of it could not be read.

    Nothing readable is lost. A file cut short (a recording interrupted while written) is read
    up to the cut: a BLF file shorter than its header says, or never closed; a text file whose
    last line has no line end (that line is dropped); an ASC file without its closing ``End
    TriggerBlock``. A text file cut exactly at a line end of a frame cannot be told from a
    complete one. A damaged BLF container (one byte wrong breaks its compression) is skipped and
    the containers after it are read; a damaged line of a text log is skipped and the lines
    after it are read. Each is logged as a warning naming where it was, the frames lost and the
    time span. An .mf4 file is read whole or refused: MDF 4 writers complete the file when the
    recording ends, and asammdf reads no part of a damaged one.

    Parameters
    ----------
    path : str or os.PathLike
        The file; its suffix (one of :data:`SUPPORTED_SUFFIXES`) selects the format.

    Returns
    -------
    frames : list[can.Message]
        The frames in file order, timestamps in s (see the module notes on what each format
        preserves).
    integrity : Integrity
        What was cut or skipped.

    Raises
    ------
    RecordingError
        If the file does not exist, has an unsupported suffix, cannot be read, or holds no
        readable frame.
    """
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"recording {path} does not exist")
    if path.is_dir():
        raise RecordingError(
            f"recording {path} is a directory: give the recordings in it "
            f"({', '.join(SUPPORTED_SUFFIXES)})"
        )
    suffix = _suffix(path)
    try:
        if suffix == ".blf":
            frames, integrity = _read_blf(path)
        elif suffix == ".mf4":
            frames, integrity = read_mf4(path)[0], Integrity()
        else:
            frames, integrity = _read_text(path, suffix)
    except RecordingError:
        raise
    except OSError as error:
        raise RecordingError(f"cannot read recording {path}: {error.strerror or error}") from error
    if not frames:
        problem = f" ({integrity.cut})" if integrity.cut else ""
        if integrity.damaged:
            problem += f" ({len(integrity.damaged)} damaged part(s), {integrity.damaged[0].where})"
        readable = " readable" if problem else ""
        raise RecordingError(f"recording {path} holds no{readable} CAN frames{problem}")
    if integrity.damaged:
        lost = sum(d.frames_lost for d in integrity.damaged)
        logger.warning(
            "recording %s is damaged: %d part(s) skipped, about %d frame(s) lost, the other %d "
            "frames read: %s",
            path,
            len(integrity.damaged),
            lost,
            len(frames),
            "; ".join(d.describe() for d in integrity.damaged[:5])
            + ("; ..." if len(integrity.damaged) > 5 else ""),
        )
    if integrity.cut:
        logger.warning(
            "recording %s %s; read the %d frames before the cut", path, integrity.cut, len(frames)
        )
    logger.info("read %d frames from %s", len(frames), path)
    return frames, integrity


def _timed(damage: list[tuple[str, int, int]], frames: list[can.Message]) -> tuple[Damage, ...]:
    """Damage records (where, frames lost, index of the next intact frame) with their times."""
    return tuple(
        Damage(
            where,
            lost,
            frames[index - 1].timestamp if index > 0 else None,
            frames[index].timestamp if index < len(frames) else None,
        )
        for where, lost, index in damage
    )


class _ResilientBLFReader(can.BLFReader):
    """python-can's BLF reader, walking the file container by container so that a damaged one
    is skipped instead of ending the read; python-can parses each intact container."""

    def __init__(self, file: io.BufferedIOBase) -> None:
        super().__init__(file)
        self.damage: list[tuple[str, int, int]] = []
        self.overrun = False
        self._frames = 0
        self._bytes = 0

    def __iter__(self) -> Iterator[can.Message]:
        offset = self.file.tell()
        data = self.file.read()
        header_size = OBJ_HEADER_BASE_STRUCT.size
        pos, resync = 0, False
        while pos + header_size <= len(data):
            signature, _, _, size, kind = OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)
            end = pos + size
            if signature != b"LOBJ" or size < header_size or end > len(data):
                following = data.find(b"LOBJ", pos + 1)
                if signature == b"LOBJ" and end > len(data) and following < 0:
                    self.overrun = True  # the last object runs past the end: cut short
                    break
                stop = following if following >= 0 else len(data)
                self._damaged(offset + pos, offset + stop, 0)
                resync = True
                if following < 0:
                    break
                pos = following
                continue
            following = end + size % 4
            if kind == LOG_CONTAINER:
                method, uncompressed = LOG_CONTAINER_STRUCT.unpack_from(data, pos + header_size)
                payload = data[pos + header_size + LOG_CONTAINER_STRUCT.size : end]
                try:
                    if method == NO_COMPRESSION:
                        inner = payload
                    elif method == ZLIB_DEFLATE:
                        inner = zlib.decompressobj().decompress(payload)
                    else:
                        raise BLFParseError(f"unknown compression method {method}")
                    if resync:
                        start = inner.find(b"LOBJ")
                        inner = inner[start:] if start >= 0 else b""
                        self._tail = b""
                    frames = list(self._parse_container(inner))
                except (*_BLF_ERRORS, IndexError) as error:
                    logger.debug("BLF container at byte %d: %s", offset + pos, _reason(error))
                    self._damaged(offset + pos, offset + following, uncompressed)
                    resync = True
                    pos = following
                    continue
                resync = False
                self._frames += len(frames)
                self._bytes += len(inner)
                yield from frames
            pos = following

    def _damaged(self, start: int, stop: int, uncompressed: int) -> None:
        per_frame = self._bytes / self._frames if self._frames else 48.0
        self._tail = b""
        self.damage.append((f"bytes {start}-{stop}", round(uncompressed / per_frame), self._frames))


def _read_blf(path: Path) -> tuple[list[can.Message], Integrity]:
    size = path.stat().st_size
    raw = path.read_bytes()
    try:
        reader = _ResilientBLFReader(io.BytesIO(raw))
    except _BLF_ERRORS as error:
        if len(raw) <= FILE_HEADER_SIZE:
            raise RecordingError(
                f"recording {path} is not a readable BLF file (broken header: {_reason(error)})"
            ) from error
        # a damaged header: read the objects after it, times relative to the first frame
        logger.warning(
            "recording %s: its BLF header is damaged (%s); reading the frames after it",
            path,
            _reason(error),
        )
        repaired = bytearray(raw)
        repaired[0:4] = b"LOGG"
        repaired[4:8] = FILE_HEADER_SIZE.to_bytes(4, "little")
        repaired[40:72] = bytes(32)  # start and stop time unknown
        try:
            reader = _ResilientBLFReader(io.BytesIO(bytes(repaired)))
        except _BLF_ERRORS:
            raise RecordingError(
                f"recording {path} is not a readable BLF file (broken header: {_reason(error)})"
            ) from error
    frames = list(reader)
    declared = reader.file_size
    cut = None
    if declared > size or reader.overrun:
        cut = f"is cut short ({size} of {declared} bytes)"
    elif declared <= FILE_HEADER_SIZE < size:
        cut = "was not closed by its writer (header never completed)"
    return frames, Integrity(cut, _timed(reader.damage, frames))


def _read_text(path: Path, suffix: str) -> tuple[list[can.Message], Integrity]:
    # latin-1 maps every byte to a character: Vector tools write ASC headers in the Windows
    # code page, and lines that are not frames fail to parse (.log) or are skipped (.asc).
    text = path.read_bytes().decode("latin-1")
    end = text.rfind("\n") + 1
    tail = text[end:]
    cut = None
    if tail.strip() and tail.strip().lower() != _ASC_END:
        cut = f"ends in an incomplete line (cut while written?), ignored: {tail[:60]!r}"
        text = text[:end]
    elif suffix == ".asc" and not text.rstrip().lower().endswith(_ASC_END):
        cut = "lacks its closing 'End TriggerBlock' line (cut short?)"
    lines = text.splitlines(keepends=True)
    damaged = [i for i, line in enumerate(lines) if _CONTROL_CHARACTER.search(line)]
    if len(damaged) > len(lines) // 2:
        raise RecordingError(
            f"recording {path} holds binary data in {len(damaged)} of {len(lines)} lines "
            f"(the first: line {damaged[0] + 1}); it is not a {suffix} text log"
        )
    for i in damaged:
        lines[i] = "\n"
    frames, failed = _parse_lines(lines, suffix)
    inconsistent = {i for i, frame in frames if not _consistent(frame)}
    inconsistent |= _stray_times(frames)
    frames = [(i, frame) for i, frame in frames if i not in inconsistent]
    bad = sorted(set(damaged) | set(failed) | inconsistent | set(_unknown_lines(lines, suffix)))
    records = []
    for i in bad:
        index = next((k for k, (line_no, _) in enumerate(frames) if line_no > i), len(frames))
        records.append((f"line {i + 1}", 1, index))
    messages = [frame for _, frame in frames]
    return messages, Integrity(cut, _timed(records, messages))


def _frame_lines(lines: list[str], suffix: str) -> list[int]:
    """Indices of the lines that should each hold one frame."""
    if suffix == ".log":
        return [i for i, line in enumerate(lines) if line.strip()]
    if suffix == ".trc":  # comments and the header start with ';'
        return [i for i, line in enumerate(lines) if line.strip() and line.lstrip()[0] != ";"]
    if suffix == ".csv":  # a header line of column names, then one frame a line
        return [i for i, line in enumerate(lines) if line.strip() and _is_number(line[:1])]
    found = []
    for i, line in enumerate(lines):
        fields = line.split()
        if len(fields) > 2 and _is_number(fields[0]) and fields[1].lower() != "start":
            found.append(i)
    return found


_ASC_HEADER = re.compile(
    r"\s*($|date |base |internal events|no internal events|//|begin triggerblock|end triggerblock)",
    re.IGNORECASE,
)
"""ASC lines that are not frames and not damage: the header, comments, the trigger block."""


def _unknown_lines(lines: list[str], suffix: str) -> list[int]:
    """Lines of an ASC log that are neither header nor comment nor timed (a frame or an event):
    python-can skips them silently; they are counted as damage."""
    if suffix != ".asc":
        return []
    return [
        i
        for i, line in enumerate(lines)
        if not _ASC_HEADER.match(line) and not _is_number(line.split(maxsplit=1)[0])
    ]


STRAY_S = 1.0
"""A text log's frame whose time lies this far (s) from both its neighbours in the file, while
they lie close to each other, is a damaged time stamp (a digit changed), not a late frame."""


def _stray_times(frames: list[tuple[int, can.Message]]) -> set[int]:
    """The lines whose time stamp stands alone, away from both neighbours (see STRAY_S)."""
    stray = set()
    for k in range(1, len(frames) - 1):
        before, now, after = (frames[k + d][1].timestamp for d in (-1, 0, 1))
        if abs(after - before) < STRAY_S and min(abs(now - before), abs(now - after)) > STRAY_S:
            stray.add(frames[k][0])
    return stray


def _consistent(frame: can.Message) -> bool:
    """A frame's time is a number (python-can reads a candump ``(nan)`` as one), and a classical
    data frame carries as many bytes as its DLC says (a cut line does not)."""
    if not math.isfinite(frame.timestamp):
        return False
    if frame.is_fd or frame.is_remote_frame or frame.is_error_frame:
        return True
    return len(frame.data) == min(frame.dlc, 8)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _parse_lines(lines: list[str], suffix: str) -> tuple[list[tuple[int, can.Message]], list[int]]:
    """The frames of a text log with the line each came from, and the frame lines python-can
    could not parse. python-can parses the whole text at once; where that fails or yields fewer
    frames than there are frame lines, the frame lines are split in halves until each failing
    line stands alone (each block behind the ASC header, whose settings it needs)."""
    candidates = _frame_lines(lines, suffix)
    reader = _TEXT_READERS[suffix]
    header = "" if suffix == ".log" else "".join(lines[: candidates[0]] if candidates else lines)

    def parse(block: list[int]) -> list[can.Message] | None:
        text = header + "".join(lines[i] for i in block)
        try:
            frames = list(reader(io.StringIO(text)))
        except (ValueError, IndexError):
            return None
        return frames if len(frames) == len(block) else None

    frames: list[tuple[int, can.Message]] = []
    failed: list[int] = []
    pending = [candidates]
    while pending:
        block = pending.pop()
        parsed = parse(block) if block else []
        if parsed is not None:
            frames.extend(zip(block, parsed, strict=True))
        elif len(block) == 1:
            failed.append(block[0])
        else:
            pending += [block[len(block) // 2 :], block[: len(block) // 2]]
    frames.sort(key=lambda pair: pair[0])
    return frames, sorted(failed)
