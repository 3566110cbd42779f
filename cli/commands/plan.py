"""``dtid plan``: the shortest chirp test that reaches the precision asked for."""

from __future__ import annotations

import argparse
import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from dtid.acquisition.config import load_config
from dtid.acquisition.plan import MAX_TEST_S
from dtid.cli.commands.common import (
    add_interface_options,
    add_vehicle_option,
    at_most,
    is_identification,
    non_negative_float,
    output_file,
    plot_file,
    positive_float,
    read_identification,
    read_parameter_set,
    vehicle_data,
)
from dtid.errors import ConfigError
from dtid.identification.planning.design import (
    DEFAULT_MAX_TIME_S,
    PRECISION_NAMES,
    SIGMAS,
    VALIDATION_NM,
    Design,
    parse_targets,
    plan_test,
    recorded_designs,
)
from dtid.identification.planning.document import plan_document
from dtid.identification.planning.information import DEFAULT_SEEDS
from dtid.identification.planning.spread import (
    DEFAULT_SPREAD_PERCENT,
    DEFAULT_VEHICLES,
    MAX_SPREAD,
    RECORDED,
    describe,
)
from dtid.jsonfile import write_json
from dtid.simulator.controller import IdleController
from dtid.simulator.parameters import (
    DrivetrainParameters,
    reference_parameters,
)
from dtid.simulator.simulate import SimulationOptions
from dtid.simulator.vehicle_data import VehicleData
from dtid.workflow import measured_tests

logger = logging.getLogger(__name__)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "plan",
        help="design the shortest chirp test that meets precision targets",
        description="Predict each parameter's precision for a chirp test from eq. (17)'s "
        "linearised information at a prior (simulated with noise and the model's own Monte "
        "Carlo scatter) and search the shortest test (two amplitudes, repeats, chirp duration, "
        f"band) that meets every target at {SIGMAS:g} sigma, at the prior and at vehicles drawn "
        "around it (--spread). Targets it cannot meet within the limits are listed with what "
        "would meet them. See docs/planning.md.",
    )
    parser.add_argument(
        "--prior",
        type=Path,
        help="parameters to plan for: a parameter set (TOML: the keys at its top level or in a "
        "vehicle file's [drivetrain]) or a dtid identify JSON (its parameters; default: the "
        "reference vehicle)",
    )
    parser.add_argument(
        "--after",
        type=Path,
        nargs="+",
        default=[],
        metavar="RECORDING",
        help="plan a follow-up to these recordings: their identifying runs count in, the new "
        "test's time only is minimised, the idle speed is theirs (give --prior their "
        "identification's JSON: its profile intervals then confirm the targets the prediction "
        "says are met)",
    )
    parser.add_argument(
        "--target",
        nargs="+",
        default=[],
        metavar="NAME=PERCENT",
        help=f"precision targets at {SIGMAS:g} sigma over the defaults (inertias, mass ratios, "
        "stiffnesses, free plays 5 %%; dampings, friction 20 %%); NAME=0 drops one; names: "
        + ", ".join(PRECISION_NAMES),
    )
    parser.add_argument(
        "--setpoint",
        type=positive_float,
        metavar="RPM",
        help="the vehicle's idle speed, rpm: the mean torque's Nyquist frequency (rpm/60 Hz "
        f"for four cylinders) caps the band (default: --after's, else "
        f"{IdleController().setpoint_rpm:g})",
    )
    parser.add_argument(
        "--config",
        type=Path,
        help="daemon configuration whose [safety] caps the amplitude and the speed excursion",
    )
    parser.add_argument(
        "--max-amplitude",
        type=positive_float,
        metavar="NM",
        help="largest test torque amplitude, N*m (default: [safety] max_amplitude_nm)",
    )
    parser.add_argument(
        "--max-time",
        type=at_most(MAX_TEST_S, "a test at idle may take at most that long", " s"),
        default=DEFAULT_MAX_TIME_S,
        metavar="S",
        help=f"longest whole test, s (default: {DEFAULT_MAX_TIME_S:g})",
    )
    parser.add_argument(
        "--validation",
        type=non_negative_float,
        metavar="NM",
        help=f"validation chirp amplitude, N*m; 0 for none (default: {VALIDATION_NM:g}; with "
        "--after 0, the first test's stands)",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=DEFAULT_SEEDS,
        help=f"noise seeds the information is averaged over (default: {DEFAULT_SEEDS})",
    )
    parser.add_argument(
        "--spread",
        metavar="PERCENT|recorded",
        help="plan for vehicles around the prior too, each drivetrain parameter within "
        "+-PERCENT of its value, or with 'recorded' within what --after's runs leave open (2 "
        "sigma of their precision, each parameter its own, drawn along their predicted error "
        "correlation): the test must meet every target on "
        f"each (default: {DEFAULT_SPREAD_PERCENT:g} for a parameter set or the reference, a "
        "guess; 'recorded' for an identification's JSON with --after; 0 for one without)",
    )
    parser.add_argument(
        "--spread-vehicles",
        type=int,
        default=DEFAULT_VEHICLES,
        metavar="N",
        help=f"vehicles drawn around the prior with --spread (default: {DEFAULT_VEHICLES})",
    )
    parser.add_argument(
        "--json", type=output_file, help="write the plan as JSON ([test] plan = FILE)"
    )
    parser.add_argument("--plot", type=plot_file, help="plot precision against test time")
    add_interface_options(parser)
    add_vehicle_option(parser)
    parser.set_defaults(run=run)


