"""``dtid diagnose``: is the identified model adequate, and where does it miss the recordings.

Identifies first (as ``dtid identify``, profiles off unless asked for) unless given the
identification JSON of these recordings. The two largest amplitudes identify and the others
validate, as in ``dtid identify``. Every run's |G_DRV| is compared with the model's, bin by bin,
each bin standardised by the scatter a recording of the model itself shows there; bands where
the difference is significant (family-wise error 1 %) make the mismatch map, and for each run
the coupling values it would ask for on its own are reported as hints. Where the map finds a
mismatch, the mechanisms of the library that could explain it are added to the model, refitted
and kept only where the fit improves significantly and the held-out runs improve too
(docs/diagnosis.md).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from dtid.cli.commands.common import (
    ProgressBar,
    add_interface_options,
    add_vehicle_option,
    output_file,
    plot_file,
    read_identification,
    read_parameter_set,
    vehicle_data,
)
from dtid.cli.commands.identify import (
    add_bounds_options,
    add_identify_option,
    add_search_options,
    parse_bounds,
    search_settings,
)
from dtid.errors import ConfigError
from dtid.identification.diagnosis.diagnose import Diagnosis, diagnose_document, diagnose_report
from dtid.identification.search.identify import SearchSettings
from dtid.jsonfile import write_json
from dtid.simulator.mechanisms import BY_NAME
from dtid.simulator.parameters import reference_parameters
from dtid.workflow import identify, measured_tests

SHIFTS_SHOWN = 4
"""Parameters named, largest change first, for each mechanism the drivetrain would absorb."""
SHIFT_SHOWN = 0.005
"""Smallest relative change named."""
HELD_OUT_MEASURE = {
    "drv": "NRMSE",
    "eng": "|G_ENG| RMS z",
    "strokes": "strokes' departure",
}
"""What a candidate's held-out figure measures, by where it was tested."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "diagnose",
        help="locate where the identified model misses the recordings",
        description=__doc__,
    )
    parser.add_argument("recordings", type=Path, nargs="+", metavar="RECORDING")
    parser.add_argument(
        "--identification",
        type=Path,
        metavar="ID.json",
        help="the JSON `dtid identify --json` wrote for these recordings (default: identify)",
    )
    add_identify_option(parser)
    add_bounds_options(parser)
    add_vehicle_option(parser)
    add_search_options(parser)
    parser.set_defaults(profile_points=0)
    add_mechanisms_option(parser)
    parser.add_argument("--json", type=output_file, help="write the diagnosis as JSON")
    parser.add_argument("--plot", type=plot_file, help="plot the mismatch map and the FRFs")
    add_interface_options(parser)
    parser.set_defaults(run=run)


def add_mechanisms_option(parser: argparse.ArgumentParser, what: str = "") -> None:
    """Add ``--mechanisms`` (``dtid diagnose`` and ``dtid worker``): the library's mechanisms a
    diagnosis considers; None (not given) is all of them, the option alone none (locate only)."""
    parser.add_argument(
        "--mechanisms",
        nargs="*",
        choices=list(BY_NAME),
        metavar="NAME",
        help=f"mechanisms to consider{what} (default: all of {', '.join(BY_NAME)}; the option "
        "alone: locate only)",
    )


def run(args: argparse.Namespace) -> int:
    """Diagnose, print the verdict first, write JSON and plot as asked."""
    if args.identification is not None:
        refuse_search_options(args)
        document = read_identification(args.identification)
        vehicle = vehicle_data(args, (args.identification, document))
        tests = measured_tests(args.recordings, args.dbc, args.signals, vehicle)
        diagnosis = diagnose_document(tests, document, args.identify, mechanisms=args.mechanisms)
    else:
        vehicle = vehicle_data(args)
        bar = ProgressBar()
        report = identify(
            args.recordings,
            dbc=args.dbc,
            signals=args.signals,
            vehicle=vehicle,
            prior=read_parameter_set(args.prior, "--prior")[0]
            if args.prior
            else reference_parameters(),
            bounds=parse_bounds(args.bounds),
            span=None if args.span is None else args.span / 100,
            identify_amplitudes=args.identify,
            settings=search_settings(args),
            profile_points=args.profile_points,
            progress=bar,
        )
        bar.finish()
        diagnosis = diagnose_report(
            report, mechanisms=args.mechanisms, profile_points=args.profile_points
        )
    print_diagnosis(diagnosis)
    print(vehicle.describe())
    if args.json:
        write_json(args.json, diagnosis.as_dict())
    if args.plot:
        from dtid.identification.diagnosis.figure import plot_mismatch

        plot_mismatch(diagnosis, args.plot)
        print(f"plot: {args.plot}")
    return 0


