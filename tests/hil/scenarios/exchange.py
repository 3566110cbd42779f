"""Smoke scenario: two processes exchange frames on the HIL bus and count what arrives.

Run inside the namespace by :func:`hil.namespace.run_scenario` (``tests/test_netns.py``)::

    python tests/hil/scenarios/exchange.py --frames 200 --period 0.001

The coordinator starts two peers (:class:`hil.processes.Processes`), waits until both have
opened the bus, tells both to go, and prints one JSON line: per peer ``sent``, ``from_peer``
(distinct frames of the other peer received), ``lost``, ``duplicated``, ``out_of_order``,
``echoes`` (its own frames received back: udp_multicast delivers them) and
``receive_buffer_bytes`` (as the kernel reports it). Each peer sends ``--frames`` frames with
its own ID, the sequence number in bytes 0-3, one every ``--period`` s, receiving in between; with
``--period 0`` it sends them all as one burst before it reads anything. ``--receive-buffer 0``
keeps the system's default socket receive buffer instead of the harness's 4 MiB.
"""

from __future__ import annotations

import argparse
import itertools
import json
import struct
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import can
from hil.namespace import RECEIVE_BUFFER_BYTES, hil_bus, receive_buffer_size
from hil.processes import Processes

PEER_IDS = (0x5A0, 0x5A1)
QUIET_S = 1.0
"""A peer stops listening after this long without a frame once it has sent all of its own."""


def peer(
    own_id: int, other_id: int, frames: int, period: float, receive_buffer: int
) -> dict[str, int]:
    """One peer: open the bus, print ``ready``, wait for ``go`` on stdin, send and count."""
    spec = replace(hil_bus(), receive_buffer_bytes=receive_buffer)
    bus = spec.open()  # refuses udp_multicast outside a loopback-only namespace
    granted = receive_buffer_size(bus)
    seen: list[int] = []
    echoes = 0

    def take(message: can.Message | None) -> None:
        nonlocal echoes
        if message is None:
            return
        if message.arbitration_id == other_id:
            seen.append(struct.unpack_from("<I", message.data)[0])
        elif message.arbitration_id == own_id:
            echoes += 1

    try:
        print("ready", flush=True)
        if sys.stdin.readline().strip() != "go":
            raise SystemExit("peer: expected 'go' on stdin")
        start = time.monotonic()
        for seq in range(frames):
            bus.send(
                can.Message(
                    arbitration_id=own_id,
                    data=struct.pack("<I", seq) + bytes(4),
                    is_extended_id=False,
                )
            )
            if not period:
                continue  # a burst: nothing is read until all frames are sent
            deadline = start + (seq + 1) * period  # receive until this frame's slot is over
            while True:
                remaining = deadline - time.monotonic()
                message = bus.recv(timeout=max(0.0, remaining))
                take(message)
                if message is None or remaining <= 0:
                    break
        last = time.monotonic()
        while len(set(seen)) < frames or echoes < frames:
            message = bus.recv(timeout=0.05)
            if message is not None:
                take(message)
                last = time.monotonic()
            elif time.monotonic() - last > QUIET_S:
                break
    finally:
        bus.shutdown()
    distinct = set(seen)
    return {
        "sent": frames,
        "from_peer": len(distinct),
        "lost": frames - len(distinct),
        "duplicated": len(seen) - len(distinct),
        "out_of_order": sum(1 for a, b in itertools.pairwise(seen) if b < a),
        "echoes": echoes,
        "receive_buffer_bytes": granted,
    }


def coordinate(
    frames: int, period: float, receive_buffer: int, log_dir: Path, timeout: float
) -> dict[str, object]:
    """Start both peers, let them go together, collect their counts."""
    names = ("a", "b")
    with Processes(log_dir) as procs:
        for name, own, other in zip(names, PEER_IDS, reversed(PEER_IDS), strict=True):
            procs.python(
                name,
                __file__,
                "peer",
                f"--own-id={own}",
                f"--other-id={other}",
                f"--frames={frames}",
                f"--period={period}",
                f"--receive-buffer={receive_buffer}",
                stdin=True,
            )
        for name in names:
            procs.wait_for_line(name, "ready", timeout)
        for name in names:
            procs.send_line(name, "go")
        status = {name: procs.wait(name, timeout) for name in names}
        report: dict[str, object] = {
            "frames": frames,
            "period_s": period,
            "receive_buffer_asked": receive_buffer,
        }
        for name in names:
            if status[name] != 0:
                raise SystemExit(f"peer {name} failed ({status[name]}):\n{procs.errors(name)}")
            report[name] = json.loads(procs.output(name).splitlines()[-1])
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("role", nargs="?", choices=("coordinate", "peer"), default="coordinate")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--period", type=float, default=0.001, help="s between frames; 0: burst")
    parser.add_argument(
        "--receive-buffer",
        type=int,
        default=RECEIVE_BUFFER_BYTES,
        help="socket receive buffer to ask for, bytes; 0: the system default",
    )
    parser.add_argument("--own-id", type=int, default=PEER_IDS[0])
    parser.add_argument("--other-id", type=int, default=PEER_IDS[1])
    parser.add_argument("--timeout", type=float, default=30.0)
    parser.add_argument("--logs", type=Path, help="folder for the peers' output (default: temp)")
    args = parser.parse_args()
    if args.role == "peer":
        print(
            json.dumps(
                peer(args.own_id, args.other_id, args.frames, args.period, args.receive_buffer)
            ),
            flush=True,
        )
        return
    settings = (args.frames, args.period, args.receive_buffer)
    if args.logs:
        report = coordinate(*settings, args.logs, args.timeout)
    else:
        with tempfile.TemporaryDirectory(prefix="dtid-hil-") as logs:
            report = coordinate(*settings, Path(logs), args.timeout)
    print(json.dumps(report), flush=True)


if __name__ == "__main__":
    main()
