"""The Python API: read a recording, estimate its FRFs, identify the drivetrain.

What the ``dtid`` commands do, as functions a notebook calls; the commands are a thin layer over
them. Each function is also at the package's top (``dtid.read_recording``, ``dtid.frf``,
``dtid.identify``), and the result of :func:`identify` is a report object in the manner of
python-control's results (:class:`dtid.identification.pipeline.IdentificationReport`):
``.parameters``, ``.intervals``, ``.to_json()``, ``.plot()``.

Example
-------
>>> import dtid
>>> recording = dtid.read_recording("test.blf")                  # doctest: +SKIP
>>> [round(e.run.amplitude_nm) for e in dtid.frf(recording)]     # doctest: +SKIP
[5, 10, 2]
>>> report = dtid.identify(["test.blf"])                         # doctest: +SKIP
>>> report.parameters["c12"]                                     # doctest: +SKIP
301.2

docs/api.md shows a whole session; a test runs it.
"""

from __future__ import annotations

import hashlib
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path

from dtid.acquisition.metadata import read_metadata
from dtid.dbc.interface import VehicleInterface
from dtid.dbc.loader import load_interface
from dtid.errors import AnalysisError, ConfigError
from dtid.identification.frf.closed_loop import DEFAULT_RESOLUTION_HZ, FrfEstimate, estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import IdentificationReport, ProfileMap, run_identification
from dtid.identification.samples.recording import Recording, load_recording
from dtid.identification.search.identify import Progress, SearchSettings
from dtid.simulator.parameters import DrivetrainParameters, load_parameters, reference_parameters
from dtid.simulator.vehicle_data import VehicleData, load_vehicle_data

PathLike = str | os.PathLike[str]


def read_recording(
    path: PathLike, dbc: PathLike | None = None, signals: PathLike | None = None
) -> Recording:
    """Read and decode a CAN recording (.blf, .asc, .log, .mf4, .trc, .csv; format by suffix).

    Parameters
    ----------
    path
        The recording.
    dbc, signals
        The vehicle's CAN database and the signal map that reads it (docs/vehicle.md); the
        product's own when omitted.

    Returns
    -------
    Recording
        The decoded series per role; ``.test_data()`` gives the FRF pipeline's signals.
    """
    return load_recording(path, load_interface(dbc, signals))


def frf(
    recording: Recording | PathLike,
    resolution_hz: float = DEFAULT_RESOLUTION_HZ,
    band_hz: tuple[float, float] | None = None,
    dbc: PathLike | None = None,
    signals: PathLike | None = None,
) -> list[FrfEstimate]:
    """The closed-loop frequency responses of every chirp run of a recording (eqs. 12-15).

    Parameters
    ----------
    recording
        A :class:`Recording` or the path of one (then ``dbc`` and ``signals`` read it).
    resolution_hz
        Welch frequency resolution, Hz.
    band_hz
        Frequency band, Hz; each chirp's sweep by default.

    Returns
    -------
    list of FrfEstimate
        One per run, in time order: ``.frequency_hz``, ``.drv_db``, ``.eng_db``,
        ``.coherence``, ``.engine_gain`` (K, eq. 24).

    Raises
    ------
    AnalysisError
        If the recording holds no chirp.
    """
    if not isinstance(recording, Recording):
        recording = read_recording(recording, dbc, signals)
    data = recording.test_data()
    runs = find_runs(data.test_torque)
    if not runs:
        raise AnalysisError(
            f"{recording.path}: no chirp in the test torque, so no FRF can be estimated"
        )
    return [estimate_frf(data, run, resolution_hz, band_hz) for run in runs]


def measured_tests(
    recordings: Sequence[PathLike],
    dbc: PathLike | VehicleInterface | None = None,
    signals: PathLike | None = None,
    vehicle: VehicleData | PathLike | None = None,
    resolution_hz: float = DEFAULT_RESOLUTION_HZ,
) -> list[MeasuredTest]:
    """Read recordings and prepare what the identification needs of each: its runs and FRFs,
    K, T_loss, the idle speed and the vehicle's own idle loop (docs/method.md).

    Parameters
    ----------
    recordings
        One recording per test.
    dbc, signals
        As :func:`read_recording`; ``dbc`` may also be a bound interface.
    vehicle
        The vehicle file (TOML, docs/model-assumptions.md) or its data; the reference's engine
        and speed sensor when omitted.
    """
    interface = dbc if isinstance(dbc, VehicleInterface) else load_interface(dbc, signals)
    refuse_repeated(recordings)
    refuse_mixed_vehicles(recordings)
    if vehicle is None:
        vehicle = VehicleData()
    elif not isinstance(vehicle, VehicleData):
        vehicle = load_vehicle_data(vehicle)
    return [
        MeasuredTest.from_data(
            str(path), load_recording(path, interface).test_data(), resolution_hz, vehicle
        )
        for path in recordings
    ]