def refuse_search_options(args: argparse.Namespace) -> None:
    """Refuse the identification's options beside ``--identification``: the identification is
    given, so they would be ignored without a word.

    Raises
    ------
    ConfigError
        Naming the first such option given.
    """
    defaults = SearchSettings()
    given = {
        "--prior": args.prior is not None,
        "--span": args.span is not None,
        "--bounds": bool(args.bounds),
        "--generations": args.generations != defaults.generations,
        "--popsize": args.popsize != defaults.popsize,
        "--polish-evaluations": args.polish_evaluations != defaults.polish_evaluations,
        "--single-start": args.single_start,
        "--profile-points": args.profile_points != 0,
    }
    for option, used in given.items():
        if used:
            raise ConfigError(
                f"{option} sets the identification, and --identification {args.identification} "
                "gives it: drop one of them (without --identification, dtid diagnose identifies "
                "first with these options)"
            )


def print_diagnosis(diagnosis: Diagnosis) -> None:
    """The verdict first, then the bands, the per-run hints and the test's figures."""
    print(diagnosis.sentence())
    for band in diagnosis.mismatch.bands:
        print(
            f"mismatch |G_{band.frf.upper()}| {band.label} ({band.role}): {band.f_lo_hz:.2f}-"
            f"{band.f_hi_hz:.2f} Hz, {band.excess_db:+.2f} dB at {band.peak_hz:.2f} Hz, "
            f"p = {band.p_value:.2g}, coherence {band.coherence:.2f}"
            f"{' (smooth trend over the run)' if band.kind == 'trend' else ''}"
        )
    for candidate in diagnosis.candidates:
        values = ", ".join(f"{k} = {v:.4g}" for k, v in candidate.parameters().items())
        held = HELD_OUT_MEASURE[candidate.frf]
        gain = candidate.validation_gain
        change = "not measured (no held-out run)" if math.isnan(gain) else f"{-100 * gain:+.1f} %"
        print(
            f"candidate {'+'.join(candidate.mechanisms)} ({values}): statistic "
            f"{candidate.statistic:.1f}, p = {candidate.p_value:.2g}, criterion "
            f"{candidate.criterion:.1f}, held-out {held} {change}"
            f"{' accepted' if candidate.accepted else ''}"
        )
    if diagnosis.indistinguishable:
        print(
            "indistinguishable on these data (neither detected nor excluded): "
            + ", ".join(diagnosis.indistinguishable)
        )
    for entry in diagnosis.absorbed:
        values = ", ".join(f"{k} = {v:.4g}" for k, v in entry.parameters.items())
        moved = [item for item in entry.shift.items() if abs(item[1]) >= SHIFT_SHOWN]
        largest = sorted(moved, key=lambda item: -abs(item[1]))[:SHIFTS_SHOWN]
        shifts = (
            "as " + ", ".join(f"{name} {100 * value:+.1f} %" for name, value in largest)
            if largest
            else f"leaving every drivetrain parameter within {100 * SHIFT_SHOWN:g} %"
        )
        print(
            f"if present, {entry.mechanism} ({values}) would be absorbed {shifts} "
            f"(eq. 17 {entry.objective:.3f} of the imitation)"
        )
    if diagnosis.cylinders is not None:
        cylinders = diagnosis.cylinders
        for name, factors in cylinders.factors.items():
            print(
                f"cylinders {name}: torque factor by place in the firing order "
                + ", ".join(f"{f:.3f}" for f in factors)
                + f" (odd place {cylinders.places[name]})"
            )
        print(
            f"cylinders: one-cylinder share {cylinders.share:+.4f} +- "
            f"{cylinders.standard_error:.4f}, p = {cylinders.p_value:.2g}"
        )
    for hint in diagnosis.hints:
        edge = " (grid edge)" if hint.at_edge else ""
        print(
            f"hint {hint.name} {hint.label} ({hint.role}): {hint.effective:.4g}{edge} against "
            f"{hint.identified:.4g}, NRMSE {hint.nrmse_identified:.3f} -> "
            f"{hint.nrmse_effective:.3f}"
        )
    test = diagnosis.mismatch
    print(
        f"test: {test.effective_bins:.0f} effective bins (neighbour correlation "
        f"{test.drv.correlation:.2f}), |z| threshold {test.drv.threshold_z:.2f}, global p = "
        f"{test.global_p_value:.2g}; {diagnosis.seconds:.1f} s"
    )
