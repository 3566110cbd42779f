"""A fleet's tests identified in parallel on Dask (``dtid batch``).

One test is one argument: a session directory (the daemon's: the recordings in it are that
test's) or one recording. Each test becomes one Dask task that identifies it as ``dtid identify``
does (and diagnoses it with ``diagnose``), on a local cluster by default or on an existing Dask
scheduler. What a task is sent: the test's files as bytes (recordings, and the DBC, signal map,
vehicle and prior files when given; about 0.5 MB per 60 s chirp in BLF) and the options; what
it returns: the identification JSON (about 50 kB with curves and profiles), the diagnosis JSON
and one table row. Nothing is read from a shared file system and nothing stays on the workers,
so any scheduler's workers serve, and the client's network carries a few MB per test against
a minute of computing.

With ``--profile-points N`` the likelihood profiles of each identification become tasks of their
own, one per free parameter, spread over the same cluster while the identification's task waits
(it leaves its worker thread to them).

Results: ``OUT/fleet.csv`` (one row per test: vehicle, date, status, NRMSEs, each parameter
with its interval and verdict, the diagnosis), ``OUT/tests/<test>.json`` (the identification)
and ``<test>.diagnosis.json``, and the fleet view (:mod:`dtid.identification.fleet`):
``OUT/fleet.png`` and ``OUT/fleet.html``.

The vehicle of a test is the ``vehicle`` of its recording's metadata when it has one, else the
name of the folder holding the test (a fleet kept as ``FLEET/VEHICLE/SESSION/``); its date is
the metadata's ``started_utc``, else the recording's modification time.
"""

from __future__ import annotations

import csv
import datetime
import os
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dtid.acquisition.logfile import SUPPORTED_SUFFIXES, recordings_in
from dtid.acquisition.metadata import read_metadata
from dtid.errors import ConfigError, DtidError, RecordingError
from dtid.identification.fleet import fleet_view
from dtid.identification.search.identify import SearchSettings
from dtid.identification.search.parameterization import THETA_NAMES
from dtid.jsonfile import write_json

TABLE = "fleet.csv"
"""The results table's file name in the output folder."""
SCHEDULER_TIMEOUT_S = 10.0
"""How long a given Dask scheduler is tried before it is named unreachable, s."""


@dataclass(frozen=True)
class TestSpec:
    """One test of the batch.

    Attributes
    ----------
    name
        Unique name (the session directory's or the recording's stem; made unique).
    vehicle, date
        The vehicle and the test's start (ISO 8601), as the module notes say.
    recordings
        The test's recordings.
    """

    name: str
    vehicle: str
    date: str
    recordings: tuple[Path, ...]


@dataclass(frozen=True)
class BatchOptions:
    """What every test is identified with (the options of ``dtid identify``).

    Attributes
    ----------
    dbc, signals, vehicle, prior
        Files as in ``dtid identify`` (None: the product's defaults).
    fixed, bounds, span, settings, profile_points
        As in ``dtid identify``.
    diagnose
        Also diagnose each test (``dtid diagnose``, the mechanism library off: locate only).
    threads
        Numba threads per task (one per Dask worker thread is right).
    """

    dbc: Path | None = None
    signals: Path | None = None
    vehicle: Path | None = None
    prior: Path | None = None
    fixed: Mapping[str, float] = field(default_factory=dict)
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    span: float | None = None
    settings: SearchSettings = field(default_factory=SearchSettings)
    profile_points: int = 5
    diagnose: bool = False
    threads: int = 1


def find_tests(paths: Sequence[str | os.PathLike[str]]) -> list[TestSpec]:
    """The tests of the arguments: each a session directory or a recording.

    Raises
    ------
    RecordingError
        If an argument does not exist or a directory holds no recording.
    ConfigError
        If an argument is given twice.
    """
    tests, names, seen = [], set(), {}
    for argument in map(Path, paths):
        if argument.resolve() in seen:  # a shell glob and a name, or a folder given twice
            raise ConfigError(
                f"{argument} is given twice (as {seen[argument.resolve()]} before): each test is "
                "a row of the fleet table once"
            )
        seen[argument.resolve()] = argument
        if argument.is_dir():
            recordings = tuple(recordings_in(argument))
            if not recordings:
                raise RecordingError(
                    f"{argument} holds no recording ({', '.join(SUPPORTED_SUFFIXES)})"
                )
            name, folder = argument.resolve().name, argument.resolve().parent
        elif argument.exists():
            recordings, name, folder = (argument,), argument.stem, argument.resolve().parent
        else:
            raise RecordingError(
                f"{argument} does not exist: give session directories or recordings"
            )
        unique, number = name, 1
        while unique in names:
            number += 1
            unique = f"{name}-{number}"
        names.add(unique)
        metadata = _metadata(recordings[0])
        vehicle = str(metadata.get("vehicle") or folder.name)
        date = metadata.get("started_utc") or datetime.datetime.fromtimestamp(
            recordings[0].stat().st_mtime, datetime.UTC
        ).isoformat(timespec="seconds")
        tests.append(TestSpec(unique, vehicle, str(date), recordings))
    return tests


