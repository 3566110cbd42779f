"""The daemon's frame path under 10^5 random frames: nothing crashes, every frame is counted
and logged, and the safety envelope still raises its alarm when it must."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import can
import numpy as np

from dtid.acquisition.clock import BusClock
from dtid.acquisition.config import SafetyConfig
from dtid.acquisition.framepath import FramePath
from dtid.acquisition.health import EchoFilter
from dtid.acquisition.logfile import read_log_checked
from dtid.acquisition.recorder import Recorder
from dtid.acquisition.safety import SafetyMonitor
from dtid.dbc.loader import load_interface

INTERFACE = load_interface()
TOOL_KEYS = [INTERFACE.frame_key("test_torque"), INTERFACE.frame_key("heartbeat")]
MAPPED = sorted({INTERFACE.frame_key(r)[0] for r in INTERFACE.present_roles()})
FD_LENGTHS = (12, 16, 20, 24, 32, 48, 64)
N_FRAMES = 100_000
BLOCK = 200
"""Frames per samples event, as the daemon's blocks."""


class _Server:
    """The event server's interface, keeping the events in memory."""

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    @property
    def count(self) -> int:
        return len(self.events)

    def publish(self, kind: str, fields: dict[str, Any]) -> dict[str, Any]:
        event = {"kind": kind, "seq": len(self.events), **fields}
        self.events.append(event)
        return event


def random_frames(rng: np.random.Generator, n: int, tool_ids: bool) -> list[can.Message]:
    """Random IDs (the tool's and the mapped ones among them), every DLC, CAN FD lengths, error
    and remote frames, bursts with equal times, reordered and duplicated frames."""
    ids = [key[0] for key in TOOL_KEYS] if tool_ids else []
    tool = {key[0] for key in TOOL_KEYS}
    others = [int(i) for i in rng.integers(0, 0x7FF, 20) if tool_ids or int(i) not in tool]
    ids = np.array(ids + [i for i in MAPPED if tool_ids or i not in tool] + others)
    frames, t = [], time.time()
    while len(frames) < n:
        kind = rng.random()
        t += 0.0 if rng.random() < 0.1 else float(rng.exponential(0.0005))
        extended = bool(rng.random() < 0.1)
        arbitration_id = int(rng.choice(ids)) if not extended else int(rng.integers(0x800, 1 << 29))
        if kind < 0.02:
            frame = can.Message(timestamp=t, is_error_frame=True, arbitration_id=0, dlc=8)
        elif kind < 0.04:
            frame = can.Message(
                timestamp=t, arbitration_id=arbitration_id, is_remote_frame=True,
                dlc=int(rng.integers(0, 9)), is_extended_id=extended,
            )  # fmt: skip
        elif kind < 0.10:
            length = int(rng.choice(FD_LENGTHS))
            frame = can.Message(
                timestamp=t, arbitration_id=arbitration_id, is_fd=True, is_extended_id=extended,
                data=rng.integers(0, 256, length, dtype=np.uint8).tobytes(),
            )  # fmt: skip
        else:
            frame = can.Message(
                timestamp=t, arbitration_id=arbitration_id, is_extended_id=extended,
                data=rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8).tobytes(),
            )  # fmt: skip
        frames.append(frame)
        if rng.random() < 0.01:  # a duplicate
            frames.append(frame)
    order = np.arange(len(frames))
    swaps = rng.integers(1, len(frames), len(frames) // 100)  # neighbours reordered
    order[swaps], order[swaps - 1] = order[swaps - 1], order[swaps]
    return [frames[i] for i in order[:n]]


def run_path(tmp_path: Path, frames: list[can.Message], safety: bool) -> tuple[FramePath, Recorder]:
    recorder = Recorder(tmp_path / "fuzz.blf", frames[0].timestamp, flush_period_s=0.05)
    path = FramePath(
        INTERFACE, BusClock(), recorder, _Server(), EchoFilter(TOOL_KEYS), {"plan": {}}
    )
    if safety:
        path.safety = SafetyMonitor(SafetyConfig(), frames[0].timestamp, settle_s=0.0)
    for start in range(0, len(frames), BLOCK):
        for frame in frames[start : start + BLOCK]:
            path.take(frame)
        path.publish_block()
        recorder.flush_if_due()
    path.publish_health()
    recorder.close()
    return path, recorder


def test_random_frames_are_all_counted_and_logged_and_foreign_ones_alarm(tmp_path: Path) -> None:
    frames = random_frames(np.random.default_rng(7), N_FRAMES, tool_ids=True)
    path, recorder = run_path(tmp_path, frames, safety=False)
    assert recorder.frames == N_FRAMES and recorder.failure is None
    assert path.health.counts.frames == N_FRAMES
    assert path._server.events[-1]["kind"] == "health"
    assert path._server.events[-1]["frames"] == N_FRAMES
    assert (
        sum(e.get("frames", 0) for e in path._server.events if e["kind"] == "samples") == N_FRAMES
    )
    logged, integrity = read_log_checked(recorder.path)
    assert len(logged) == N_FRAMES and integrity.intact
    assert [f.arbitration_id for f in logged] == [f.arbitration_id for f in frames]
    assert path.alarm == "foreign_tx" and path.health.counts.foreign_tx > 0


def test_the_speed_window_still_aborts_among_random_frames(tmp_path: Path) -> None:
    """Random traffic without the tool's IDs, then the engine speed leaves its window."""
    rng = np.random.default_rng(8)
    frames = random_frames(rng, 20_000, tool_ids=False)
    t0 = frames[0].timestamp
    speed = []
    for k, rpm in enumerate([1000.0] * 300 + [1400.0] * 10):
        speed.append(INTERFACE.encode("speed", rpm, t0 + 0.015 * k, counter=k % 256))
    mixed = sorted(frames + speed, key=lambda f: f.timestamp)
    path, recorder = run_path(tmp_path, mixed, safety=True)
    assert path.alarm == "speed_window"
    assert recorder.frames == len(mixed)
