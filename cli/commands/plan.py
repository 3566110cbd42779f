"""``dtid plan``: the shortest chirp test that reaches the precision asked for."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from dtid.acquisition.config import load_config
from dtid.cli.commands.common import positive_float
from dtid.errors import ConfigError
from dtid.identification.planning.design import (
    DEFAULT_MAX_TIME_S,
    PRECISION_NAMES,
    SIGMAS,
    VALIDATION_NM,
    parse_targets,
    plan_document,
    plan_test,
)
from dtid.identification.planning.information import DEFAULT_SEEDS
from dtid.jsonfile import write_json
from dtid.simulator.controller import IdleController
from dtid.simulator.parameters import load_parameters, reference_parameters
from dtid.simulator.simulate import SimulationOptions


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "plan",
        help="design the shortest chirp test that meets precision targets",
        description="Predict each parameter's precision for a chirp test from eq. (17)'s "
        "linearised information at a prior (simulated with noise and the model's own Monte "
        "Carlo scatter) and search the shortest test (two amplitudes, repeats, chirp duration, "
        f"band) that meets every target at {SIGMAS:g} sigma. Targets it cannot meet within the "
        "limits are listed with what would meet them. See docs/planning.md.",
    )
    parser.add_argument(
        "--prior",
        type=Path,
        help="parameter set (TOML) to plan for (default: the reference vehicle)",
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
        default=IdleController().setpoint_rpm,
        metavar="RPM",
        help="the vehicle's idle speed, rpm: the mean torque's Nyquist frequency (rpm/60 Hz "
        "for four cylinders) caps the band (default: %(default)s)",
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
        type=positive_float,
        default=DEFAULT_MAX_TIME_S,
        metavar="S",
        help=f"longest whole test, s (default: {DEFAULT_MAX_TIME_S:g})",
    )
    parser.add_argument(
        "--validation",
        type=float,
        default=VALIDATION_NM,
        metavar="NM",
        help=f"validation chirp amplitude, N*m; 0 for none (default: {VALIDATION_NM:g})",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=DEFAULT_SEEDS,
        help=f"noise seeds the information is averaged over (default: {DEFAULT_SEEDS})",
    )
    parser.add_argument("--json", type=Path, help="write the plan as JSON ([test] plan = FILE)")
    parser.add_argument("--plot", type=Path, help="plot precision against test time")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Measure the information, search, print, write."""
    targets = parse_targets(args.target)
    safety = load_config(args.config).safety
    cap = args.max_amplitude or safety.max_amplitude_nm
    if args.seeds < 2:
        raise ConfigError("--seeds must be at least 2 (the residual's variance needs a spread)")
    if args.validation < 0:
        raise ConfigError("--validation must be >= 0 N*m (0: no validation chirp)")
    prior = load_parameters(args.prior) if args.prior else reference_parameters()
    info, recommendation = plan_test(
        prior,
        targets,
        replace(safety, max_amplitude_nm=cap),
        max_time_s=args.max_time,
        validation_nm=args.validation,
        seeds=args.seeds,
        options=SimulationOptions(controller=IdleController(setpoint_rpm=args.setpoint)),
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

        plot_plan(info, recommendation.design, targets, args.plot)
        print(f"plot: {args.plot}")
    return 0


def print_plan(document: dict) -> None:
    """The recommended plan, the precision of both plans against the targets, what is unmet."""
    plan, paper = document["plan"], document["paper"]
    chirps = " + ".join(
        f"{n} x {a:g} N*m" for a, n in zip(plan["amplitudes_nm"], plan["repeats"], strict=True)
    )
    verdict = "meets every target" if document["meets_targets"] else "does NOT meet every target"
    print(
        f"recommended: {chirps}, {plan['duration_s']:g} s chirps over {plan['f1_hz']:g}-"
        f"{plan['f2_hz']:g} Hz, validation {plan['validation_nm']:g} N*m, at "
        f"{plan['setpoint_rpm']:.0f} rpm: {document['test_time_s'] / 60:.1f} min; {verdict}"
    )
    sigmas = document["sigmas"]
    print(
        f"{'':>6} {'target %':>9} {'paper %':>9} {'plan %':>9}   (precision at {sigmas:g} sigma; "
        f"paper: {paper['test_time_s'] / 60:.1f} min)"
    )
    targets = document["targets_percent"]
    for name, value in document["predicted_precision"].items():
        target = f"{targets[name]:g}" if name in targets else "-"
        old = 100 * sigmas * paper["predicted_precision"][name]
        print(f"{name:>6} {target:>9} {old:9.1f} {100 * sigmas * value:9.1f}")
    for unmet in document["unmet"]:
        print(f"unmet {unmet['name']}: {unmet['reason']}")
    for amplitude, why in document["information"]["excluded"].items():
        print(f"not used: {amplitude} N*m, {why}")
