"""ASAM MDF 4 (.mf4) recordings: python-can's MF4 writer and reader (through asammdf), fitted to
whole recordings and to a session's metadata.

python-can lays the bus out as ASAM's bus-logging convention does (a ``CAN_DataFrame`` channel
group with its ID, IDE, DLC, DataLength, DataBytes and Dir fields, one group each for error and
remote frames), which INCA, CANape and Vector loggers read and write. Two things are changed here:

- Data frames are appended in blocks of :data:`BLOCK_FRAMES` instead of one by one: python-can's
  writer calls asammdf once per frame (90 us a frame on this host; a 60 s chirp test of 53,000
  frames took 5 s, a soak's 4.9 million frames would take 7 minutes), in blocks 5 us a frame.
- The file's start time is the recording's own first timestamp, not the wall time at which the
  writer was made, so that frame times are stored relative to it (python-can subtracts the wall
  clock: a simulated recording starting at 0 s kept its times only to 0.2 us).

The session's metadata (:mod:`dtid.acquisition.metadata`) goes into the header's comment, as ASAM
MDF 4 provides for it: an ``HDcomment`` XML whose ``common_properties`` hold one element,
``dtid_metadata``, with the JSON text.
"""

from __future__ import annotations

import gc
import json
import logging
import os
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any, BinaryIO, TypeVar
from xml.etree import ElementTree

import can
import numpy as np
from asammdf import MDF
from can.io.mf4 import STD_DTYPE, MF4Reader, MF4Writer

from dtid.errors import RecordingError

T = TypeVar("T")

BLOCK_FRAMES = 8192
"""Data frames buffered before they are appended to the file's data group."""
METADATA_ELEMENT = "dtid_metadata"
"""Name of the header comment's property holding the session metadata (JSON)."""
_FIELD = "CAN_DataFrame."
_FRAME_GROUPS = ("CAN_DataFrame", "CAN_ErrorFrame", "CAN_RemoteFrame")


