"""Acquisition daemon speed: frames recorded and decoded per second, and bus-to-worker latency.

Run from the repository root::

    PYTHONPATH=. python benchmarks/bench_daemon.py [--quick] [--bus virtual|udp]

(a) Throughput, on one core (the process pinned to CPU 0): pre-built frames go through the
    daemon's real per-frame path, :meth:`dtid.acquisition.framepath.FramePath.take` (bus time, echo
    filter, BLF log) and, per block, :meth:`~dtid.acquisition.framepath.FramePath.publish_block`
    (decode through the DBC, counter health, speed-window check, JSON ``samples`` event on a ZeroMQ
    PUB socket), with the log flushed (``fsync``) every ``flush_period_s`` as in the daemon. The
    bus's own ``recv`` is not part of it. Three mixes: the engine ECU's frames of the product DBC
    (all decoded), unmapped 8-byte frames and unmapped 0-byte frames (recorded only), in blocks
    of 200 frames (the daemon's batch at about 100,000 frames/s with a 2 ms block period) and,
    for the ECU mix, of 1 frame (a quiet bus: one event per frame). Compared with the highest
    frame rate of a 1 Mbit/s classical CAN bus, computed below without bit stuffing.
(b) Latency: the whole daemon (:class:`dtid.acquisition.daemon.Daemon`) with a fake engine ECU
sending
    speed, torque-request and mean-torque frames, and a ZeroMQ SUB subscriber in a separate
    process. Latency of a frame = the subscriber's ``time.time()`` when the samples event holding
    it arrives minus the frame's timestamp in that event (``time_factor`` 1: the receive time on
    the bus, in ``time.time()``). Median, 99th percentile and maximum over every ECU frame of a
    test, at the ECU rate of an engine at 1000 rpm (167 frames/s) and at a heavy 3000 frames/s.
    Two buses: ``--bus virtual`` (default), python-can's in-process virtual bus with the ECU as a
    thread of this process (its timestamps are the send times); ``--bus udp``, python-can's
    ``udp_multicast`` with the ECU in another process, inside a private network namespace whose
    only interface is loopback (the script re-runs itself under ``unshare -n``; its timestamps
    are the kernel's receive times at the daemon's socket). udp_multicast is never opened
    outside such a namespace.

Prints the figures and writes them to ``benchmarks/results/daemon_<bus>.json``. A benchmark, not
a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import can
import numpy as np

from dtid.acquisition import netns
from dtid.acquisition.clock import BusClock
from dtid.acquisition.config import (
    AcquisitionConfig,
    BusConfig,
    OutputConfig,
    PipelineConfig,
    SafetyConfig,
    TestPlan,
)
from dtid.acquisition.daemon import Daemon
from dtid.acquisition.framepath import FramePath
from dtid.acquisition.health import EchoFilter
from dtid.acquisition.recorder import Recorder
from dtid.acquisition.safety import SafetyMonitor
from dtid.acquisition.server import EventServer
from dtid.dbc.loader import load_interface

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
UDP_GROUP = "239.74.163.2"
"""IPv4 multicast group of the udp_multicast latency test (IPv6 groups deliver nothing on lo)."""
UNSHARE = ["unshare", "--net", "--"] if os.geteuid() == 0 else ["unshare", "-r", "--net", "--"]
NAMESPACE_SETUP = (
    "ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo && "
    'exec "$@"'
)
"""Loopback of the private namespace up, with multicast and the multicast route."""

BITRATE = 1_000_000
"""Bit rate of the fastest classical CAN bus, bit/s."""


def frame_bits(data_bytes: int) -> int:
    """Bits on the bus of a classical standard-ID data frame, without bit stuffing.

    SOF 1 + identifier 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data 8n + CRC 15 + CRC delimiter 1 +
    ACK slot 1 + ACK delimiter 1 + EOF 7 = 44 + 8n, plus the interframe space of 3 bits: 47 + 8n
    (111 bits for 8 data bytes, 47 for none). Stuff bits (up to one per 4 bits of the stuffed
    part) only make frames longer, so these are the highest frame rates.
    """
    return 47 + 8 * data_bytes


def full_bus_rates() -> dict[str, float]:
    """Frames per second of a saturated 1 Mbit/s bus."""
    return {
        "8_byte_frames_per_s": BITRATE / frame_bits(8),
        "0_byte_frames_per_s": BITRATE / frame_bits(0),
    }


def ecu_frames(n: int, start: float) -> list[can.Message]:
    """``n`` frames of the engine ECU at 1000 rpm: speed and torque request every 15 ms, the
    mean torque every other time, counters running, timestamps from ``start``."""
    interface = load_interface()
    frames: list[can.Message] = []
    event = 0
    while len(frames) < n:
        t = start + 0.015 * event
        frames.append(interface.encode("speed", 1000.0, t, counter=event % 65536))
        frames.append(interface.encode("torque_request", 20.0, t, counter=event % 256))
        if event % 2 == 0:
            stroke = event // 2
            frames.append(
                interface.encode("mean_torque", 20.0, t, counter=stroke % 256, cylinder=stroke % 4)
            )
        event += 1
    return frames[:n]


def unmapped_frames(n: int, start: float, data_bytes: int) -> list[can.Message]:
    """``n`` frames on an ID the signal map does not use (recorded, not decoded)."""
    payload = bytes(range(data_bytes))
    return [
        can.Message(
            timestamp=start + 1e-5 * i, arbitration_id=0x321, is_extended_id=False, data=payload
        )
        for i in range(n)
    ]


def copies(frames: list[can.Message]) -> list[can.Message]:
    """Fresh frames (the path sets timestamp and channel on the ones it takes)."""
    return [
        can.Message(
            timestamp=f.timestamp,
            arbitration_id=f.arbitration_id,
            is_extended_id=f.is_extended_id,
            data=f.data,
            channel="vcan0",
        )
        for f in frames
    ]


def throughput(frames: list[can.Message], block: int, repeats: int, workdir: Path) -> float:
    """Frames per second through the per-frame path, best of ``repeats``."""
    interface = load_interface()
    best = 0.0
    for repeat in range(repeats):
        clock = BusClock(1.0)
        directory = workdir / f"throughput-{uuid.uuid4().hex[:8]}"
        directory.mkdir()
        recorder = Recorder(directory / "bench.blf", frames[0].timestamp - 1.0, 0.5)
        pipeline = PipelineConfig(
            blocks=f"ipc://{directory}/blocks", replay=f"ipc://{directory}/replay"
        )
        server = EventServer(pipeline, f"bench-{repeat}")
        echo = EchoFilter([interface.frame_key("test_torque"), interface.frame_key("heartbeat")])
        path = FramePath(interface, clock, recorder, server, echo, {})
        path.safety = SafetyMonitor(SafetyConfig(), frames[0].timestamp, 0.5)
        fresh = copies(frames)
        take, publish = path.take, path.publish_block
        flush = recorder.flush_if_due
        started = time.perf_counter()
        for begin in range(0, len(fresh), block):
            for frame in fresh[begin : begin + block]:
                take(frame)
            publish()
            flush()
        elapsed = time.perf_counter() - started
        recorder.close()
        server.close()
        best = max(best, len(fresh) / elapsed)
    return best


def send_ecu_frames(bus: can.BusABC, rate: float, stop: threading.Event) -> None:
    """Engine ECU frames at ``rate`` frames/s until ``stop``: speed and torque request at every
    crank event, the mean torque at every other (2.5 frames per event), counters running."""
    interface = load_interface()
    encode, send = interface.encode, bus.send
    period = 2.5 / rate
    start = time.time()
    event = 0
    while not stop.is_set():
        time.sleep(max(0.0, start + event * period - time.time()))
        send(encode("speed", 1000.0, 0.0, counter=event % 65536))
        send(encode("torque_request", 20.0, 0.0, counter=event % 256))
        if event % 2 == 0:
            send(encode("mean_torque", 20.0, 0.0, counter=event // 2 % 256, cylinder=0))
        event += 1


UDP_ECU = """
import sys, threading
sys.path.insert(0, {repo!r})
from dtid.acquisition.bus import open_bus
from dtid.acquisition.config import BusConfig
from benchmarks.bench_daemon import send_ecu_frames
bus = open_bus(BusConfig(interface="udp_multicast", channel={group!r}))
print("ready", flush=True)
send_ecu_frames(bus, {rate!r}, threading.Event())
"""

SUBSCRIBER = """
import json, sys, time, zmq
context = zmq.Context()
sub = context.socket(zmq.SUB)
sub.setsockopt(zmq.SUBSCRIBE, b"samples")
sub.setsockopt(zmq.SUBSCRIBE, b"end")
sub.connect(sys.argv[1])
quiet_ms = int(sys.argv[3]) if len(sys.argv) > 3 else 20000
print("ready", flush=True)
latencies = []
while sub.poll(quiet_ms):
    topic, body = sub.recv_multipart()
    now = time.time()
    if topic == b"end":
        break
    event = json.loads(body)
    for role in ("speed", "torque_request", "mean_torque"):
        latencies.extend(now - t for t in event["roles"].get(role, {}).get("t", []))
