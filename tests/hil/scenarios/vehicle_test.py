"""Scenario: virtual vehicle, acquisition daemon and worker as separate processes on the HIL bus.

Run inside the namespace by :func:`hil.namespace.run_scenario` (``tests/hil/test_end_to_end.py``)::

    python tests/hil/scenarios/vehicle_test.py CONFIG WORKDIR [options]

It starts ``dtid vehicle`` (``--vehicle ARGS``), ``dtid worker --once`` at low priority
(``--worker ARGS``; ``--no-worker`` for none) and ``dtid acquire``; optionally kills the worker
(SIGKILL) when the daemon prints a line and starts a new one (``--restart-worker-at TEXT``), or
kills the daemon (SIGKILL) when it prints a line (``--kill-daemon-at TEXT``). When the daemon has
ended it stops the vehicle and prints one JSON line: exit statuses, the vehicle's report, the
session folder, the daemon's and worker's output.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import sys
import time
from pathlib import Path

from hil.processes import Processes

WORKER_NICE = 15
"""Niceness of the worker: its search must not delay the processes on the bus."""
BUS_PRIORITY = ["nice", "-n", "-5"] if os.geteuid() == 0 else []
"""Priority of vehicle and daemon (as a deployment would give the daemon): at 3x real time a
scheduling delay of 30 ms is 0.1 s of bus time. Even so (and as much under SCHED_FIFO) the
vehicle's frames were up to 60 ms late now and then while the worker searched, and came in a
burst: the analysis puts such bursts back on their crank slots
(dtid.identification.samples.late_frames)."""


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("config")
    parser.add_argument("workdir", type=Path)
    parser.add_argument("--vehicle", default="", help="further arguments of dtid vehicle")
    parser.add_argument("--worker", default="", help="further arguments of dtid worker")
    parser.add_argument("--no-worker", action="store_true")
    parser.add_argument("--restart-worker-at", help="daemon output line that triggers it")
    parser.add_argument("--kill-daemon-at", help="daemon output line that triggers it")
    parser.add_argument("--timeout", type=float, default=100.0, help="wall s for the daemon")
    args = parser.parse_args()
    report = args.workdir / "vehicle-report.json"
    summary: dict[str, object] = {}
    with Processes(args.workdir / "logs") as procs:
        dtid = [*BUS_PRIORITY, sys.executable, "-m", "dtid.cli"]
        vehicle = [*dtid, "vehicle", "--config", args.config, "--report", str(report)]
        procs.start("vehicle", [*vehicle, *shlex.split(args.vehicle)])
        # the worker's search leaves one core to the bus processes by itself
        worker = ["nice", "-n", str(WORKER_NICE), sys.executable, "-m", "dtid.cli", "worker"]
        worker += ["--config", args.config, "--once", *shlex.split(args.worker)]
        if not args.no_worker:
            procs.start("worker", worker)
        procs.start("acquire", [*dtid, "acquire", "--config", args.config, "--linger", "15"])
        if args.restart_worker_at:
            procs.wait_for_line("acquire", args.restart_worker_at, timeout=args.timeout)
            time.sleep(0.5)
            procs.signal("worker", signal.SIGKILL)
            procs.wait("worker", timeout=10)
            summary["worker_killed"] = True
            procs.start("worker-2", worker)
        if args.kill_daemon_at:
            procs.wait_for_line("acquire", args.kill_daemon_at, timeout=args.timeout)
            time.sleep(1.5)  # into the chirp, past a flush of the log
            procs.signal("acquire", signal.SIGKILL)
        summary["acquire"] = procs.wait("acquire", timeout=args.timeout)
        time.sleep(1.0)  # let the vehicle see the requests stop
        procs.signal("vehicle", signal.SIGTERM)
        summary["vehicle"] = procs.wait("vehicle", timeout=20)
        last_worker = "worker-2" if args.restart_worker_at else "worker"
        if not args.no_worker:
            summary["worker"] = procs.wait(last_worker, timeout=args.timeout)
            summary["worker_err"] = procs.errors(last_worker)[-3000:]
        summary["acquire_out"] = procs.output("acquire")
        summary["acquire_err"] = procs.errors("acquire")[-3000:]
        summary["vehicle_err"] = procs.errors("vehicle")[-2000:]
    summary["vehicle_report"] = json.loads(report.read_text()) if report.exists() else None
    sessions = sorted((args.workdir / "runs").glob("*/"))
    summary["session"] = str(sessions[-1]) if sessions else None
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