def _metadata(path: Path) -> dict[str, Any]:
    try:
        return read_metadata(path) or {}
    except RecordingError:
        return {}


def identify_test(
    name: str, files: Mapping[str, bytes], originals: Mapping[str, str], options: BatchOptions
) -> dict[str, Any]:
    """The Dask task: identify (and diagnose) one test from its files' bytes.

    Parameters
    ----------
    name
        The test's name.
    files
        File name -> content: the recordings first (in order), then the option files, each
        under the name its option gives it (``dbc:NAME`` and so on).
    originals
        File name -> the path it had on the client, so that the results name the recordings as
        ``dtid identify`` would.
    options
        The batch's options.

    Returns
    -------
    dict
        ``identification`` (the JSON document, or None), ``diagnosis`` (or None), ``error`` (a
        user's mistake or an analysis that failed, or None), ``seconds``, ``profile_tasks``
        (the profiles computed as tasks of their own on the cluster).
    """
    import numba

    from dtid.identification.diagnosis.diagnose import diagnose_report
    from dtid.workflow import identify

    numba.set_num_threads(max(1, min(options.threads, numba.config.NUMBA_NUM_THREADS)))
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dtid-batch-") as folder:
        paths: dict[str, Path] = {}
        for key, content in files.items():
            role, _, filename = key.rpartition(":")
            path = Path(folder) / (role or "recordings") / filename
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(content)
            paths[key] = path
        recordings = [paths[k] for k in files if ":" not in k]
        spread = options.profile_points > 0 and _on_a_worker()
        try:
            report = identify(
                recordings,
                dbc=paths.get(f"dbc:{options.dbc.name}") if options.dbc else None,
                signals=paths.get(f"signals:{options.signals.name}") if options.signals else None,
                vehicle=paths.get(f"vehicle:{options.vehicle.name}") if options.vehicle else None,
                prior=paths.get(f"prior:{options.prior.name}") if options.prior else None,
                fixed=dict(options.fixed),
                bounds=dict(options.bounds),
                settings=options.settings,
                profile_points=options.profile_points,
                span=options.span,
                profile_map=_cluster_map if spread else None,
            )
            document = report.as_dict()
            diagnosis = (
                diagnose_report(report, mechanisms=()).as_dict() if options.diagnose else None
            )
            error = None
        except DtidError as failure:
            document, diagnosis, error = None, None, str(failure)
        renamed = {str(paths[k]): originals[k] for k in files if ":" not in k}
    return {
        "identification": _renamed(document, renamed),
        "diagnosis": _renamed(diagnosis, renamed),
        "error": _renamed(error, renamed),
        "seconds": time.perf_counter() - start,
        "profile_tasks": len((document or {}).get("profiles", {})) if spread else 0,
    }


def _on_a_worker() -> bool:
    """True inside a Dask worker's task (False when :func:`identify_test` is called directly)."""
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        return False
    return True


def _cluster_map(function: Callable[[str], Any], names: list[str]) -> list[Any]:
    """The profiles of one identification as tasks of their own, spread over the cluster: the
    identification's task leaves its worker thread to them while it waits."""
    from distributed import worker_client

    with worker_client() as client:
        futures = client.map(_single_threaded, [function] * len(names), names, pure=False)
        return list(client.gather(futures))


def _single_threaded(function: Callable[[str], Any], name: str) -> Any:
    """``function(name)`` with numba on one thread (one task per worker thread)."""
    import numba

    numba.set_num_threads(1)
    return function(name)


def _renamed(value: Any, names: Mapping[str, str]) -> Any:
    """``value`` with the task's temporary paths replaced by the client's (keys and strings)."""
    if isinstance(value, str):
        for temporary, original in names.items():
            value = value.replace(temporary, original)
        return value
    if isinstance(value, dict):
        return {_renamed(k, names): _renamed(v, names) for k, v in value.items()}
    if isinstance(value, list):
        return [_renamed(v, names) for v in value]
    return value


def task_files(test: TestSpec, options: BatchOptions) -> tuple[dict[str, bytes], dict[str, str]]:
    """What :func:`identify_test` is sent for a test: its files' bytes by key (the recordings,
    then ``dbc:``, ``signals:``, ``vehicle:``, ``prior:`` files) and each recording key's path on
    the client."""
    files, originals = {}, {}
    for path in test.recordings:
        key = path.name if path.name not in files else f"{len(files)}-{path.name}"
        files[key] = path.read_bytes()
        originals[key] = str(path)
    for role in ("dbc", "signals", "vehicle", "prior"):
        path = getattr(options, role)
        if path is not None:
            try:
                files[f"{role}:{path.name}"] = Path(path).read_bytes()
            except OSError as error:
                raise ConfigError(f"--{role} {path}: {error.strerror or error}") from None
    return files, originals