def read_prior(path: Path | None) -> DrivetrainParameters:
    """The parameters of --prior: a parameter TOML or an identification JSON."""
    if path is None:
        return reference_parameters()
    prior, document = read_parameter_set(path, "--prior")
    edges = (document or {}).get("at_bounds") or {}
    if edges:
        logger.warning(
            "--prior %s: %s ended on an edge of the identification's search box; the plan is "
            "made at values the vehicle may lie beyond (widen the box with dtid identify's "
            "--bounds and identify again first)",
            path,
            ", ".join(f"{name} ({edge['side']})" for name, edge in edges.items()),
        )
    return prior


def planned_vehicle(args: argparse.Namespace) -> VehicleData:
    """The model's vehicle data: ``--vehicle``'s, else those the ``--prior`` identification was
    made with, else the reference's (:func:`dtid.cli.commands.common.vehicle_data`)."""
    if args.prior is not None and is_identification(args.prior):
        return vehicle_data(args, (args.prior, read_identification(args.prior, "--prior")))
    return vehicle_data(args)


def recorded_runs(args: argparse.Namespace) -> tuple[list[Design], list[float], float | None]:
    """The identifying runs of --after's recordings, each as a design, the amplitudes of their
    validation runs, and their idle speed."""
    if not args.after:
        return [], [], None
    tests = measured_tests(args.after, args.dbc, args.signals, planned_vehicle(args))
    designs, held_out = recorded_designs(tests)
    return designs, held_out, float(np.mean([t.setpoint_rpm for t in tests]))


def recorded_identification(args: argparse.Namespace) -> dict | None:
    """The ``--prior`` identification when it was made of ``--after``'s recordings (its profile
    intervals then confirm the targets the prediction says are met:
    :mod:`dtid.identification.planning.confirmation`); None otherwise, with a note when it was
    made of other recordings."""
    if not args.after or args.prior is None or not is_identification(args.prior):
        return None
    document = read_identification(args.prior, "--prior")
    made_of = set(document.get("combustion_variation") or {})  # the identifying recordings
    # and those that only validated: the NRMSEs' labels are "RECORDING @ A N*m" (pipeline.py)
    validated = {
        label.rpartition(" @ ")[0] for label in (document.get("nrmse") or {}).get("validation", {})
    }
    after = {Path(p).resolve() for p in args.after}
    identifying = {Path(name).resolve() for name in made_of}
    used = identifying | {Path(name).resolve() for name in validated}
    if not identifying <= after <= used:
        print(
            f"note: --prior {args.prior} was identified from other recordings than --after's "
            f"({', '.join(sorted(made_of)) or 'none named'}): its intervals do not confirm "
            "the targets; the prediction alone decides"
        )
        return None
    return document


def planned_spread(args: argparse.Namespace) -> float | str:
    """--spread as :func:`dtid.identification.planning.design.plan_test` takes it: a relative
    half-width or ``recorded``, with the defaults the option's help gives."""
    guessed = args.prior is None or not is_identification(args.prior)
    value = args.spread
    if value is None:
        if guessed:
            return DEFAULT_SPREAD_PERCENT / 100.0
        return RECORDED if args.after else 0.0
    if value == RECORDED:
        if not args.after:
            raise ConfigError("--spread recorded needs the recordings: give them with --after")
        return RECORDED
    try:
        percent = float(value)
    except ValueError:
        percent = math.nan
    if not 0.0 <= percent <= 100.0 * MAX_SPREAD:
        raise ConfigError(
            f"--spread {value!r}: give a percentage from 0 to {100 * MAX_SPREAD:g} or 'recorded'"
        )
    return percent / 100.0