class BulkMF4Writer(MF4Writer):
    """python-can's MF4 writer with block appends, the recording's own start time and metadata.

    Parameters
    ----------
    file
        Path or binary file to write.
    start_s
        Start time of the recording, s (its first frame's timestamp or earlier): stored as the
        file's start time, frame times relative to it.
    metadata
        Session metadata written into the header comment; None for none.
    """

    def __init__(
        self,
        file: str | os.PathLike[str] | BinaryIO,
        start_s: float,
        metadata: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(file)
        # python-can keeps the start time in these two attributes and offers no argument for
        # it; the header keeps whole microseconds, and the offsets are taken from that value
        start = datetime.fromtimestamp(start_s, UTC)
        self._mdf.header.start_time = start
        self._start_time = self.last_timestamp = start.timestamp()
        if metadata is not None:
            self._mdf.header.comment = header_comment(metadata)
        self._block = np.zeros(BLOCK_FRAMES, dtype=STD_DTYPE)
        self._times = np.zeros(BLOCK_FRAMES)
        self._count = 0

    def on_message_received(self, msg: can.Message) -> None:
        """Buffer a data frame (error, remote and FD frames go python-can's way at once)."""
        if msg.is_remote_frame or msg.is_error_frame or msg.is_fd or msg.timestamp is None:
            super().on_message_received(msg)
            return
        record = self._block[self._count]
        channel = can.util.channel2int(msg.channel)
        record[_FIELD + "BusChannel"] = 0 if channel is None else channel
        record[_FIELD + "ID"] = msg.arbitration_id
        record[_FIELD + "IDE"] = int(msg.is_extended_id)
        record[_FIELD + "Dir"] = 0 if msg.is_rx else 1
        size = len(msg.data)
        record[_FIELD + "DataLength"] = size
        record[_FIELD + "DataBytes"][:size] = msg.data
        record[_FIELD + "DLC"] = msg.dlc
        self._times[self._count] = msg.timestamp - self._start_time
        self.last_timestamp = max(self.last_timestamp, msg.timestamp)
        self._count += 1
        if self._count == BLOCK_FRAMES:
            self._append_block()

    def _append_block(self) -> None:
        if self._count:
            count = self._count
            self._mdf.extend(0, [(self._times[:count].copy(), None), (self._block[:count], None)])
            self._block = np.zeros(BLOCK_FRAMES, dtype=STD_DTYPE)
            self._count = 0

    def stop(self) -> None:
        """Append the buffered frames and write the file."""
        self._append_block()
        super().stop()


def frame_count(path: str | os.PathLike[str]) -> int:
    """Frames an .mf4 file holds, from its channel groups' cycle counts (nothing decoded).

    Raises
    ------
    RecordingError
        If the file is not a readable MDF 4 file.
    """

    def count() -> int:
        with MDF(path) as mdf:
            return sum(
                group.channel_group.cycles_nr
                for group in mdf.groups
                if any(str(c.name).startswith(_FRAME_GROUPS) for c in group.channels)
            )

    return _reading(path, count)


def header_comment(metadata: dict[str, Any]) -> str:
    """The MDF 4 header comment (``HDcomment`` XML) carrying the session metadata."""
    root = ElementTree.Element("HDcomment")
    ElementTree.SubElement(root, "TX").text = "drivetrain-id recording"
    properties = ElementTree.SubElement(root, "common_properties")
    element = ElementTree.SubElement(properties, "e", name=METADATA_ELEMENT, type="string")
    element.text = json.dumps(metadata, sort_keys=True)
    return ElementTree.tostring(root, encoding="unicode")


def read_mf4(path: os.PathLike[str]) -> tuple[list[can.Message], dict[str, Any] | None]:
    """Read the CAN frames of an .mf4 file, and the session metadata in its header, if any.

    Parameters
    ----------
    path
        The file.

    Returns
    -------
    frames : list[can.Message]
        The frames of every CAN bus-logging channel group, in time order, timestamps in s
        (absolute: the file's start time plus the frame's offset).
    metadata : dict or None
        What :func:`header_comment` stored; None for a file written by another tool.

    Raises
    ------
    RecordingError
        If the file is not a readable MDF 4 file.
    """

    def read() -> tuple[list[can.Message], str]:
        with MF4Reader(path) as reader:
            return list(reader), reader._mdf.header.comment  # python-can offers no accessor

    frames, comment = _reading(path, read)
    return frames, parse_header_comment(comment)


def read_mf4_metadata(path: os.PathLike[str]) -> dict[str, Any] | None:
    """The session metadata in an .mf4 file's header (None when it holds none).

    Raises
    ------
    RecordingError
        If the file is not a readable MDF 4 file.
    """

    def read() -> str:
        with MDF(path) as mdf:
            return mdf.header.comment

    return parse_header_comment(_reading(path, read))


def _reading(path: os.PathLike[str], read: Callable[[], T]) -> T:
    """``read()`` of an .mf4 file, asammdf's failure on a damaged file turned into one
    RecordingError, without the traceback asammdf logs and the ``__del__`` complaints of its
    half-built objects (collected here, while they are muted; the error is raised outside the
    handler, so that it does not hold them in its context)."""
    quiet = logging.getLogger("asammdf")
    was_disabled, hook = quiet.disabled, sys.unraisablehook
    quiet.disabled, sys.unraisablehook = True, lambda unraisable: None
    reason = None
    try:
        try:
            return read()
        except Exception as error:  # asammdf raises many kinds on a damaged file
            reason = " ".join(str(error).split()) or type(error).__name__
        gc.collect()
    finally:
        quiet.disabled, sys.unraisablehook = was_disabled, hook
    raise RecordingError(
        f"recording {path} is not a readable MF4 file ({reason}); an MF4 file is written "
        "whole when its recording ends, so a cut or damaged one cannot be read in part: use "
        "the logger's own repair tool, or the session's BLF journal when dtid recorded it"
    )


def parse_header_comment(comment: str) -> dict[str, Any] | None:
    """The session metadata of an MDF 4 header comment; None when it holds none."""
    if not comment or METADATA_ELEMENT not in comment:
        return None
    try:
        root = ElementTree.fromstring(comment)
    except ElementTree.ParseError:
        return None
    for element in root.iter("e"):
        if element.get("name") == METADATA_ELEMENT and element.text:
            try:
                value = json.loads(element.text)
            except json.JSONDecodeError:
                return None
            return value if isinstance(value, dict) else None
    return None
