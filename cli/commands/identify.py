"""``dtid identify``: the drivetrain's parameters from chirp recordings.

The two largest amplitudes identify and the others validate (the paper: 5 and 10 N*m identify,
2 N*m validates). Profiles of every free parameter give the 95 % intervals and say which
parameters the data pin down. One 60 s test at 5 and 10 N*m pins the inertias, stiffnesses and
the DMF play to a few per cent, but the gear play only to about 4-13 % and the DMF friction to
30-80 % (one standard deviation, simulated): read the intervals and the verdicts, not only the
values. Intervals wider than ``dtid plan``'s default targets are listed after them, with the
``dtid plan --after`` command that designs the follow-up test reaching them.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dtid.cli.commands.common import (
    ProgressBar,
    add_interface_options,
    add_vehicle_option,
    output_file,
    plot_file,
    positive_float,
    read_parameter_set,
    seed,
    vehicle_data,
)
from dtid.errors import ConfigError
from dtid.identification.pipeline import OPERATING_POINT, restart_finder
from dtid.identification.planning.design import DEFAULT_TARGETS_PERCENT, wider_than_targets
from dtid.identification.search.identify import SearchSettings
from dtid.identification.search.parameterization import (
    PRIOR_SPAN,
    THETA_NAMES,
    check_theta_value,
)
from dtid.identification.uncertainty.profile import MIN_POINTS
from dtid.simulator.parameters import reference_parameters
from dtid.workflow import identify


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "identify",
        help="identify the drivetrain parameters from chirp recordings",
        description=__doc__,
    )
    parser.add_argument("recordings", type=Path, nargs="+", metavar="RECORDING")
    parser.add_argument(
        "--fix",
        nargs="+",
        default=[],
        metavar="NAME=VALUE",
        help=f"hold parameters at values (SI units): {', '.join(THETA_NAMES + OPERATING_POINT)}",
    )
    add_identify_option(parser)
    add_bounds_options(parser)
    add_vehicle_option(parser)
    add_search_options(parser)
    parser.add_argument(
        "--compare",
        type=Path,
        metavar="FILE",
        help="a drivetrain to test against the identified one (a data sheet's, the design's, an "
        "earlier identification's): a parameter TOML as --prior takes or an identification "
        "JSON; says whether these recordings reject it",
    )
    parser.add_argument("--json", type=output_file, help="write the result as JSON")
    parser.add_argument(
        "--plot", type=plot_file, help="overlay measured and identified FRFs (Fig. 6)"
    )
    add_interface_options(parser)
    parser.set_defaults(run=run)


def add_identify_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--identify``: the amplitudes that identify (``dtid identify``, ``dtid diagnose``)."""
    parser.add_argument(
        "--identify",
        type=positive_float,
        nargs="+",
        metavar="NM",
        help="amplitudes that identify (default: the two largest); the others validate",
    )


def add_bounds_options(parser: argparse.ArgumentParser) -> None:
    """Add the prior and the search box (``dtid identify`` and ``dtid profile``)."""
    parser.add_argument(
        "--prior",
        type=Path,
        help="parameter set the bounds centre on: a TOML (the keys at its top level or in a "
        "vehicle file's [drivetrain]) or an identification JSON (default: the reference vehicle)",
    )
    parser.add_argument(
        "--span",
        type=positive_float,
        metavar="PERCENT",
        help="bounds of every free parameter: the prior +- this (default: the prior +- "
        f"{100 * PRIOR_SPAN:g} %%, widened to a passenger car's ranges)",
    )
    parser.add_argument(
        "--bounds",
        nargs="+",
        default=[],
        metavar="NAME=LOWER:UPPER",
        help="explicit bounds of parameters (SI units), overriding --span for them",
    )


def parse_bounds(items: list[str]) -> dict[str, tuple[float, float]]:
    """``NAME=LOWER:UPPER`` items to a dict, naming a wrong one (the values' order is checked
    by :meth:`dtid.identification.search.parameterization.Parameterization.around`)."""
    bounds = {}
    for item in items:
        name, sep, span = item.partition("=")
        lower, colon, upper = span.partition(":")
        try:
            if not (sep and colon and name in THETA_NAMES):
                raise ValueError
            ends = (float(lower), float(upper))
        except ValueError:
            raise ConfigError(
                f"--bounds {item!r}: expected NAME=LOWER:UPPER in SI units (e.g. c12=100:600) "
                f"with NAME one of {', '.join(THETA_NAMES)}"
            ) from None
        for end in ends:
            check_theta_value(name, end, f"--bounds {item}")
        bounds[name] = ends
    return bounds


