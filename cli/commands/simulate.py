"""``dtid simulate``: run a chirp test on the simulator and write the CAN recording."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from dtid.acquisition.logfile import write_log
from dtid.acquisition.metadata import session_metadata
from dtid.acquisition.plan import TestPlan, plan_from_file, planned_setpoint
from dtid.cli.commands.common import (
    add_interface_options,
    add_vehicle_option,
    new_file,
    positive_float,
    seed,
)
from dtid.dbc.loader import load_interface
from dtid.errors import ConfigError
from dtid.simulator.controller import IdleController
from dtid.simulator.mechanisms import BY_NAME, Effects, parse_effect
from dtid.simulator.parameters import (
    VEHICLE_TABLES,
    load_parameters,
    read_toml,
    reference_parameters,
)
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_data import VehicleData, load_vehicle_data
from dtid.simulator.vehicle_frames import simulation_frames

_DEFAULTS = TestPlan()
VALIDATION_LAST = (5.0, 10.0, 2.0)
"""The default chirps: the two that identify, then the one that validates (the acquisition
daemon's order), so that nothing before the identification runs is validation data."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a chirp test and write the CAN recording",
        description="Simulate the chirp test on the numba plant and write the frames the vehicle "
        "bus would carry (.blf, .asc, candump .log, .mf4, .trc or .csv by the file's suffix), "
        "timestamps in simulated time, with its metadata (docs/formats.md).",
    )
    parser.add_argument(
        "output", type=new_file, help="recording to write (.blf, .asc, .log, .mf4, .trc or .csv)"
    )
    parser.add_argument(
        "--params", type=Path, help="parameter set (TOML; default: the reference vehicle)"
    )
    parser.add_argument(
        "--amplitudes",
        type=positive_float,
        nargs="+",
        default=list(VALIDATION_LAST),
        metavar="NM",
        help="chirp amplitudes in N*m, one chirp each (default: %(default)s)",
    )
    parser.add_argument("--f1", type=positive_float, default=_DEFAULTS.f1_hz, help="start Hz")
    parser.add_argument("--f2", type=positive_float, default=_DEFAULTS.f2_hz, help="end Hz")
    parser.add_argument(
        "--duration", type=positive_float, default=_DEFAULTS.duration_s, help="seconds per chirp"
    )
    parser.add_argument(
        "--setpoint",
        type=positive_float,
        default=IdleController().setpoint_rpm,
        help="idle speed set-point, rpm",
    )
    parser.add_argument(
        "--plan",
        type=Path,
        help="simulate the test of a dtid plan JSON file (its amplitudes, repeats, duration, "
        "band and validation chirp; instead of --amplitudes, --f1, --f2, --duration)",
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of noise and combustion")
    parser.add_argument(
        "--clean", action="store_true", help="no combustion variation and no sensor noise"
    )
    parser.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME[:k=v,...]",
        help="conceal a mechanism beyond the paper's model (repeatable): "
        f"{', '.join(BY_NAME)}; e.g. progressive_spring:c12_2=600,knee12=0.008 (SI units; "
        "the main parameter defaults to the middle of its typical range)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing recording")
    add_vehicle_option(parser)
    add_interface_options(parser)
    parser.set_defaults(run=run)


SETPOINT_TOLERANCE = 0.05
"""A plan's idle speed and the simulated vehicle's differing by more than this share are
named: the plan's precision was predicted at its own idle speed."""


def run(args: argparse.Namespace) -> int:
    """Simulate and write the recording."""
    parameters = load_parameters(args.params) if args.params else reference_parameters()
    if args.plan is not None:
        given = [
            option
            for option, value, default in (
                ("--amplitudes", args.amplitudes, list(VALIDATION_LAST)),
                ("--f1", args.f1, _DEFAULTS.f1_hz),
                ("--f2", args.f2, _DEFAULTS.f2_hz),
                ("--duration", args.duration, _DEFAULTS.duration_s),
            )
            if value != default
        ]
        if given:
            raise ConfigError(f"{given[0]} and --plan both set the test: give one of them")
        plan = plan_from_file(args.plan)
        planned = planned_setpoint(args.plan)
        if planned is not None and abs(planned - args.setpoint) > SETPOINT_TOLERANCE * planned:
            print(
                f"note: {args.plan} was planned for a vehicle idling at {planned:g} rpm; this "
                f"one idles at {args.setpoint:g} rpm (--setpoint {planned:g} simulates the "
                "vehicle it was planned for)"
            )
    else:
        plan = TestPlan(
            amplitudes_nm=tuple(args.amplitudes),
            validation_nm=0.0,
            f1_hz=args.f1,
            f2_hz=args.f2,
            duration_s=args.duration,
        )
    controller = IdleController(setpoint_rpm=args.setpoint)
    named = [text.partition(":")[0].strip() for text in args.effect]
    again = sorted({name for name in named if named.count(name) > 1})
    if again:
        raise ConfigError(
            f"--effect {again[0]} is given more than once: give each mechanism once, its "
            "parameters together (NAME:k=v,k=v)"
        )
    effects = Effects({k: v for text in args.effect for k, v in parse_effect(text).items()})
    options = (
        SimulationOptions.clean(controller=controller, effects=effects)
        if args.clean
        else SimulationOptions(controller=controller, effects=effects)
    )
    vehicle = simulated_vehicle(args.vehicle, args.params)
    if vehicle is not None:
        options = vehicle.simulated(options)
    interface = load_interface(args.dbc, args.signals)
    result = simulate(parameters, plan, options, seed=args.seed)
    metadata = session_metadata(
        session=args.output.stem,
        started_s=time.time(),
        source=f"dtid simulate (seed {args.seed})",
        interface=interface,
        plan=plan.as_dict(),
    )
    count = write_log(
        args.output,
        simulation_frames(result, interface),
        overwrite=args.force,
        metadata=metadata,
    )
    if vehicle is not None:
        print(vehicle.describe())
    print(
        f"wrote {args.output}: {count} frames, {plan.end_s:.0f} s, chirps at "
        f"{', '.join(f'{a:g}' for a in plan.levels)} N*m"
    )
    return 0


def simulated_vehicle(vehicle: Path | None, params: Path | None) -> VehicleData | None:
    """The vehicle data the plant is simulated with: ``--vehicle``'s, else those of a
    ``--params`` vehicle file that has ``[engine]``, ``[sensors]`` or ``[model]`` (one file for
    one vehicle; they were ignored without a word), else None (the reference engine)."""
    if vehicle is not None:
        return load_vehicle_data(vehicle)
    if params is not None and any(t in read_toml(params, "parameter file") for t in VEHICLE_TABLES):
        return load_vehicle_data(params)
    return None
