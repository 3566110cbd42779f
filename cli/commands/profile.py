"""``dtid profile``: likelihood profiles (section IV-B, Fig. 5) of a setup or of recordings.

``--setup 1..4`` simulates the paper's identification setups on the reference vehicle (clean data,
bounds +-100 % of the truth) and profiles every free parameter; with recordings instead, the
parameters are identified first and profiled around the optimum.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from dtid.cli.commands.common import (
    add_interface_options,
    add_vehicle_option,
    output_file,
    plot_file,
    read_parameter_set,
    seed,
    vehicle_data,
)
from dtid.cli.commands.identify import add_bounds_options, fixed_and_bounds
from dtid.errors import ConfigError
from dtid.identification.pipeline import run_identification
from dtid.identification.setups import profile_setup, setup
from dtid.identification.uncertainty.profile import MIN_POINTS
from dtid.jsonfile import write_json
from dtid.simulator.parameters import reference_parameters
from dtid.workflow import measured_tests


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "profile",
        help="likelihood profiles of a setup or of recordings (Fig. 5)",
        description=__doc__,
    )
    parser.add_argument("recordings", type=Path, nargs="*", metavar="RECORDING")
    parser.add_argument("--setup", type=int, choices=(1, 2, 3, 4), help="paper's setup")
    parser.add_argument("--points", type=int, default=7, help="grid points (default: 7)")
    parser.add_argument("--fix", nargs="+", default=[], metavar="NAME=VALUE")
    add_bounds_options(parser)
    add_vehicle_option(parser)
    parser.add_argument("--seed", type=seed, default=0)
    parser.add_argument("--json", type=output_file, help="write the profiles as JSON")
    parser.add_argument("--plot", type=plot_file, help="plot the profiles")
    add_interface_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Profile and report."""
    if args.setup is None and not args.recordings:
        raise ConfigError("give --setup 1..4 (the paper's plant) or recordings to profile")
    if args.setup is not None and args.recordings:
        raise ConfigError("give either --setup 1..4 or recordings to profile, not both")
    if args.points < MIN_POINTS:
        raise ConfigError(f"--points must be at least {MIN_POINTS}")
    if args.setup is not None:
        profiles = profile_setup(setup(args.setup), points=args.points, seed=args.seed)
        title = f"Setup {args.setup}"
    else:
        fixed, bounds = fixed_and_bounds(args)
        tests = measured_tests(args.recordings, args.dbc, args.signals, vehicle_data(args))
        report = run_identification(
            tests,
            read_parameter_set(args.prior, "--prior")[0] if args.prior else reference_parameters(),
            fixed=fixed,
            bounds=bounds,
            span=None if args.span is None else args.span / 100,
            profile_points=args.points,
        )
        profiles = dict(report.profiles)
        title = "Profiles around the identified parameters"
    for name, prof in profiles.items():
        left, right = prof.rise
        print(f"{name:>6}: {prof.verdict:<10} rise left {left:.3f}, right {right:.3f}")
    for note in dict.fromkeys(prof.note for prof in profiles.values() if prof.note):
        print(f"not identifiable: {note}")
    if args.json:
        write_json(args.json, {name: prof.as_dict() for name, prof in profiles.items()})
    if args.plot:
        from dtid.identification.plots import plot_profiles

        plot_profiles(profiles, args.plot, title)
        print(f"plot: {args.plot}")
    return 0
