"""``dtid demo``: the main job on built-in defaults, end to end, offline.

Simulates the reference vehicle's chirp test at two amplitudes, writes the CAN recording the bus
would carry, reads it back through the DBC and estimates the FRFs, and shows them: a summary on
the terminal, a plot and a JSON file in the output folder.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.logfile import write_log
from dbc.loader import load_interface
from dtid.commands.common import write_json
from dtid.commands.frf import summary_line
from dtid.errors import RecordingError
from identification.frf import estimate_frf
from identification.plots import plot_frf
from identification.recording import load_recording
from identification.runs import find_runs
from simulator.chirp import TestPlan
from simulator.linear import three_mass_modes
from simulator.parameters import reference_parameters
from simulator.simulate import simulate
from simulator.vehicle_frames import simulation_frames

DEMO_AMPLITUDES_NM = (2.0, 10.0)
"""A small and a large chirp: the DMF resonance moves between them (Fig. 3)."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "demo",
        help="simulate the reference vehicle's test and show its FRF (no vehicle needed)",
        description=__doc__,
    )
    parser.add_argument(
        "--out", type=Path, default=Path("dtid-demo"), help="output folder (default: %(default)s)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of noise and combustion")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Simulate, record, read back, estimate and show."""
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise RecordingError(
            f"cannot create the output folder {args.out}: {error.strerror}"
        ) from None
    parameters = reference_parameters()
    plan = TestPlan(amplitudes_nm=DEMO_AMPLITUDES_NM)
    interface = load_interface()
    low, high = three_mass_modes(parameters)
    print(
        f"reference vehicle: linear modes {low:.1f} and {high:.1f} Hz; simulating "
        f"{plan.end_s:.0f} s of chirp test at {', '.join(f'{a:g}' for a in plan.amplitudes_nm)}"
        " N*m ..."
    )
    result = simulate(parameters, plan, seed=args.seed)
    recording = args.out / f"reference-seed{args.seed}.blf"
    count = write_log(recording, simulation_frames(result, interface), overwrite=True)
    print(f"recording: {recording} ({count} frames)")
    data = load_recording(recording, interface).test_data()
    estimates = [estimate_frf(data, run) for run in find_runs(data.test_torque)]
    for estimate in estimates:
        print(summary_line(estimate))
    write_json(
        args.out / "frf.json",
        {"runs": [{"recording": str(recording), **e.as_dict()} for e in estimates]},
    )
    plot = plot_frf(estimates, args.out / "frf.png", "Reference vehicle, simulated (Fig. 3)")
    print(f"FRF: {args.out / 'frf.json'}, plot: {plot}")
    return 0