def run(args: argparse.Namespace) -> int:
    """Measure the information, search, print, write."""
    targets = parse_targets(args.target)
    safety = load_config(args.config).safety
    cap = args.max_amplitude or safety.max_amplitude_nm
    if args.seeds < 2:
        raise ConfigError("--seeds must be at least 2 (the residual's variance needs a spread)")
    validation = args.validation
    if validation is None:
        validation = 0.0 if args.after else VALIDATION_NM
    if validation < 0:
        raise ConfigError("--validation must be >= 0 N*m (0: no validation chirp)")
    prior = read_prior(args.prior)
    spread = planned_spread(args)
    if args.spread_vehicles < 1:
        raise ConfigError("--spread-vehicles must be at least 1")
    recorded, held_out, idle = recorded_runs(args)
    setpoint = args.setpoint or idle or IdleController().setpoint_rpm
    identification = recorded_identification(args)
    info, recommendation = plan_test(
        prior,
        targets,
        replace(safety, max_amplitude_nm=cap),
        max_time_s=args.max_time,
        validation_nm=validation,
        seeds=args.seeds,
        options=SimulationOptions(controller=IdleController(setpoint_rpm=setpoint)),
        recorded=recorded,
        held_out_nm=held_out,
        vehicle=planned_vehicle(args),
        spread=spread,
        vehicles=args.spread_vehicles,
        identification=identification,
    )
    limits = {
        "max_amplitude_nm": cap,
        "max_time_s": args.max_time,
        "speed_window_rpm": safety.speed_window_rpm,
    }
    document = plan_document(info, recommendation, targets, limits)
    print_plan(document)
    if args.json:
        write_json(args.json, document)
    if args.plot:
        from dtid.identification.planning.figure import plot_plan

        plot_plan(info, recommendation, targets, args.plot)
        print(f"plot: {args.plot}")
    return 0


def print_plan(document: dict) -> None:
    """The recommended plan, the precision of both plans against the targets, what is unmet."""
    plan, paper, recorded = document["plan"], document["paper"], document["recorded"]
    verdict = "meets every target" if document["meets_targets"] else "does NOT meet every target"
    if recorded["runs"]:
        print(
            f"recorded: {len(recorded['runs'])} identifying runs at "
            f"{', '.join(f'{a:g}' for a in sorted({r['amplitude_nm'] for r in recorded['runs']}))} "
            "N*m"
        )
    if plan is None:
        print("the recorded runs meet every target: no further test is needed")
    else:
        chirps = " + ".join(
            f"{n} x {a:g} N*m" for a, n in zip(plan["amplitudes_nm"], plan["repeats"], strict=True)
        )
        print(
            f"recommended{' follow-up' if recorded['runs'] else ''}: {chirps}, "
            f"{plan['duration_s']:g} s chirps over {plan['f1_hz']:g}-{plan['f2_hz']:g} Hz, "
            f"validation {plan['validation_nm']:g} N*m, at {plan['setpoint_rpm']:.0f} rpm: "
            f"{document['test_time_s'] / 60:.1f} min; {verdict}"
        )
    sigmas = document["sigmas"]
    spread = document["spread"]
    first = "recorded %" if recorded["runs"] else "paper %"
    at_prior = spread["predicted_precision_at_prior"] if spread["vehicles"] else None
    if at_prior:
        within = describe({n: v / 100.0 for n, v in spread["percent_by_parameter"].items()})
        along = ", along the errors the recorded runs leave" if spread["correlated"] else ""
        print(
            f"planned for the prior and {spread['vehicles']} vehicles within {within} of it"
            f"{along} (--spread): each figure is the worst of them"
        )
    print(
        f"{'':>6} {'target %':>9} {first:>10} {'plan %':>9}"
        + (f" {'at prior':>9} {'vehicles meeting':>17}" if at_prior else "")
        + f"   (precision at {sigmas:g} sigma; paper's test: {paper['test_time_s'] / 60:.1f} min)"
    )
    targets = document["targets_percent"]
    before = recorded["predicted_precision"] or paper["predicted_precision"]
    for name, value in document["predicted_precision"].items():
        target = f"{targets[name]:g}" if name in targets else "-"
        line = (
            f"{name:>6} {target:>9} {100 * sigmas * before[name]:10.1f} {100 * sigmas * value:9.1f}"
        )
        if at_prior:
            meeting = spread["vehicles_meeting"].get(name)
            share = f"{meeting} of {spread['vehicles'] + 1}" if meeting is not None else "-"
            line += f" {100 * sigmas * at_prior[name]:9.1f} {share:>17}"
        print(line)
    for unmet in document["unmet"]:
        print(f"unmet {unmet['name']}: {unmet['reason']}")
    for note in document["notes"]:
        print(f"note: {note}")
    for amplitude, why in document["information"]["excluded"].items():
        print(f"not used: {amplitude} N*m, {why}")
    if recorded["runs"] and plan is not None:
        levels = " ".join(f"{a:g}" for a in document["identify_nm"])
        print(f"identify the recordings of both tests together with --identify {levels}")
