"""``dtid vehicle``: the simulator as the vehicle's engine ECU on a CAN bus."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path
from threading import Event

from dtid.acquisition.bus import open_bus
from dtid.acquisition.config import load_config
from dtid.cli.commands.common import output_file, positive_float, seed, speedup
from dtid.dbc.loader import load_interface
from dtid.jsonfile import write_json
from dtid.simulator.controller import IdleController
from dtid.simulator.parameters import load_parameters, reference_parameters
from dtid.simulator.plant_stepper import PlantStepper
from dtid.simulator.simulate import SimulationOptions
from dtid.simulator.virtual_vehicle import BusFaults, SetpointStep, VirtualVehicle


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "vehicle",
        help="run the simulated vehicle as the engine ECU on a CAN bus",
        description="Run the numba plant as the vehicle's engine ECU on the configured bus: it "
        "accepts the tool's test-torque requests as the ECU does (checksum, alive counter, "
        "timeout), steps the plant and sends speed and torque frames per the DBC, in real time "
        "or faster by --speedup. Stops on SIGINT/SIGTERM or after --duration.",
    )
    parser.add_argument("--config", type=Path, help="configuration file (TOML; default: built-in)")
    parser.add_argument("--interface", help="python-can interface (overrides [bus])")
    parser.add_argument("--channel", help="bus channel (overrides [bus])")
    parser.add_argument(
        "--params", type=Path, help="parameter set (TOML; default: the reference vehicle)"
    )
    parser.add_argument(
        "--speedup",
        type=speedup,
        help="bus time per wall time (default: [bus] time_factor of the configuration)",
    )
    parser.add_argument("--duration", type=positive_float, help="bus seconds to run, then stop")
    parser.add_argument(
        "--setpoint", type=positive_float, default=IdleController().setpoint_rpm, help="idle rpm"
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of noise and combustion")
    parser.add_argument(
        "--clean", action="store_true", help="no combustion variation and no sensor noise"
    )
    faults = parser.add_argument_group("fault injection (for tests)")
    for name in ("drop", "duplicate", "corrupt"):
        faults.add_argument(
            f"--{name}", type=float, default=0.0, metavar="P", help=f"{name} each frame with P"
        )
    faults.add_argument(
        "--setpoint-step",
        type=float,
        nargs=2,
        metavar=("AT_S", "RPM"),
        help="move the idle set-point to RPM at bus time AT_S (drives the speed out of window)",
    )
    parser.add_argument("--report", type=output_file, help="write what the vehicle did as JSON")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run the subcommand."""
    config = load_config(args.config)
    overrides = {k: v for k, v in (("interface", args.interface), ("channel", args.channel)) if v}
    if overrides:
        config = config.with_changes("bus", **overrides)
    interface = load_interface(config.vehicle_interface.dbc, config.vehicle_interface.signals)
    parameters = load_parameters(args.params) if args.params else reference_parameters()
    controller = IdleController(setpoint_rpm=args.setpoint)
    options = (
        SimulationOptions.clean(controller=controller)
        if args.clean
        else SimulationOptions(controller=controller)
    )
    faults = BusFaults(args.drop, args.duplicate, args.corrupt, seed=args.seed)
    step = SetpointStep(*args.setpoint_step) if args.setpoint_step else None
    speedup = args.speedup or config.bus.time_factor
    stop = Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    with open_bus(config.bus) as bus:
        vehicle = VirtualVehicle(
            bus, interface, PlantStepper(parameters, options, args.seed), speedup, faults, step
        )
        print(
            f"virtual vehicle on {config.bus.interface}:{config.bus.channel}, "
            f"{speedup:g}x real time",
            file=sys.stderr,
            flush=True,
        )
        report = vehicle.run(args.duration, stop)
    print(json.dumps(report.as_dict()), file=sys.stderr)
    if args.report:
        write_json(args.report, report.as_dict())
    return 0
