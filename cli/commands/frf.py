"""``dtid frf``: frequency responses of every chirp run in one or more recordings."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from dtid.cli.commands.common import add_interface_options, output_file, plot_file, positive_float
from dtid.dbc.loader import load_interface
from dtid.errors import ConfigError
from dtid.identification.frf.closed_loop import DEFAULT_RESOLUTION_HZ, FrfEstimate
from dtid.identification.samples.recording import load_recording
from dtid.jsonfile import write_json
from dtid.workflow import frf


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "frf",
        help="estimate G_DRV, G_ENG and the coherence of each chirp run",
        description="Find the chirp runs in each recording and estimate the closed-loop "
        "frequency responses G_DRV (eq. 14) and G_ENG (eq. 15) with Welch-averaged "
        "cross-spectra against the test torque.",
    )
    parser.add_argument("recordings", type=Path, nargs="+", metavar="RECORDING")
    parser.add_argument("--json", type=output_file, help="write the FRFs as JSON")
    parser.add_argument("--plot", type=plot_file, help="plot |G_DRV| per amplitude (Fig. 3)")
    parser.add_argument(
        "--resolution",
        type=positive_float,
        default=DEFAULT_RESOLUTION_HZ,
        help="Welch frequency resolution in Hz (default: %(default)s)",
    )
    parser.add_argument(
        "--band",
        type=positive_float,
        nargs=2,
        metavar=("F1", "F2"),
        help="frequency band in Hz (default: each chirp's sweep)",
    )
    add_interface_options(parser)
    parser.set_defaults(run=run)


def estimate_all(
    recordings: list[Path], args: argparse.Namespace
) -> list[tuple[Path, FrfEstimate]]:
    """FRFs of every chirp run of every recording, in order."""
    seen: set[Path] = set()
    for path in recordings:
        if path.resolve() in seen:
            raise ConfigError(f"{path} is given twice: give each recording once")
        seen.add(path.resolve())
    if args.band and args.band[0] >= args.band[1]:
        raise ConfigError(
            f"--band {args.band[0]:g} {args.band[1]:g}: give the lower frequency first (F1 < F2)"
        )
    interface = load_interface(args.dbc, args.signals)
    band = tuple(args.band) if args.band else None
    return [
        (path, estimate)
        for path in recordings
        for estimate in frf(load_recording(path, interface), args.resolution, band)
    ]


def summary_line(estimate: FrfEstimate) -> str:
    """One line per run: amplitude, strongest resonance, K, the share of coherent bins and the
    engine's lag behind its request where T/T_ecu shows one.

    The resonance is the peak of |G_DRV| * omega (the response with the rigid-body 1/(J s)
    taken out), which is the DMF mode for a passenger-car drivetrain at idle.
    """
    f, db = estimate.frequency_hz, estimate.drv_db
    peak = int(np.argmax(db + 20 * np.log10(f)))
    gain, lag = estimate.engine_gain, estimate.engine_lag
    return (
        f"A = {estimate.run.amplitude_nm:5.2f} N*m  {estimate.run.start_s:7.1f} s  "
        f"resonance {f[peak]:5.2f} Hz ({db[peak]:6.1f} dB)  "
        f"K = {'-' if np.isnan(gain) else f'{gain:.3f}'}  "
        f"coherence > 0.9 in {np.mean(estimate.coherence > 0.9):.0%} of bins"
        + ("" if lag is None else f"  engine lag {lag.tau_s:.3f} s (K {lag.gain:.3f})")
    )


def run(args: argparse.Namespace) -> int:
    """Estimate, print a summary, write JSON and plot as asked."""
    results = estimate_all(args.recordings, args)
    for _, estimate in results:
        print(summary_line(estimate))
    if args.json:
        write_json(
            args.json, {"runs": [{"recording": str(path), **e.as_dict()} for path, e in results]}
        )
    if args.plot:
        from dtid.identification.plots import plot_frf

        plot_frf([e for _, e in results], args.plot)
        print(f"plot: {args.plot}")
    return 0
