"""Soak: the whole test at full 1 Mbit/s bus load, through daemon and worker, for ten minutes.

Run from the repository root (needs root or unprivileged user namespaces)::

    python -m benchmarks.soak [--chirp-s 180] [--rate 8800] [--quick]

The script re-runs itself in a private network namespace whose only interface is loopback
(python-can's ``udp_multicast`` is never opened anywhere else) and starts, as separate processes
on that bus, what a vehicle test runs:

* ``dtid vehicle``: the virtual vehicle, in real time (its engine ECU frames, about 170/s);
* a filler: unmapped 8-byte frames (ID 0x321, a 32-bit sequence number in the payload) so that
  the bus carries ``--rate`` frames/s in all (default 8,800: a saturated 1 Mbit/s classical bus
  carries at most 9,009 frames/s of 8 bytes);
* ``dtid acquire``: the daemon, running the product's test plan (5, 10, 2 N*m) with chirps of
  ``--chirp-s`` s (default 180 s: three chirps with their settling take about ten minutes);
* ``dtid worker --once``: FRFs and identification from the daemon's stream;
* a ZeroMQ subscriber on the daemon's blocks, which measures the latency from a vehicle frame's
  receive time on the bus to the arrival of the block holding it.

Vehicle and daemon run at nice -5 and the worker at nice 15, as the HIL scenarios do.

Figures (printed and written to ``benchmarks/results/soak.json``):

* frames lost: filler sequence numbers missing from the daemon's raw log between the first and
  the last one it holds, and the daemon's own ``health`` counts of the vehicle's frames;
* latency bus to subscriber: median, p99 and maximum over every vehicle frame;
* resident memory (``VmRSS``) of daemon and worker, sampled every 5 s: at the start of the test,
  at its end, and the largest;
* the identification's relative errors against the vehicle's parameters (the reference vehicle).

A benchmark, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_daemon import NAMESPACE_SETUP, SUBSCRIBER, UDP_GROUP, UNSHARE
from dtid.acquisition import netns

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
FILLER_ID = 0x321
"""ID of the filler frames: not in the product DBC, so recorded and never decoded."""

FILLER = """
import struct, time
import can
from dtid.acquisition.bus import open_bus
from dtid.acquisition.config import BusConfig
bus = open_bus(BusConfig(interface="udp_multicast", channel={group!r}))
rate, slot = {rate!r}, 0.002
per_slot = rate * slot
print("ready", flush=True)
start, sequence = time.monotonic(), 0
while True:
    slot_index = int((time.monotonic() - start) / slot)
    due = int((slot_index + 1) * per_slot)
    while sequence < due:
        payload = struct.pack("<II", sequence, 0)
        bus.send(can.Message(arbitration_id={frame_id}, is_extended_id=False, data=payload))
        sequence += 1
    time.sleep(max(0.0, start + (slot_index + 1) * slot - time.monotonic()))
"""


def config_text(workdir: Path, chirp_s: float) -> str:
    """The configuration file of the soak (dtid.acquisition.config keys)."""
    ipc = workdir / "ipc"
    return f"""
[bus]
interface = "udp_multicast"
channel = "{UDP_GROUP}"
receive_buffer_bytes = {16 << 20}

[test]
duration_s = {chirp_s!r}

[output]
directory = "{workdir / "runs"}"

[pipeline]
blocks = "ipc://{ipc / "blocks"}"
replay = "ipc://{ipc / "replay"}"
results = "ipc://{ipc / "results"}"
"""


def resident_kib(pid: int) -> int | None:
    """Resident memory of a process (VmRSS), KiB; None once it has ended."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def filler_loss(log: Path) -> dict[str, int]:
    """Filler frames in the daemon's log, and sequence numbers missing between its first and last
    one (lost on the way: socket buffer, daemon, recorder)."""
    from dtid.acquisition.logfile import read_log

    sequences = np.array(
        [
            int.from_bytes(bytes(frame.data[:4]), "little")
            for frame in read_log(log)
            if frame.arbitration_id == FILLER_ID
        ],
        dtype=np.int64,
    )
    if len(sequences) == 0:
        return {"recorded": 0, "missing": 0, "repeated": 0}
    span = int(sequences.max() - sequences.min() + 1)
    unique = len(np.unique(sequences))
    return {
        "recorded": len(sequences),
        "missing": span - unique,
        "repeated": len(sequences) - unique,
    }


def identification_errors(document: dict[str, Any]) -> dict[str, float]:
    """Relative errors of an identification JSON against the reference vehicle."""
    from dtid.identification.search.parameterization import theta_from_parameters
    from dtid.simulator.parameters import reference_parameters

    truth = reference_parameters()
    values = {**truth.as_dict(), **theta_from_parameters(truth)}
    found = document["parameters"]
    return {name: round(found[name] / values[name] - 1, 4) for name in values if name in found}


