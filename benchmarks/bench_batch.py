"""Fleet throughput: tests identified per hour by ``dtid batch`` against the Dask workers.

Run from the repository root::

    PYTHONPATH=. python benchmarks/bench_batch.py [--tests 4] [--workers 1 2] [--quick]

Simulates ``--tests`` recordings of the reference vehicle (the default test: 5, 10 and 2 N*m,
60 s chirps; ``--quick``: 20 s chirps and a small search budget), each a test of its own, and
runs :func:`dtid.batch.run_batch` on a local cluster of each worker count (processes, one thread
each, numba on one thread per task), profiles off. Wall time from submitting to the table
written, cluster start included; tests per hour; the speed-up against one worker. Also what one
task carries: the bytes sent (recordings and options) and returned (the JSONs).

Writes ``benchmarks/results/batch.json``. A benchmark, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import datetime
import json
import pickle
import platform
import tempfile
import time
from pathlib import Path

from dtid.acquisition.plan import TestPlan
from dtid.batch import BatchOptions, find_tests, identify_test, run_batch, task_files
from dtid.cli import main as dtid
from dtid.identification.search.identify import SearchSettings

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    """Measure and print."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tests", type=int, default=4)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    duration = 20.0 if args.quick else TestPlan().duration_s
    settings = (
        SearchSettings(popsize=4, generations=4, polish_evaluations=60)
        if args.quick
        else SearchSettings()
    )
    options = BatchOptions(settings=settings, profile_points=0)
    figures = {}
    with tempfile.TemporaryDirectory() as folder:
        paths = []
        for index in range(args.tests):
            path = Path(folder) / "fleet" / f"test{index}.blf"
            path.parent.mkdir(exist_ok=True)
            dtid(["simulate", str(path), "--duration", f"{duration:g}", "--seed", str(index)])
            paths.append(path)
        tests = find_tests(paths)
        files, originals = task_files(tests[0], options)
        sent = len(pickle.dumps((tests[0].name, files, originals, options)))
        returned = len(pickle.dumps(identify_test(tests[0].name, files, originals, options)))
        for workers in args.workers:
            start = time.perf_counter()
            rows = run_batch(tests, options, Path(folder) / f"out{workers}", workers=workers)
            wall = time.perf_counter() - start
            assert all(r["status"] == "ok" for r in rows), rows
            figures[workers] = {
                "wall_s": wall,
                "tests_per_hour": 3600.0 * len(tests) / wall,
                "task_s": [r["seconds"] for r in rows],
            }
    one = figures.get(min(figures))
    print(f"{args.tests} tests, {duration:g} s chirps, sent {sent / 1e3:.0f} kB and returned "
          f"{returned / 1e3:.0f} kB per task")  # fmt: skip
    print("| workers | wall, s | tests/hour | speed-up | task, s (median) |")
    print("|---|---|---|---|---|")
    for workers, figure in figures.items():
        tasks = sorted(figure["task_s"])
        print(
            f"| {workers} | {figure['wall_s']:.0f} | {figure['tests_per_hour']:.0f} | "
            f"{one['wall_s'] / figure['wall_s']:.2f} | {tasks[len(tasks) // 2]:.0f} |"
        )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "batch.json").write_text(
        json.dumps(
            {
                "date": datetime.date.today().isoformat(),
                "host": platform.node(),
                "tests": args.tests,
                "chirp_s": duration,
                "bytes_sent_per_task": sent,
                "bytes_returned_per_task": returned,
                "workers": figures,
            },
            indent=2,
        )
        + "\n"
    )


if __name__ == "__main__":
    main()