def refuse_repeated(recordings: Sequence[PathLike]) -> None:
    """Raise ConfigError where a recording is given twice: the same file, or the same bytes
    under another name (a copy).

    Each recording's runs are its own terms of eq. (17) and its own information in the profile
    intervals: a recording counted twice weighs its runs double in the search and narrows the
    intervals as if the test had been repeated, and the report showed it once (the runs' labels
    are the file's name), so nothing said it had happened.
    """
    paths = [Path(r) for r in recordings if Path(r).is_file()]  # the reader names the rest
    sizes = Counter(path.stat().st_size for path in paths)
    seen: dict[str, Path] = {}
    for path in paths:
        if sizes[path.stat().st_size] < 2:
            continue  # alone in its size: no copy of another
        with path.open("rb") as handle:
            digest = hashlib.file_digest(handle, "sha256").hexdigest()
        if digest in seen:
            same = path.resolve() == seen[digest].resolve()
            again = "given twice" if same else f"the same recording as {seen[digest]}"
            raise ConfigError(
                f"{path} is {again}: each recording counts once in the identification and its "
                "intervals (a repeated test is a new recording); give it once"
            )
        seen[digest] = path


def refuse_mixed_vehicles(recordings: Sequence[PathLike]) -> None:
    """Raise ConfigError where the recordings' metadata name different vehicles.

    One identification fits one drivetrain to every run: recordings of two vehicles give
    parameters of neither, fitted as well as the search can and reported without a word. The
    name is the metadata's ``vehicle`` (the daemon's ``[output] vehicle``: a name or VIN),
    compared without case or surrounding blanks; recordings without one are not judged.
    """
    files: dict[str, list[str]] = {}
    spelt: dict[str, str] = {}  # each vehicle's name as its first recording gives it
    for recording in recordings:
        if not Path(recording).is_file():
            continue  # the reader names it
        name = (read_metadata(recording) or {}).get("vehicle")
        if isinstance(name, str) and name.strip():
            key = name.strip().casefold()
            spelt.setdefault(key, name.strip())
            files.setdefault(key, []).append(str(recording))
    if len(files) > 1:
        named = "; ".join(f"{', '.join(paths)} of {spelt[key]!r}" for key, paths in files.items())
        raise ConfigError(
            f"the recordings come from {len(files)} vehicles by their metadata ({named}): one "
            "identification is one drivetrain. Identify each vehicle on its own (`dtid batch` "
            "identifies a fleet, vehicle by vehicle); where they are one vehicle under two names, "
            "correct the `vehicle` of the metadata beside the recording (docs/formats.md)"
        )


def identify(
    recordings: Sequence[PathLike] | Sequence[MeasuredTest],
    *,
    dbc: PathLike | None = None,
    signals: PathLike | None = None,
    vehicle: VehicleData | PathLike | None = None,
    prior: DrivetrainParameters | PathLike | None = None,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    identify_amplitudes: Sequence[float] | None = None,
    settings: SearchSettings | None = None,
    profile_points: int = 0,
    span: float | None = None,
    progress: Progress | None = None,
    profile_map: ProfileMap | None = None,
) -> IdentificationReport:
    """Identify the drivetrain's parameters from chirp recordings (``dtid identify``).

    Parameters
    ----------
    recordings
        The recordings (paths), or tests already prepared by :func:`measured_tests`.
    dbc, signals, vehicle
        As :func:`measured_tests`.
    prior
        Centre of the search box and source of what the data do not give: a parameter set or
        a parameter file (TOML); the reference vehicle's when omitted.
    fixed
        Values to hold, by parameter name (setup 4's, or K, T_loss, combustion_variation).
    bounds
        Explicit search bounds by parameter name, SI units.
    identify_amplitudes
        The amplitudes that identify, N*m (default: the two largest); the others validate.
    settings
        Search budget and seed.
    profile_points
        Grid points per likelihood profile; 0 (the default here, unlike the command) skips
        them: no intervals, no verdicts, about a minute less.
    span
        Relative half-width of the box around the prior; None: +-100 % widened to a passenger
        car's ranges.
    progress
        Called as ``progress(stage, step, steps, best)`` while the search runs.
    profile_map
        How the profiles are computed (``dtid batch`` spreads them over its cluster); None:
        one after another.

    Returns
    -------
    IdentificationReport
        ``.parameters``, ``.intervals``, ``.to_json()``, ``.plot()``, ``.as_dict()``.
    """
    if all(isinstance(r, MeasuredTest) for r in recordings):
        tests = list(recordings)
    else:
        tests = measured_tests(recordings, dbc, signals, vehicle)  # type: ignore[arg-type]
    if prior is None:
        prior = reference_parameters()
    elif not isinstance(prior, DrivetrainParameters):
        prior = load_parameters(Path(prior))
    return run_identification(
        tests,  # type: ignore[arg-type]
        prior,
        fixed=fixed,
        bounds=bounds,
        identify_amplitudes=identify_amplitudes,
        settings=settings,
        profile_points=profile_points,
        progress=progress,
        span=span,
        profile_map=profile_map,
    )