def run_batch(
    tests: Sequence[TestSpec],
    options: BatchOptions,
    out: str | os.PathLike[str],
    scheduler: str | None = None,
    workers: int = 2,
    report: Callable[[str], None] = lambda line: None,
) -> list[dict[str, Any]]:
    """Identify every test on Dask and write the table, the JSONs and the fleet view.

    Parameters
    ----------
    tests
        The tests (:func:`find_tests`).
    options
        What each is identified with.
    out
        Output folder (made when missing).
    scheduler
        Address of an existing Dask scheduler; None: a local cluster of ``workers`` processes
        with one thread each.
    workers
        Processes of the local cluster.
    report
        Called with one line per test as it finishes.

    Returns
    -------
    list of dict
        The table's rows, in the tests' order.

    Raises
    ------
    ConfigError
        If Dask is not installed or the scheduler cannot be reached.
    """
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ConfigError(
            "dtid batch needs Dask: pip install 'drivetrain-id[fleet]' (dask[distributed])"
        ) from None
    out = Path(out)
    try:
        (out / "tests").mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(
            f"cannot make the output folder {out}/tests: {error.strerror or error} (--out names a "
            "folder)"
        ) from None
    cluster = None
    try:
        if scheduler is None:
            cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            client = Client(cluster)
        else:
            client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
    except (OSError, TimeoutError) as error:
        if cluster is not None:
            cluster.close()
        raise ConfigError(f"cannot reach the Dask scheduler {scheduler}: {error}") from None
    rows: dict[str, dict[str, Any]] = {}
    try:
        futures = {}
        for test in tests:
            files, originals = task_files(test, options)
            future = client.submit(identify_test, test.name, files, originals, options, pure=False)
            futures[future] = test
        for future in as_completed(futures):
            test = futures[future]
            try:
                outcome = future.result()
            except Exception as error:  # a failure in the product, not in the test's data
                outcome = {
                    "identification": None,
                    "diagnosis": None,
                    "error": f"internal error ({type(error).__name__}: {error}); please report it",
                    "seconds": 0.0,
                    "profile_tasks": 0,
                }
            rows[test.name] = _row(test, outcome)
            _write_documents(out / "tests", test, outcome)
            report(_line(rows[test.name]))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    table = [rows[t.name] for t in tests]
    write_table(out / TABLE, table)
    fleet_view(table, out)
    return table


def _row(test: TestSpec, outcome: Mapping[str, Any]) -> dict[str, Any]:
    document = outcome["identification"]
    row: dict[str, Any] = {
        "test": test.name,
        "vehicle": test.vehicle,
        "date": test.date,
        "recordings": " ".join(str(p) for p in test.recordings),
        "status": "ok" if document else "error",
        "error": outcome["error"] or "",
        "seconds": round(outcome["seconds"], 1),
        "profile_tasks": outcome.get("profile_tasks", 0),
    }
    if document:
        nrmse = document["nrmse"]
        row["nrmse_fit"] = _mean(nrmse["fit"].values())
        row["nrmse_validation"] = _mean(nrmse["validation"].values())
        for name in THETA_NAMES:
            interval = document["intervals"].get(name) or {}
            row[name] = document["parameters"][name]
            row[f"{name}_lower"] = interval.get("lower")
            row[f"{name}_upper"] = interval.get("upper")
            row[f"{name}_verdict"] = document["identifiable"].get(
                name, "fixed" if name in document["fixed"] else ""
            )
    diagnosis = outcome["diagnosis"]
    if diagnosis:
        row["adequate"] = diagnosis["adequate"]
        row["mismatch_bands"] = len(diagnosis["mismatch"])
    return row


def _mean(values: Any) -> float | None:
    values = list(values)
    return sum(values) / len(values) if values else None


def _line(row: Mapping[str, Any]) -> str:
    if row["status"] != "ok":
        return f"{row['test']} ({row['vehicle']}): error: {row['error']}"
    return (
        f"{row['test']} ({row['vehicle']}, {row['date'][:10]}): c12 {row['c12']:.4g}, "
        f"eps12 {row['eps12']:.4g}, d12 {row['d12']:.4g}; NRMSE fit {row['nrmse_fit']:.3f}"
        f" in {row['seconds']:.0f} s"
    )


def _write_documents(folder: Path, test: TestSpec, outcome: Mapping[str, Any]) -> None:
    if outcome["identification"] is not None:
        write_json(folder / f"{test.name}.json", outcome["identification"])
    if outcome["diagnosis"] is not None:
        write_json(folder / f"{test.name}.diagnosis.json", outcome["diagnosis"])


def write_table(path: Path, rows: Sequence[Mapping[str, Any]]) -> Path:
    """The results as CSV: every column any row has, in first-seen order."""
    columns: dict[str, None] = {}
    for row in rows:
        columns.update(dict.fromkeys(row))
    try:
        with path.open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(columns))
            writer.writeheader()
            writer.writerows(rows)
    except OSError as error:
        raise RecordingError(f"cannot write {path}: {error.strerror or error}") from None
    return path
