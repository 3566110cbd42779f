"""``dtid inspect``: what a recording holds, for a user about to trust it."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from dtid.acquisition.metadata import interface_differences, read_metadata
from dtid.cli.commands.common import add_interface_options, output_file
from dtid.dbc.interface import VehicleInterface
from dtid.dbc.loader import load_interface
from dtid.dbc.roles import REQUIRED_ROLES
from dtid.errors import DbcError
from dtid.identification.frf.runs import find_runs
from dtid.identification.samples.recording import Recording, load_recording
from dtid.jsonfile import write_json


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    parser = subparsers.add_parser(
        "inspect",
        help="report the roles and chirp runs a recording holds",
        description="Decode a recording and report, per role, its sample count, rate, range and "
        "longest gap, and the chirp runs found in the test torque.",
    )
    parser.add_argument(
        "recording", type=Path, help="CAN recording (.blf, .asc, .log, .mf4, .trc or .csv)"
    )
    parser.add_argument("--json", type=output_file, help="also write the report as JSON")
    add_interface_options(parser)
    parser.set_defaults(run=run)


def role_summary(times: np.ndarray, values: np.ndarray) -> dict[str, float | int | None]:
    """count, rate_hz, min, max and max_gap_s of one role's samples."""
    count = len(times)
    if count == 0:
        return {"count": 0, "rate_hz": None, "min": None, "max": None, "max_gap_s": None}
    span = float(times[-1] - times[0])
    return {
        "count": count,
        "rate_hz": (count - 1) / span if span > 0 else None,
        "min": float(values.min()),
        "max": float(values.max()),
        "max_gap_s": float(np.diff(times).max()) if count > 1 else None,
    }


def report(recording: Recording) -> dict[str, object]:
    """The inspect report (docs/schemas/inspect.schema.json)."""
    roles = {
        role: {
            **role_summary(series.timestamps, series.values),
            "bad_frames": series.n_bad,
            "not_measured": series.not_measured,
        }
        for role, series in recording.roles.items()
    }
    runs = (
        [run.as_dict() for run in find_runs(recording.series("test_torque"))]
        if "test_torque" in recording.roles
        else []
    )
    return {
        "recording": str(recording.path),
        "frames": recording.n_frames,
        "duration_s": recording.duration_s,
        "roles": roles,
        "missing_roles": list(recording.missing_roles),
        "runs": runs,
        "integrity": recording.integrity.as_dict(),
        "metadata": read_metadata(recording.path),
        "sampling": recording.sampling_problems(),
        "channels": {role: dict(found) for role, found in recording.channels.items()},
        "channel_problems": dict(recording.channel_problems),
    }


def no_runs_reason(test_torque: dict | None) -> str:
    """Why a recording holds no chirp run, from its test torque's summary (``roles`` entry of
    the JSON): absent, constant (at zero: no test run; elsewhere: a raw value the signal never
    left, or the map's scale or offset), or varying without a chirp the run finder takes."""
    if not test_torque or not test_torque["count"]:
        return "the test torque is absent"
    low, high = test_torque["min"], test_torque["max"]
    if low == high == 0:
        return "the test torque is zero throughout: no test was run"
    if low == high:
        return (
            f"the test torque holds {low:g} N*m throughout: a raw value its signal never left "
            "(no test run, or the signal map's scale or offset is off)"
        )
    return "the test torque varies but holds no chirp: not the tool's test torque?"


def _fmt(value: object, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _print_metadata(metadata: dict[str, Any] | None, interface: VehicleInterface) -> None:
    """What travels with the recording, and whether it is read as it was made."""
    if metadata is None:
        print("metadata: none (not recorded by dtid, or its sidecar <log>.json is not beside it)")
        return
    kept = metadata.get("integrity") or {}
    software = metadata.get("software") or {}
    print(
        f"metadata: session {metadata.get('session')}, {metadata.get('source')}, started "
        f"{metadata.get('started_utc')}, drivetrain-id {software.get('drivetrain-id')}"
    )
    closed = "closed cleanly" if kept.get("closed") else "not closed cleanly"
    failure = f" ({kept['failure']})" if kept.get("failure") else ""
    print(
        f"metadata: the log kept {kept.get('frames')} frames, lost {kept.get('lost')}, "
        f"{closed}{failure}"
    )
    for difference in interface_differences(metadata, interface):
        print(f"metadata: warning: {difference}")


def run(args: argparse.Namespace) -> int:
    """Print (and optionally save) the report."""
    interface = load_interface(args.dbc, args.signals)
    document = report(load_recording(args.recording, interface))
    print(f"{document['recording']}: {document['frames']} frames, {document['duration_s']:.1f} s")
    integrity = document["integrity"]
    if integrity["intact"]:
        print("integrity: intact")
    if integrity["cut"]:
        print(f"integrity: the file {integrity['cut']}")
    for damage in integrity["damaged"]:
        print(
            f"integrity: damaged at {damage['where']}, about {damage['frames_lost']} frame(s) lost"
        )
    _print_metadata(document["metadata"], interface)
    print(f"{'role':<16}{'count':>8}{'rate/Hz':>10}{'min':>12}{'max':>12}{'max gap/s':>11}")
    for role, s in document["roles"].items():
        print(
            f"{role:<16}{s['count']:>8}{_fmt(s['rate_hz'], '.1f'):>10}"
            f"{_fmt(s['min'], '.2f'):>12}{_fmt(s['max'], '.2f'):>12}"
            f"{_fmt(s['max_gap_s'], '.3f'):>11}"
        )
        if s["count"] == 0:
            print(f"  no frame of {role}'s message in this recording: wrong DBC or signal map?")
        if s["bad_frames"]:
            print(f"  {s['bad_frames']} frames of {role} could not be decoded")
        if s["not_measured"]:
            print(
                f"  {s['not_measured']} frames of {role} carry no measurement (a value the DBC "
                "names outside the signal's range, or the validity flag): left out"
            )
    for role in document["missing_roles"]:
        print(f"{role:<16}not in the signal map")
    problems = document["channel_problems"]
    for role, found in document["channels"].items():
        if len(found) > 1 and role not in problems:
            listed = ", ".join(f"{channel} ({n} frames)" for channel, n in found.items())
            print(f"  {role}: its message is on channels {listed}; the signal map's is read")
    for problem in problems.values():
        print(f"  {problem}: frf, identify and diagnose refuse the recording")
    for role, problem in document["sampling"].items():
        effect = (
            "the model is then driven by the measured torque"
            if role == "torque_request"
            else "frf, identify and diagnose refuse the recording"
        )
        print(f"  {problem}: {effect}")
    if not document["runs"]:
        print(f"no chirp runs ({no_runs_reason(document['roles'].get('test_torque'))})")
    for run in document["runs"]:
        print(
            f"chirp {run['start_s']:.1f}-{run['end_s']:.1f} s: {run['amplitude_nm']:.2f} N*m, "
            f"{run['f1_hz']:.2f} -> {run['f2_hz']:.2f} Hz"
        )
    if args.json:
        write_json(args.json, document)
    roles = document["roles"]
    if not any(roles[role]["count"] for role in REQUIRED_ROLES if role in roles):
        database = args.dbc or "the product's own"
        raise DbcError(
            f"{args.recording}: no frame of the speed's, the mean torque's or the test torque's "
            f"message (DBC: {database}): the DBC or the signal map is not this vehicle's; give "
            "the vehicle's with --dbc and --signals"
        )
    return 0