def add_search_options(parser: argparse.ArgumentParser) -> None:
    """Add the search's seed and budget (``dtid identify`` and ``dtid worker``)."""
    defaults = SearchSettings()
    parser.add_argument("--seed", type=seed, default=defaults.seed, help="seed of the search")
    parser.add_argument(
        "--generations",
        type=int,
        default=defaults.generations,
        help="differential evolution generations (default: %(default)s)",
    )
    parser.add_argument(
        "--popsize",
        type=int,
        default=defaults.popsize,
        help="differential evolution population per free parameter (default: %(default)s)",
    )
    parser.add_argument(
        "--polish-evaluations",
        type=int,
        default=defaults.polish_evaluations,
        help="objective evaluations of each Nelder-Mead polish (default: %(default)s)",
    )
    parser.add_argument(
        "--single-start",
        action="store_true",
        help="polish and finish the evolution's best member alone, without the gear coupling's "
        "scan and the gear play's check: about half the time, but it ends in whichever basin "
        "that member lies (not for a result to report)",
    )
    parser.add_argument(
        "--profile-points",
        type=int,
        default=5,
        help="grid points per profile; 0 skips intervals and verdicts (default: %(default)s)",
    )


def search_settings(args: argparse.Namespace) -> SearchSettings:
    """The search settings of :func:`add_search_options`; a budget below 1 is refused."""
    for option in ("generations", "popsize", "polish_evaluations"):
        if getattr(args, option) < 1:
            raise ConfigError(f"--{option.replace('_', '-')} must be at least 1")
    if args.profile_points < 0 or 0 < args.profile_points < MIN_POINTS:
        raise ConfigError(
            f"--profile-points must be 0 (no profiles) or at least {MIN_POINTS} (a profile's "
            "minimum and a point on each side)"
        )
    settings = SearchSettings(
        popsize=args.popsize,
        generations=args.generations,
        polish_evaluations=args.polish_evaluations,
        seed=args.seed,
    )
    return settings.single_start() if args.single_start else settings


def print_report(
    document: Mapping[str, Any], fixed: Mapping[str, float], follow_up: str | None = None
) -> None:
    """The identified parameters, intervals, verdicts and NRMSEs of a result on the terminal.

    ``follow_up`` is the ``dtid plan`` command that designs the test reaching the targets the
    intervals miss (:func:`wide_intervals`); printed after them where some do.
    """
    edges = document.get("at_bounds", {})  # a document of an earlier version has none
    for name, value in document["parameters"].items():
        interval = document["intervals"].get(name)
        verdict = document["identifiable"].get(name, "fixed" if name in fixed else "")
        if name in edges:
            verdict = f"{verdict} (at the search box's {edges[name]['side']} end)".lstrip()
        span = ""
        if interval:
            lo, hi = interval["lower"], interval["upper"]
            span = (
                f"[{'-inf' if lo is None else f'{lo:.4g}'}, {'inf' if hi is None else f'{hi:.4g}'}]"
            )
        print(f"{name:>6} = {value:<12.5g} {span:<26} {verdict}")
    for note in dict.fromkeys(document["identifiability_notes"].values()):
        print(f"not identifiable: {note}")
    wide = wide_intervals(document)
    if wide:
        print(f"wider than dtid plan's default targets (95 % interval, % of the value): {wide}")
        if follow_up:
            print(f"the follow-up test that reaches them: {follow_up}")
    elif not (
        document["intervals"]
        or document.get("profiles")
        or document.get("target_tests")  # a campaign round's target tests say what it reaches
        or set(THETA_NAMES) <= set(fixed)  # nothing searched
    ):
        print(unprofiled_note(follow_up))
    for role, values in document["nrmse"].items():
        for label, value in values.items():
            print(f"NRMSE {role:<10} {label}: {value:.3f}")
    for name, value in document["combustion_variation"].items():
        loop = document["idle_loop"].get(name, {})
        if "combustion_variation" in fixed:
            source = "fixed"
        elif loop.get("torque_noise_nm") is not None:
            source = f"the torque sensor's {loop['torque_noise_nm']:.2f} N*m of noise told apart"
        else:
            source = "the idle scatter; a model driven by the measured torque adds none"
        print(f"combustion variation of {name}: {value:.4f} ({source})")
    for name, loop in document["idle_loop"].items():
        detail = (
            f"the stroke takes the request {loop['latch_events']} crank events before its "
            f"report, K {loop['latch_gain']:.3f}, residual {loop['latch_residual_nm']:.2f} N*m"
            if loop["mode"] == "recorded_request"
            else "no torque request recorded"
        )
        print(
            f"idle loop of {name}: model driven by the {loop['mode'].replace('_', ' ')} ({detail})"
        )
    restart = document.get("search_restart")
    if restart:
        outcome = "the estimate is the restart's" if restart["adopted"] else "no better; kept"
        # identification JSON files before 2026-12-08 have no found_by: a profile's
        held = restart_finder(restart.get("found_by", "profile"), restart["parameter"])
        print(
            f"search restarted where {held} fitted better: eq. "
            f"(17) {restart['objective_search']:.4f} -> {restart['objective_restart']:.4f} "
            f"({outcome})"
        )
    print(f"{document['parameter_sets']} parameter sets simulated in {document['seconds']:.0f} s")