json.dump(latencies, open(sys.argv[2], "w"))
"""


def latency(bus: str, rate: float, duration_s: float, workdir: Path) -> dict[str, Any]:
    """Bus-to-subscriber latency of the ECU frames of one test on ``bus`` (``virtual``: ECU
    thread in this process; ``udp``: ECU process on udp_multicast), s."""
    directory = workdir / f"latency-{uuid.uuid4().hex[:8]}"
    if bus == "udp":
        bus_config = BusConfig(interface="udp_multicast", channel=UDP_GROUP)
    else:
        bus_config = BusConfig(interface="virtual", channel=f"bench-{uuid.uuid4().hex}")
    config = AcquisitionConfig(
        bus=bus_config,
        test=TestPlan(amplitudes_nm=(5.0,), validation_nm=0.0, duration_s=duration_s, settle_s=0.5),
        output=OutputConfig(directory=directory / "runs"),
        pipeline=PipelineConfig(
            blocks=f"ipc://{directory}/ipc/blocks", replay=f"ipc://{directory}/ipc/replay"
        ),
    )
    out = directory / "latencies.json"
    subscriber = subprocess.Popen(
        [sys.executable, "-c", SUBSCRIBER, config.pipeline.blocks, str(out)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert subscriber.stdout is not None
    subscriber.stdout.readline()  # connected (it reconnects until the daemon binds)
    stop = threading.Event()
    if bus == "udp":
        script = UDP_ECU.format(repo=str(REPO), group=UDP_GROUP, rate=rate)
        ecu = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
        assert ecu.stdout is not None
        ecu.stdout.readline()  # its bus is open; the daemon waits for its first speed frame
    else:
        ecu_bus = can.Bus(interface="virtual", channel=config.bus.channel)
        thread = threading.Thread(target=send_ecu_frames, args=(ecu_bus, rate, stop), daemon=True)
        threading.Timer(0.2, thread.start).start()  # after the daemon's bus is open
    try:
        result = Daemon(config, linger_s=0.5, wait_s=10.0).run()
    finally:
        if bus == "udp":
            ecu.kill()
            ecu.wait()
        else:
            stop.set()
            thread.join()
            ecu_bus.shutdown()
    subscriber.wait(60)
    values = np.array(json.loads(out.read_text()))
    return {
        "bus": bus,
        "ecu_frames_per_s": rate,
        "frames": len(values),
        "status": result.status,
        "median_ms": float(np.median(values) * 1e3),
        "p99_ms": float(np.percentile(values, 99) * 1e3),
        "max_ms": float(values.max() * 1e3),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer frames and a shorter test")
    parser.add_argument(
        "--bus",
        choices=("virtual", "udp"),
        default="virtual",
        help="bus of the latency test: python-can's in-process virtual bus (default) or "
        "udp_multicast with the ECU in another process, inside a private network namespace "
        "(the script re-runs itself under `unshare -n`; needs root or user namespaces)",
    )
    args = parser.parse_args()
    if args.bus == "udp" and not netns.only_loopback():
        return subprocess.call(
            [*UNSHARE, "sh", "-c", NAMESPACE_SETUP, "sh", sys.executable, *sys.argv]
        )
    n = 20_000 if args.quick else 100_000
    repeats = 2 if args.quick else 3
    duration = 5.0 if args.quick else 20.0
    rates = full_bus_rates()
    results: dict[str, Any] = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "python": platform.python_version(),
        "python_can": can.__version__,
        "full_bus": {**rates, "bits_8_byte": frame_bits(8), "bits_0_byte": frame_bits(0)},
    }
    with tempfile.TemporaryDirectory(prefix="dtid-bench-", dir="/tmp") as tmp:
        workdir = Path(tmp)
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
        start = time.time()
        cases = {
            "ecu_block_200": (ecu_frames(n, start), 200),
            "ecu_block_1": (ecu_frames(n // 5, start), 1),
            "unmapped_8_byte_block_200": (unmapped_frames(n, start, 8), 200),
            "unmapped_0_byte_block_200": (unmapped_frames(n, start, 0), 200),
        }
        throughputs = {}
        for name, (frames, block) in cases.items():
            fps = throughput(frames, block, repeats, workdir)
            reference = rates["0_byte_frames_per_s" if "0_byte" in name else "8_byte_frames_per_s"]
            throughputs[name] = {"frames_per_s": fps, "x_full_bus": fps / reference}
            print(f"{name:28s} {fps:10,.0f} frames/s  {fps / reference:5.1f}x full bus")
        results["throughput_one_core"] = throughputs
        os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
        latencies = {}
        for rate in (167.0, 3000.0):
            figures = latency(args.bus, rate, duration, workdir)
            latencies[f"{rate:g}_frames_per_s"] = figures
            print(
                f"latency ({args.bus}) at {rate:6.0f} frames/s: median {figures['median_ms']:.3f} "
                f"ms, p99 {figures['p99_ms']:.3f} ms, max {figures['max_ms']:.1f} ms "
                f"({figures['frames']} frames, test {figures['status']})"
            )
        results["latency"] = latencies
    out = RESULTS / f"daemon_{args.bus}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
