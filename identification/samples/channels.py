"""Which bus channel each role's frames are read from, in a recording of several buses.

A logger on two buses records a message twice where a gateway forwards it from one bus to the
other, and two buses may use one ID for different messages. Decoded together, such frames give a
series with every sample twice or two signals interleaved: the crank-sampling check then reads
twice the rate, or nothing at all is right. Where the signal map names a role's ``channel``
(:class:`dtid.dbc.signal_map.RoleSpec`) that channel's frames alone are decoded; a role's message
found on several channels without one named, or not on the one named, is a problem of the role
that ``dtid inspect`` shows and the analysis refuses
(:meth:`dtid.identification.samples.recording.Recording.test_data`). Channels are named as the
recording names them (:func:`dtid.acquisition.logfile.recorded_channel`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import can

from dtid.acquisition.logfile import recorded_channel
from dtid.dbc.interface import VehicleInterface


@dataclass(frozen=True)
class ChannelSelection:
    """The frames to decode, and the channels each role's message came on.

    Attributes
    ----------
    frames
        The recording's frames less those of a mapped message on another channel than the one
        its role names.
    found
        Per role whose message the recording holds on a named channel: frames per channel.
    problems
        Per role: why its frames cannot be read as one series (they are left as recorded).
    """

    frames: Sequence[can.Message]
    found: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    problems: Mapping[str, str] = field(default_factory=dict)


def select_channels(
    frames: Sequence[can.Message], interface: VehicleInterface, path: Path
) -> ChannelSelection:
    """Each role's frames from its channel (see the module notes).

    Parameters
    ----------
    frames
        The recording's frames, in order.
    interface
        The signal map bound to the DBC: each role's message and channel.
    path
        The recording: its suffix says how it names channels; messages name it.
    """
    roles: dict[tuple[int, bool], list[str]] = {}
    for role in interface.present_roles():
        roles.setdefault(interface.frame_key(role), []).append(role)
    counts: dict[tuple[int, bool], Counter] = {key: Counter() for key in roles}
    for frame in frames:
        counter = counts.get((frame.arbitration_id, frame.is_extended_id))
        if counter is not None:
            counter[frame.channel] += 1
    found: dict[str, dict[str, int]] = {}
    problems: dict[str, str] = {}
    keep: dict[tuple[int, bool], str] = {}
    for key, counter in counts.items():
        named: Counter = Counter()
        for channel, n in counter.items():
            named[recorded_channel(channel, path.suffix)] += n
        if set(named) <= {None}:
            continue  # absent (the decoding says so), or a format without channels
        channels = {str(channel): n for channel, n in sorted(named.items(), key=str)}
        listed = ", ".join(f"{channel} ({n} frames)" for channel, n in channels.items())
        what = (
            f"{path}: the message of role {', '.join(roles[key])} "
            f"('{interface.signal_map.roles[roles[key][0]].message}', ID 0x{key[0]:X})"
        )
        wanted = interface.channel(roles[key][0])
        problem = None
        if wanted is None and len(named) > 1:
            problem = (
                f"{what} comes on channels {listed}: a logger of two buses records it twice "
                "where a gateway forwards it, or two buses use the ID for different messages; "
                f"give the role's channel in the signal map (channel = {_example(channels)}; "
                "docs/vehicle.md, Signal maps)"
            )
        elif wanted is not None and wanted not in named:
            problem = (
                f"{what} is not on channel {wanted!r}, which the signal map names, but on "
                f"{listed}; correct the role's channel"
            )
        elif wanted is not None and len(named) > 1:
            keep[key] = wanted
        for role in roles[key]:
            found[role] = channels
            if problem is not None:
                problems[role] = problem
    if keep:
        frames = [
            frame
            for frame in frames
            if (key := (frame.arbitration_id, frame.is_extended_id)) not in keep
            or recorded_channel(frame.channel, path.suffix) == keep[key]
        ]
    return ChannelSelection(frames, found, problems)


def _example(channels: Mapping[str, int]) -> str:
    """The first channel, written as the signal map takes it."""
    first = next(channel for channel in channels if channel != "None")
    return first if first.isdigit() else f'"{first}"'