def soak(workdir: Path, chirp_s: float, rate: float) -> dict[str, Any]:
    """Run the soak in ``workdir`` (inside the namespace) and return its figures."""
    (workdir / "ipc").mkdir(mode=0o700)
    (workdir / "runs").mkdir()
    config = workdir / "dtid.toml"
    config.write_text(config_text(workdir, chirp_s))
    bus_priority = ["nice", "-n", "-5"] if os.geteuid() == 0 else []
    dtid = [sys.executable, "-m", "dtid.cli"]
    logs = {name: open(workdir / f"{name}.log", "w") for name in ("vehicle", "acquire", "worker")}
    report = workdir / "vehicle-report.json"
    latencies_file = workdir / "latencies.json"
    processes: dict[str, subprocess.Popen] = {}

    def start(name: str, argv: list[str], **kwargs: Any) -> subprocess.Popen:
        processes[name] = subprocess.Popen(argv, cwd=REPO, **kwargs)
        return processes[name]

    try:
        start(
            "vehicle",
            [*bus_priority, *dtid, "vehicle", "--config", str(config), "--report", str(report)],
            stdout=logs["vehicle"],
            stderr=subprocess.STDOUT,
        )
        filler = FILLER.format(group=UDP_GROUP, rate=rate - 170.0, frame_id=FILLER_ID)
        start("filler", [sys.executable, "-c", filler], stdout=subprocess.PIPE, text=True)
        processes["filler"].stdout.readline()
        subscriber = start(
            "subscriber",
            [
                sys.executable,
                "-c",
                SUBSCRIBER,
                f"ipc://{workdir / 'ipc' / 'blocks'}",
                str(latencies_file),
                "120000",  # ms without a block before it gives up
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        subscriber.stdout.readline()
        worker = ["nice", "-n", "15", *dtid, "worker", "--config", str(config), "--once"]
        start("worker", [*worker, "--no-plot"], stdout=logs["worker"], stderr=subprocess.STDOUT)
        started = time.monotonic()
        acquire = start(
            "acquire",
            [*bus_priority, *dtid, "acquire", "--config", str(config), "--linger", "30"],
            stdout=logs["acquire"],
            stderr=subprocess.STDOUT,
        )
        memory: dict[str, list[tuple[float, int]]] = {"acquire": [], "worker": []}
        while acquire.poll() is None:
            for name, samples in memory.items():
                kib = resident_kib(processes[name].pid)
                if kib is not None:
                    samples.append((time.monotonic() - started, kib))
            time.sleep(5.0)
        test_wall_s = time.monotonic() - started
        processes["filler"].kill()
        processes["worker"].wait(timeout=900)
        subscriber.wait(timeout=180)
        processes["vehicle"].send_signal(signal.SIGTERM)
        processes["vehicle"].wait(timeout=30)
    finally:
        for process in processes.values():
            if process.poll() is None:
                process.kill()
                process.wait()
        for handle in logs.values():
            handle.close()
    acquire_out = (workdir / "acquire.log").read_text()
    health = json.loads(acquire_out.split("health: ", 1)[1].splitlines()[0])
    session = sorted((workdir / "runs").glob("*/"))[-1]
    log = next(session.glob("*.blf"))
    latencies = np.array(json.loads(latencies_file.read_text()))
    identification = session / "identification.json"
    result: dict[str, Any] = {
        "chirp_s": chirp_s,
        "bus_frames_per_s": rate,
        "test_wall_s": round(test_wall_s, 1),
        "daemon_exit": processes["acquire"].returncode,
        "worker_exit": processes["worker"].returncode,
        "log_bytes": log.stat().st_size,
        "filler": filler_loss(log),
        "health": health,
        "latency_ms": {
            "frames": len(latencies),
            "median": float(np.median(latencies) * 1e3),
            "p99": float(np.percentile(latencies, 99) * 1e3),
            "max": float(latencies.max() * 1e3),
        },
        "resident_kib": {
            name: {
                "start": samples[min(2, len(samples) - 1)][1],
                "end": samples[-1][1],
                "max": max(kib for _, kib in samples),
                "samples": samples,
            }
            for name, samples in memory.items()
            if samples
        },
    }
    if report.exists():
        result["vehicle_report"] = json.loads(report.read_text())
    if identification.exists():
        result["identification_errors"] = identification_errors(
            json.loads(identification.read_text())
        )
    else:
        result["worker_log"] = (workdir / "worker.log").read_text()[-3000:]
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chirp-s", type=float, default=180.0, help="chirp duration, s")
    parser.add_argument("--rate", type=float, default=8800.0, help="bus load, frames/s")
    parser.add_argument("--quick", action="store_true", help="20 s chirps (about a minute)")
    args = parser.parse_args()
    if not netns.only_loopback():
        argv = [sys.executable, "-m", "benchmarks.soak", *sys.argv[1:]]
        return subprocess.call([*UNSHARE, "sh", "-c", NAMESPACE_SETUP, "sh", *argv], cwd=REPO)
    chirp_s = 20.0 if args.quick else args.chirp_s
    with tempfile.TemporaryDirectory(prefix="dtid-soak-", dir="/tmp") as tmp:
        figures = soak(Path(tmp), chirp_s, args.rate)
    results = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "python": platform.python_version(),
        **figures,
    }
    summary = {k: v for k, v in results.items() if k not in ("resident_kib", "vehicle_report")}
    print(json.dumps(summary, indent=1))
    for name, memory in figures["resident_kib"].items():
        print(
            f"{name}: resident {memory['start']} KiB at start, {memory['end']} at end, "
            f"max {memory['max']}"
        )
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / ("soak_quick.json" if args.quick else "soak.json")
    out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
