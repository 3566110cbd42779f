"""Which bus channel each role's frames are read from, in a recording of several buses.

A logger on two buses records a message twice where a gateway forwards it from one bus to the
other, and two buses may use one ID for different messages. Decoded together, such frames give a
series with every sample twice or two signals interleaved: the crank-sampling check then reads
twice the rate, or nothing at all is right. A role's message found on more than one channel is
therefore refused unless the signal map names the role's ``channel``
(:class:`dtid.dbc.signal_map.RoleSpec`), and with a channel named, that channel's frames alone
are decoded. The channels are named as the recording names them
(:func:`dtid.acquisition.logfile.recorded_channel`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import can

from dtid.acquisition.logfile import recorded_channel
from dtid.dbc.interface import VehicleInterface
from dtid.errors import RecordingError


def frames_of_role_channels(
    frames: Sequence[can.Message], interface: VehicleInterface, path: Path
) -> Sequence[can.Message]:
    """``frames`` less those of a mapped message on another channel than its role's.

    Parameters
    ----------
    frames
        The recording's frames, in order.
    interface
        The signal map bound to the DBC: each role's message and channel.
    path
        The recording: its suffix says how it names channels, and messages name it.

    Raises
    ------
    RecordingError
        Where a role's message comes on several channels and the map names none, or not on
        the channel the map names.
    """
    roles: dict[tuple[int, bool], list[str]] = {}
    for role in interface.present_roles():
        roles.setdefault(interface.frame_key(role), []).append(role)
    counts: dict[tuple[int, bool], Counter] = {key: Counter() for key in roles}
    for frame in frames:
        counter = counts.get((frame.arbitration_id, frame.is_extended_id))
        if counter is not None:
            counter[frame.channel] += 1
    keep: dict[tuple[int, bool], str] = {}
    for key, counter in counts.items():
        named: Counter = Counter()
        for channel, n in counter.items():
            named[recorded_channel(channel, path.suffix)] += n
        if set(named) <= {None}:
            continue  # absent (the decoding says so), or a format without channels
        wanted = interface.channel(roles[key][0])
        found = ", ".join(
            f"{channel} ({n} frames)" for channel, n in sorted(named.items(), key=str)
        )
        what = (
            f"{path}: the message of role {', '.join(roles[key])} "
            f"('{interface.signal_map.roles[roles[key][0]].message}', ID 0x{key[0]:X})"
        )
        if wanted is None:
            if len(named) > 1:
                raise RecordingError(
                    f"{what} comes on channels {found}: a logger of two buses records it twice "
                    "where a gateway forwards it, or two buses use the ID for different "
                    "messages; give the role's channel in the signal map (channel = "
                    f"{_example(named)}; docs/vehicle.md, Signal maps)"
                )
        elif wanted not in named:
            raise RecordingError(
                f"{what} is not on channel {wanted!r}, which the signal map names, but on "
                f"{found}; correct the role's channel"
            )
        elif len(named) > 1:
            keep[key] = wanted
    if not keep:
        return frames
    return [
        frame
        for frame in frames
        if (key := (frame.arbitration_id, frame.is_extended_id)) not in keep
        or recorded_channel(frame.channel, path.suffix) == keep[key]
    ]


def _example(named: Counter) -> str:
    """The first channel, written as the signal map takes it."""
    first = sorted((c for c in named if c is not None), key=str)[0]
    return first if first.isdigit() else f'"{first}"'
