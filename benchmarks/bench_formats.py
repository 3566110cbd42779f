"""Recording formats: time to write and to read the paper's test in each, and the file size.

Run from the repository root::

    PYTHONPATH=. python benchmarks/bench_formats.py [--repeats 3]

The recording is the reference vehicle's default test (5, 10 and 2 N*m, 60 s chirps, seed 0)
as :func:`dtid.simulator.vehicle_frames.simulation_frames` puts it on the bus. Per format:
:func:`dtid.acquisition.logfile.write_log` and :func:`dtid.acquisition.logfile.read_log` (wall
time, best of ``--repeats``), the file size, and python-can's own MF4 writer (one asammdf call
a frame) for comparison with the block writer of :mod:`dtid.acquisition.mf4`.

Prints a markdown table for docs/formats.md and writes ``benchmarks/results/formats.json``.
A benchmark, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import tempfile
import time
from pathlib import Path

import can

from dtid.acquisition.logfile import SUPPORTED_SUFFIXES, read_log, write_log
from dtid.acquisition.plan import TestPlan
from dtid.dbc.loader import load_interface
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.simulate import simulate
from dtid.simulator.vehicle_frames import simulation_frames

RESULTS = Path(__file__).resolve().parent / "results"


def _best(repeats: int, action) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        action()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    """Measure and print."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    result = simulate(reference_parameters(), TestPlan(), seed=0)
    frames = simulation_frames(result, load_interface())
    rows = {}
    with tempfile.TemporaryDirectory() as folder:
        for suffix in SUPPORTED_SUFFIXES:
            path = Path(folder) / f"test{suffix}"
            write_s = _best(args.repeats, lambda p=path: write_log(p, frames, overwrite=True))
            read_s = _best(args.repeats, lambda p=path: read_log(p))
            rows[suffix] = {
                "write_s": write_s,
                "read_s": read_s,
                "bytes": path.stat().st_size,
            }
        path = Path(folder) / "python-can.mf4"

        def python_can_mf4() -> None:
            with can.Logger(path) as writer:
                for frame in frames:
                    writer.on_message_received(frame)

        rows["python-can MF4Writer"] = {
            "write_s": _best(1, python_can_mf4),
            "read_s": None,
            "bytes": path.stat().st_size,
        }
    print(f"{len(frames)} frames, {frames[-1].timestamp - frames[0].timestamp:.0f} s of test")
    print("| format | write, s | read, s | size, kB | bytes/frame |")
    print("|---|---|---|---|---|")
    for name, row in rows.items():
        read = "-" if row["read_s"] is None else f"{row['read_s']:.2f}"
        print(
            f"| {name} | {row['write_s']:.2f} | {read} | {row['bytes'] / 1e3:.0f} | "
            f"{row['bytes'] / len(frames):.1f} |"
        )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "formats.json").write_text(
        json.dumps(
            {
                "date": datetime.date.today().isoformat(),
                "host": platform.node(),
                "frames": len(frames),
                "formats": rows,
            },
            indent=2,
        )
        + "\n"
    )


if __name__ == "__main__":
    main()