def unprofiled_note(follow_up: str | None) -> str:
    """What a result without profiles (``--profile-points 0``) lacks, and the two ways to get it
    (``follow_up``: the ``dtid plan`` command of :func:`follow_up_command`, None: not given).

    Without intervals nothing says which values the recordings pin: on the independent
    vehicle_1 the search put J3 +18 % and c23 +15 % off the truth where its profiles' intervals
    run -48/+35 % for c23 and ``dtid plan --after`` predicts 25 % and 26 % at 2 sigma for J3
    and c23; on a random vehicle like it the search closed the gear play (eq. 17 0.0889), which
    the profile of c23, and now the gear play's own check
    (:mod:`dtid.identification.uncertainty.gear_play`), restart at 0.0737, the truth's basin
    (docs/accuracy.md).
    """
    note = (
        "no intervals (--profile-points 0): these values come without their precision, and in a "
        "flat valley of eq. (17) some may lie far from the vehicle's; the default profiles give "
        "each parameter's 95 % interval and verdict, and restart the search where one fits better"
    )
    if follow_up:
        note += f", and the precision these recordings reach is predicted by {follow_up}"
    return note


def wide_intervals(document: Mapping[str, Any]) -> str:
    """The intervals of a result that reach past ``dtid plan``'s default targets, one phrase
    each (``c23 -51.4/+27 (target 5)``, ``Tc12 open (target 20)``); empty where none does."""
    intervals = {
        name: (interval["lower"], interval["upper"])
        for name, interval in document["intervals"].items()
        if interval
    }
    phrases = []
    for name, ends in wider_than_targets(document["parameters"], intervals).items():
        if ends == (None, None):
            span = "open"
        else:
            span = "/".join("open" if end is None else f"{end:+.3g}" for end in ends)
        phrases.append(f"{name} {span} (target {DEFAULT_TARGETS_PERCENT[name]:g})")
    return ", ".join(phrases)


def follow_up_command(args: argparse.Namespace) -> str:
    """The ``dtid plan`` command that plans a follow-up to these recordings at this result."""
    result = str(args.json) if args.json else "ID.json"
    words = ["dtid plan", "--prior", result, "--after", *map(str, args.recordings)]
    for option in ("dbc", "signals", "vehicle"):
        if getattr(args, option, None):
            words += [f"--{option}", str(getattr(args, option))]
    command = " ".join(words)
    return command if args.json else f"{command} (with this result written by --json ID.json)"


def parse_fixed(items: list[str]) -> dict[str, float]:
    """``NAME=VALUE`` pairs to a dict, naming a wrong one."""
    fixed = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or name not in THETA_NAMES + OPERATING_POINT:
            raise ConfigError(
                f"--fix {item!r}: expected NAME=VALUE with NAME one of "
                f"{', '.join(THETA_NAMES + OPERATING_POINT)}"
            )
        try:
            value = float(text)
        except ValueError:
            raise ConfigError(f"--fix {item!r}: {text!r} is not a number") from None
        if name in THETA_NAMES:
            check_theta_value(name, value, f"--fix {item}")
        elif not (math.isfinite(value) and value >= 0):
            raise ConfigError(f"--fix {item!r}: the value must be a finite number >= 0")
        elif name == "K" and value == 0:
            raise ConfigError(f"--fix {item!r}: the engine gain K must be > 0")
        if name in fixed:
            raise ConfigError(f"--fix gives {name} twice ({fixed[name]:g}, {text}): give it once")
        fixed[name] = value
    return fixed


def fixed_and_bounds(
    args: argparse.Namespace,
) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """``--fix`` and ``--bounds`` parsed; a parameter in both is refused (its bounds would be
    ignored without a word)."""
    fixed, bounds = parse_fixed(args.fix), parse_bounds(args.bounds)
    both = sorted(set(fixed) & set(bounds))
    if both:
        raise ConfigError(
            f"{both[0]} is both held (--fix) and searched within bounds (--bounds): give one"
        )
    return fixed, bounds


def run(args: argparse.Namespace) -> int:
    """Identify, print the result, write JSON and plot as asked."""
    fixed, bounds = fixed_and_bounds(args)
    settings = search_settings(args)
    prior = read_parameter_set(args.prior, "--prior")[0] if args.prior else reference_parameters()
    compared = read_parameter_set(args.compare, "--compare")[0] if args.compare else None
    vehicle = vehicle_data(args)
    bar = ProgressBar()
    report = identify(
        args.recordings,
        dbc=args.dbc,
        signals=args.signals,
        vehicle=vehicle,
        prior=prior,
        fixed=fixed,
        bounds=bounds,
        span=None if args.span is None else args.span / 100,
        identify_amplitudes=args.identify,
        settings=settings,
        profile_points=args.profile_points,
        progress=bar,
    )
    bar.finish()
    if compared is not None:
        report = report.compared(compared, str(args.compare))
    print_report(report.as_dict(), fixed, follow_up_command(args))
    print(vehicle.describe())
    if report.comparison is not None:
        print(report.comparison.sentence())
    if args.json:
        report.to_json(args.json)
    if args.plot:
        report.plot(args.plot)
        print(f"plot: {args.plot}")
    return 0
