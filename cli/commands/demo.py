"""``dtid demo``: the whole product on a virtual bus with the reference vehicle.

The virtual vehicle (the numba plant as engine ECU), the acquisition daemon and the worker run
together, faster than real time, on python-can's in-process ``virtual`` bus: the daemon runs the
chirp test (the plan ``dtid plan`` recommends for the reference vehicle when it fits the demo's
few minutes, else the paper's: 5 and 10 N*m identify, 2 N*m validates; or a plan file) and
records the raw log, the worker estimates the FRFs and identifies the parameters while the
validation chirp runs. The demo ends with the identified parameters beside the reference
vehicle's true ones, the FRF plot (Fig. 3) and the fit (Fig. 6), all in the output folder.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import shutil
import signal
import sys
import tempfile
import threading
from dataclasses import replace
from pathlib import Path

from dtid.acquisition.bus import open_bus
from dtid.acquisition.config import (
    AcquisitionConfig,
    BusConfig,
    OutputConfig,
    PipelineConfig,
    SafetyConfig,
)
from dtid.acquisition.daemon import Daemon
from dtid.acquisition.plan import TestPlan, plan_from_file
from dtid.cli import EXIT_INTERRUPTED
from dtid.cli.commands.common import seed, speedup
from dtid.cli.commands.frf import summary_line
from dtid.dbc.loader import load_interface
from dtid.errors import AnalysisError, RecordingError
from dtid.identification.frf.closed_loop import estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.html_report import REPORT_FILE
from dtid.identification.planning.design import DEFAULT_TARGETS_PERCENT, plan_test
from dtid.identification.plots import plot_frf
from dtid.identification.samples.recording import load_recording
from dtid.identification.search.identify import SearchSettings
from dtid.identification.search.parameterization import theta_from_parameters
from dtid.identification.service.worker import Worker, WorkerOptions, leave_a_core_to_the_bus
from dtid.jsonfile import write_json
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.plant_stepper import PlantStepper
from dtid.simulator.virtual_vehicle import VirtualVehicle

DEFAULT_SPEEDUP = 3.0
"""Bus time per wall time of the demo: the 192 s test takes about 64 s. Faster is worse on a
2-core laptop: while the worker searches, the host now and then stalls the demo's process for
50-100 ms of wall time; at 5x that is up to 0.5 s of bus time, which the vehicle's 50 ms request
timeout and the chirp itself do not survive (seen here: the 2 N*m chirp cut in two)."""
VEHICLE_TIMEOUT_WALL_S = 0.2
"""The daemon's vehicle timeout in the demo, wall s (bus time: times the speedup). A vehicle on a
real bus gets 0.2 s of bus time; the demo's vehicle shares a busy laptop with the search, and a
host stall of 40-100 ms (seen here) would otherwise abort the test."""
WORKER_NICE = 10
"""Scheduling niceness of the worker, so its search never delays the bus processes."""
WORKER_STOP_S = 10.0
"""How long an interrupted or failed demo waits for its worker to end, s, before stopping it."""
TEST_BUDGET_S = 120.0
"""Wall time the demo's chirp test may take at its speedup, s: with the identification, whose
time grows with the test's, the demo then stays within five minutes on a 2-core laptop. The
plan ``dtid plan`` recommends for the reference vehicle runs when it fits, else the paper's."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "demo",
        help="run vehicle, daemon and worker on a virtual bus with the reference vehicle",
        description=__doc__,
    )
    parser.add_argument(
        "--out", type=Path, default=Path("dtid-demo"), help="output folder (default: %(default)s)"
    )
    parser.add_argument(
        "--speedup",
        type=speedup,
        default=DEFAULT_SPEEDUP,
        help="bus time per wall time (default: %(default)s)",
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of the vehicle's noise")
    parser.add_argument(
        "--plan",
        type=Path,
        help="run this dtid plan JSON's test (default: the plan dtid plan recommends for the "
        f"reference vehicle when it runs within {TEST_BUDGET_S:g} s at the speedup, else the "
        "paper's)",
    )
    parser.add_argument(
        "--generations",
        type=int,
        default=SearchSettings().generations,
        help="differential evolution generations of the identification (default: %(default)s)",
    )
    parser.set_defaults(run=run)


def _serve_worker(pipeline: PipelineConfig, options: WorkerOptions) -> None:
    """The worker process: one session, at low priority, one core left to the bus. A Ctrl-C
    is the daemon's to handle (it aborts the test and ends the session, which ends the
    worker); here it had printed the worker's traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.nice(WORKER_NICE)
    leave_a_core_to_the_bus()
    Worker(pipeline, options).serve(once=True)


def run(args: argparse.Namespace) -> int:
    """Run the three on a virtual bus and show what the worker identified."""
    if args.out.exists() and not args.out.is_dir():
        raise RecordingError(f"{args.out} is a file, not a folder: give a folder for the demo")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise RecordingError(
            f"cannot create the output folder {args.out}: {error.strerror}"
        ) from None
    if args.generations < 1:
        raise AnalysisError("--generations must be at least 1")
    test = plan_from_file(args.plan) if args.plan else _default_plan(args.speedup)
    runtime = Path(tempfile.mkdtemp(prefix="dtid-demo-"))
    config = AcquisitionConfig(
        test=test,
        bus=BusConfig(
            interface="virtual", channel=f"dtid-demo-{os.getpid()}", time_factor=args.speedup
        ),
        safety=SafetyConfig(vehicle_timeout_s=VEHICLE_TIMEOUT_WALL_S * args.speedup),
        output=OutputConfig(directory=args.out),
        pipeline=PipelineConfig(
            blocks=f"ipc://{runtime}/blocks",
            replay=f"ipc://{runtime}/replay",
            results=f"ipc://{runtime}/results",
        ),
    )
    truth = reference_parameters()
    options = WorkerOptions(
        settings=replace(SearchSettings(), generations=args.generations), profile_points=0
    )
    worker = multiprocessing.get_context("spawn").Process(
        target=_serve_worker, args=(config.pipeline, options), name="dtid-worker"
    )
    worker.start()
    stop = threading.Event()
    # the virtual bus keeps the vehicle's own time stamps (each frame's due time), so a frame
    # the shared interpreter sends late still carries its time on the crank-angle grid
    vehicle_bus = open_bus(replace(config.bus, options={"preserve_timestamps": True}))
    vehicle = VirtualVehicle(
        vehicle_bus, load_interface(), PlantStepper(truth, seed=args.seed), args.speedup
    )
    vehicle_thread = threading.Thread(target=vehicle.run, kwargs={"stop": stop}, daemon=True)
    vehicle_thread.start()
    plan = config.test
    print(
        f"reference vehicle on a virtual bus at {args.speedup:g}x real time: "
        f"{plan.end_s:.0f} s of chirp test "
        f"({', '.join(f'{a:g}' for a in sorted(set(plan.amplitudes_nm)))} N*m identify, "
        f"{plan.validation_nm:g} N*m validates)",
        flush=True,
    )
    try:
        try:
            result = Daemon(config, report=lambda line: print(line, flush=True)).run()
        finally:
            stop.set()
            vehicle_thread.join()
            vehicle_bus.shutdown()
        if result.reason == "signal":
            print(f"interrupted; the recording is kept in {result.session_dir}", file=sys.stderr)
            return EXIT_INTERRUPTED
        print("waiting for the worker's identification ...", flush=True)
        worker.join()
    finally:
        worker.join(WORKER_STOP_S)  # ended with its session; not if the daemon failed
        if worker.is_alive():
            worker.terminate()
        shutil.rmtree(runtime, ignore_errors=True)
    if result.status != "completed":
        raise AnalysisError(f"the demo's test was aborted ({result.reason})")
    identification = result.log_path.with_name("identification.json")
    if worker.exitcode != 0 or not identification.exists():
        raise AnalysisError(f"the worker did not identify (exit status {worker.exitcode})")
    _show(identification, {**truth.as_dict(), **theta_from_parameters(truth)})
    _plot_frf(result.log_path, args.out)
    print(f"report (one HTML page to forward): {result.session_dir / REPORT_FILE}")
    return 0


def _default_plan(speedup: float) -> TestPlan:
    """The recommended plan for the reference vehicle if it fits :data:`TEST_BUDGET_S`, else
    the paper's; says which and why."""
    _, recommendation = plan_test(reference_parameters(), DEFAULT_TARGETS_PERCENT, SafetyConfig())
    design = recommendation.design
    plan = design.test_plan()
    chirps = " + ".join(
        f"{n} x {a:g}" for a, n in zip(design.amplitudes_nm, design.repeats, strict=True)
    )
    described = f"{chirps} N*m, {design.duration_s:g} s chirps, {plan.end_s / 60:.1f} min"
    if plan.end_s / speedup <= TEST_BUDGET_S:
        print(f"running the plan dtid plan recommends for the reference vehicle: {described}")
        return plan
    print(
        f"dtid plan recommends {described} for the reference vehicle's targets; at "
        f"{speedup:g}x that is {plan.end_s / speedup / 60:.1f} min of bus before its "
        "identification, too long for this demo: running the paper's plan instead "
        "(dtid plan --json plan.json, then dtid demo --plan plan.json runs the recommended one)",
        flush=True,
    )
    return TestPlan()


def _show(identification: Path, truth: dict[str, float]) -> None:
    """The identified parameters beside the truth."""
    document = json.loads(identification.read_text())
    print(f"\nidentified ({identification}):")
    print(f"{'':>6}   {'identified':>12} {'truth':>12} {'error':>8}")
    for name, value in document["parameters"].items():
        true = truth.get(name)
        error = f"{100 * (value - true) / true:+7.1f}%" if true else ""
        shown = f"{true:.5g}" if true is not None else ""
        print(f"{name:>6}   {value:>12.5g} {shown:>12} {error:>8}")
    for role, values in document["nrmse"].items():
        for label, value in values.items():
            print(f"NRMSE {role} {label}: {value:.3f}")


def _plot_frf(log_path: Path, out: Path) -> None:
    """FRFs of the recorded test as Fig. 3, from the daemon's own log."""
    interface = load_interface()
    data = load_recording(log_path, interface).test_data()
    estimates = [estimate_frf(data, run) for run in find_runs(data.test_torque)]
    for estimate in estimates:
        print(summary_line(estimate))
    write_json(
        out / "frf.json",
        {"runs": [{"recording": str(log_path), **e.as_dict()} for e in estimates]},
    )
    plot = plot_frf(estimates, out / "frf.png", "Reference vehicle on a virtual bus (Fig. 3)")
    print(
        f"FRF: {out / 'frf.json'}, plot: {plot}; fit (Fig. 6): "
        f"{log_path.with_name('identification.png')}"
    )
