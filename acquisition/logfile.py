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

Decoding makes times relative to the first frame, so an absolute offset is harmless.
"""

import io
import logging
import os
import re
import struct
import zlib
from collections.abc import Iterable
from operator import attrgetter
from pathlib import Path

import can
from can.io.blf import FILE_HEADER_SIZE, BLFParseError

from dtid.errors import RecordingError

logger = logging.getLogger(__name__)

_WRITERS = {".asc": can.ASCWriter, ".blf": can.BLFWriter, ".log": can.CanutilsLogWriter}
_TEXT_READERS = {".asc": can.ASCReader, ".log": can.CanutilsLogReader}
#: Suffixes of the recording formats read and written.
SUPPORTED_SUFFIXES: tuple[str, ...] = tuple(sorted(_WRITERS))

# Last line of a complete ASC file, lower case.
_ASC_END = "end triggerblock"
# Characters that never occur in a text CAN log (control characters but tab, CR and LF).
_CONTROL_CHARACTER = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")
# Errors python-can's BLF reader raises on a cut or damaged file.
_BLF_ERRORS = (BLFParseError, struct.error, zlib.error, ValueError, EOFError)


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
    path: str | os.PathLike[str], messages: Iterable[can.Message], *, overwrite: bool = False
) -> int:
    """Write CAN frames to a recording file.

    The frames are written in timestamp order (a stable sort; the formats cannot store time
    going backwards). They are first written to a temporary file beside ``path`` that replaces
    ``path`` only when complete, so a failed write neither leaves a half-written recording nor
    destroys an existing one.

    Parameters
    ----------
    path : str or os.PathLike
        The file; its suffix (``.blf``, ``.asc`` or ``.log``) selects the format.
    messages : Iterable[can.Message]
        The frames, timestamps in s.
    overwrite : bool, optional
        Replace an existing file. Default False.

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
        with _WRITERS[suffix](temporary) as writer:
            for frame in frames:
                writer.on_message_received(frame)
        temporary.replace(path)
        complete = True
    except OSError as error:
        raise RecordingError(f"cannot write recording {path}: {error.strerror or error}") from error
    finally:
        if not complete:
            temporary.unlink(missing_ok=True)
            if reserved:
                path.unlink(missing_ok=True)
    logger.info("wrote %d frames to %s", len(frames), path)
    return len(frames)


def read_log(path: str | os.PathLike[str]) -> list[can.Message]:
    """Read the CAN frames of a recording file.

    A file cut short (a recording interrupted while written) is read up to the cut, with a
    warning: a BLF file shorter than its header says, or never closed; a text file whose last
    line has no line end (that line is dropped); an ASC file without its closing
    ``End TriggerBlock``. A text file cut exactly at a line end of a frame cannot be told from a
    complete one.

    Parameters
    ----------
    path : str or os.PathLike
        The file; its suffix (``.blf``, ``.asc`` or ``.log``) selects the format.

    Returns
    -------
    list[can.Message]
        The frames in file order, timestamps in s (see the module notes on what each format
        preserves).

    Raises
    ------
    RecordingError
        If the file does not exist, has an unsupported suffix, cannot be read, has a broken
        header, holds data that cannot be parsed before any cut, or holds no frame.
    """
    path = Path(path)
    suffix = _suffix(path)
    if not path.exists():
        raise RecordingError(f"recording {path} does not exist")
    if path.is_dir():
        raise RecordingError(f"recording {path} is a directory, not a {suffix} file")
    try:
        frames = _read_blf(path) if suffix == ".blf" else _read_text(path, suffix)
    except RecordingError:
        raise
    except OSError as error:
        raise RecordingError(f"cannot read recording {path}: {error.strerror or error}") from error
    if not frames:
        raise RecordingError(f"recording {path} holds no CAN frames")
    logger.info("read %d frames from %s", len(frames), path)
    return frames


def _read_blf(path: Path) -> list[can.Message]:
    size = path.stat().st_size
    frames: list[can.Message] = []
    failure: BaseException | None = None
    with path.open("rb") as file:
        try:
            reader = can.BLFReader(file)
        except _BLF_ERRORS as error:
            raise RecordingError(
                f"recording {path} is not a readable BLF file (broken header: {_reason(error)})"
            ) from error
        try:
            for frame in reader:
                frames.append(frame)
        except _BLF_ERRORS as error:
            failure = error
    declared = reader.file_size
    if declared > size:
        cut = f"is cut short ({size} of {declared} bytes)"
    elif declared <= FILE_HEADER_SIZE < size:
        cut = "was not closed by its writer (header never completed)"
    elif failure is not None:
        raise RecordingError(
            f"recording {path} is damaged after {len(frames)} frames: {_reason(failure)}"
        ) from failure
    else:
        return frames
    if not frames:
        raise RecordingError(f"recording {path} {cut} and holds no complete CAN frame")
    logger.warning("recording %s %s; read the %d frames before the cut", path, cut, len(frames))
    return frames


def _read_text(path: Path, suffix: str) -> list[can.Message]:
    # latin-1 maps every byte to a character: Vector tools write ASC headers in the Windows
    # code page, and lines that are not frames fail to parse (.log) or are skipped (.asc).
    text = path.read_bytes().decode("latin-1")
    end = text.rfind("\n") + 1
    tail = text[end:]
    if tail.strip() and tail.strip().lower() != _ASC_END:
        logger.warning(
            "recording %s ends in an incomplete line (cut while written?); ignored it: %r",
            path,
            tail[:60],
        )
        text = text[:end]
    binary = _CONTROL_CHARACTER.search(text)
    if binary is not None:
        line = text.count("\n", 0, binary.start()) + 1
        raise RecordingError(
            f"recording {path} holds binary data in line {line}; it is not a {suffix} text log "
            "or it is damaged"
        )
    if suffix == ".asc" and not text.rstrip().lower().endswith(_ASC_END):
        logger.warning(
            "recording %s lacks its closing 'End TriggerBlock' line; it may be cut short", path
        )
    frames: list[can.Message] = []
    try:
        for frame in _TEXT_READERS[suffix](io.StringIO(text)):
            frames.append(frame)
    except (ValueError, IndexError) as error:
        raise RecordingError(
            f"recording {path} cannot be parsed after {len(frames)} frames: {_reason(error)}"
        ) from error
    return frames
