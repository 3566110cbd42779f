"""The test report an engineer forwards: one self-contained HTML file (``dtid report``).

Everything is inside the file, so it opens anywhere without a network: the figures are PNG
images in ``data:`` URLs, the style sheet is inline, and there is no script. Sections:

1. the test: per recording its format, frames, time span, integrity, the session's metadata
   (source, plan, how the test ended, the health counters) and the chirp runs found;
2. the frequency responses of every run, as the paper's Fig. 3;
3. the identification: the parameter table with units, 95 % intervals and verdicts (and, for
   an adaptive campaign's round, each target test's outcome), the NRMSEs, the fit as Fig. 6
   and the likelihood profiles as Fig. 5 (from ``identification.json``'s ``curves``,
   ``profiles`` and ``target_tests``);
4. the diagnosis, when there is one: its verdict, the mismatch bands, the mechanisms accepted,
   left unexplained or indistinguishable, and its figure (the PNG beside ``diagnosis.json``);
5. versions: the software that made the report and the recordings, the DBC and signal map
   (SHA-256), and each recording's SHA-256.

A section whose input is missing says what is missing and the command that makes it.
"""

from __future__ import annotations

import base64
import datetime
import hashlib
import html
import io
import json
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from dtid.acquisition.logfile import SUPPORTED_SUFFIXES, recordings_in
from dtid.acquisition.metadata import session_log_metadata, software_versions
from dtid.dbc.interface import VehicleInterface
from dtid.errors import DtidError, RecordingError
from dtid.identification.frf.closed_loop import estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.plots import fit_figure, frf_figure, profiles_figure
from dtid.identification.samples.recording import Recording, load_recording

logger = logging.getLogger(__name__)

IDENTIFICATION_FILE = "identification.json"
DIAGNOSIS_FILE = "diagnosis.json"
REPORT_FILE = "report.html"
"""File names in a session directory (the worker's)."""

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 62em; color: #222; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }
th { background: #f2f2f2; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
.summary { background: #f6f8fa; border-left: 4px solid #3a6ea5; padding: 0.6em 1em; }
.warn { color: #a03000; } .missing { color: #777; font-style: italic; }
code { background: #f2f2f2; padding: 0 0.2em; }
"""


@dataclass
class ReportInputs:
    """What a report is made of.

    Attributes
    ----------
    recordings
        The CAN recordings of the test, decoded.
    files
        Their files (for the metadata that travels with them and their SHA-256).
    live
        True when the files are still being written (the worker's report during a session):
        no SHA-256 is taken, and the metadata is what the daemon wrote when the session began.
    identification
        ``dtid identify``'s JSON document, or None.
    diagnosis
        ``dtid diagnose``'s JSON document, or None.
    diagnosis_figure
        The diagnosis's PNG figure, or None.
    title
        The report's title (the session's name by default).
    """

    recordings: list[Recording]
    files: list[Path]
    live: bool = False
    identification: dict[str, Any] | None = None
    diagnosis: dict[str, Any] | None = None
    diagnosis_figure: Path | None = None
    title: str = ""


def gather(
    paths: Sequence[str | os.PathLike[str]],
    interface: VehicleInterface,
    identification: str | os.PathLike[str] | None = None,
    diagnosis: str | os.PathLike[str] | None = None,
) -> ReportInputs:
    """Collect a report's inputs from a session directory or from recordings.

    Parameters
    ----------
    paths
        One session directory (the daemon's: its log, and the worker's ``identification.json``
        and ``diagnosis.json`` when present), or recordings.
    interface
        The DBC and signal map that read the recordings.
    identification, diagnosis
        JSON documents to use instead of those found in the session directory (for recordings:
        beside the first recording).

    Raises
    ------
    RecordingError
        If a path does not exist, a directory holds no recording, or a JSON is unreadable.
    """
    paths = [Path(p) for p in paths]
    for path in paths:
        if not path.exists():
            raise RecordingError(f"{path} does not exist; give a session directory or recordings")
    if len(paths) == 1 and paths[0].is_dir():
        folder = paths[0]
        recordings = recordings_in(folder)
        if not recordings:
            raise RecordingError(
                f"session directory {folder} holds no recording ({', '.join(SUPPORTED_SUFFIXES)})"
            )
        title = folder.resolve().name
    else:
        for path in paths:
            if path.is_dir():
                raise RecordingError(
                    f"{path} is a directory: give either one session directory or recordings"
                )
        recordings, folder, title = paths, paths[0].parent, paths[0].stem
    id_path = Path(identification) if identification else folder / IDENTIFICATION_FILE
    dg_path = Path(diagnosis) if diagnosis else folder / DIAGNOSIS_FILE
    figure = dg_path.with_suffix(".png")
    documents = {
        "identification": _json(id_path, required=identification is not None),
        "diagnosis": _json(dg_path, required=diagnosis is not None),
    }
    for kind, path, given in (
        ("identification", id_path, identification),
        ("diagnosis", dg_path, diagnosis),
    ):
        mismatch = _not_a(documents[kind], kind, path) or _not_of_these(
            documents[kind], kind, path, recordings
        )
        if mismatch and given:
            raise RecordingError(mismatch)
        if mismatch:  # found beside the recordings, not asked for
            logger.warning("%s; left out of the report", mismatch)
            documents[kind] = None
    return ReportInputs(
        recordings=[load_recording(p, interface) for p in recordings],
        files=recordings,
        identification=documents["identification"],
        diagnosis=documents["diagnosis"],
        diagnosis_figure=figure if figure.exists() else None,
        title=title,
    )


def _not_a(document: dict[str, Any] | None, kind: str, path: Path) -> str | None:
    """What to say where ``document`` is not the ``kind`` of JSON the page reads (another
    command's, or edited by hand): its keys would be shown as nothing, or fail to format."""
    if document is None:
        return None
    if kind == "identification":
        parameters = document.get("parameters")
        runs = (document.get("nrmse") or {}).get("fit") if isinstance(document, dict) else None
        fits = (
            isinstance(parameters, dict)
            and all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in parameters.values()
            )
            and isinstance(runs, dict)
            and bool(runs)  # the runs it was identified from: the page's fit and its recordings
        )
        command = "dtid identify --json"
    else:
        fits = isinstance(document.get("adequate"), bool) and isinstance(
            document.get("verdict"), dict
        )
        command = "dtid diagnose --json"
    if fits and (kind == "diagnosis" or document["parameters"]):
        return None
    return f"{path} is not {kind} JSON as `{command}` writes it: give that file"


def _not_of_these(
    document: dict[str, Any] | None, kind: str, path: Path, recordings: Sequence[Path]
) -> str | None:
    """What to say where ``document`` (an identification's or a diagnosis's JSON, or None) was
    made of none of ``recordings``, by file name (a session directory may have moved): the page
    would put one test's parameters beside another test's FRFs. None where it was, or where
    it does not say."""
    if document is None:
        return None
    nrmse = document.get("nrmse") if kind == "identification" else None
    if kind == "diagnosis":
        nrmse = (document.get("baseline") or {}).get("nrmse")
    named = {
        Path(str(label).split(" @ ")[0]).name
        for runs in (nrmse or {}).values()
        if isinstance(runs, dict)
        for label in runs
    }
    given = {p.name for p in recordings}
    if named and not named & given:
        return (
            f"{path} is the {kind} of {', '.join(sorted(named))}, not of "
            f"{', '.join(sorted(given))}: give the {kind} made of these recordings"
        )
    return None


def _json(path: Path, required: bool) -> dict[str, Any] | None:
    if not path.exists():
        if required:
            raise RecordingError(f"{path} does not exist")
        return None
    try:
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RecordingError(f"{path} is not readable JSON ({error})") from error
    if not isinstance(document, dict):
        raise RecordingError(f"{path} is not a JSON object")
    return document


def write_report(inputs: ReportInputs, path: str | os.PathLike[str]) -> Path:
    """Write the report (see the module notes) to ``path``, whole or not at all.

    Raises
    ------
    RecordingError
        If a recording cannot be read or the file cannot be written.
    """
    return write_html(path, render(inputs))


def write_html(path: str | os.PathLike[str], text: str) -> Path:
    """Write a page to ``path``, whole or not at all.

    Raises
    ------
    RecordingError
        If the file cannot be written.
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        temporary.write_text(text, encoding="utf-8")
        temporary.replace(path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        raise RecordingError(f"cannot write {path}: {error.strerror or error}") from None
    return path


def render(inputs: ReportInputs) -> str:
    """The report's HTML text."""
    recordings = inputs.recordings
    metadata = [_metadata(p) for p in inputs.files]
    sections = [
        _summary(inputs, recordings, metadata),
        _test_section(recordings, metadata, inputs.live),
        _frf_section(recordings),
        _identification_section(inputs.identification, inputs.files),
        _diagnosis_section(inputs.diagnosis, inputs.diagnosis_figure, inputs.files),
        _versions_section(inputs.files, metadata, inputs.live),
    ]
    return page(f"drivetrain-id test report: {inputs.title}", sections)


def page(title: str, sections: Sequence[str]) -> str:
    """A whole self-contained HTML page: the title, the sections, who made it and when."""
    return (
        "<!DOCTYPE html>\n<html lang='en'>\n<head>\n<meta charset='utf-8'>\n"
        f"<title>{escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        f"<h1>{escape(title)}</h1>\n"
        + "\n".join(sections)
        + f"\n<p class='missing'>Made {_now()} by drivetrain-id "
        f"{escape(software_versions()['drivetrain-id'])}.</p>\n</body>\n</html>\n"
    )


# --- sections -----------------------------------------------------------------------------------


def _summary(
    inputs: ReportInputs, recordings: list[Recording], metadata: list[dict[str, Any] | None]
) -> str:
    lines = []
    runs = sum(len(_runs(r)) for r in recordings)
    lines.append(f"{len(recordings)} recording(s), {runs} chirp run(s).")
    for path, meta in zip(inputs.files, metadata, strict=True):
        outcome = (meta or {}).get("outcome")
        if outcome and outcome.get("status") == "aborted":
            lines.append(
                f"<span class='warn'>The test of {escape(path.name)} was aborted "
                f"({escape(outcome.get('reason'))}).</span>"
            )
    identification = inputs.identification
    if identification:
        validation = identification.get("nrmse", {}).get("validation") or {}
        fit = identification.get("nrmse", {}).get("fit") or {}
        lines.append(
            f"Identified: fit NRMSE {_join(fit.values())}"
            + (f", validation NRMSE {_join(validation.values())}." if validation else ".")
        )
    if inputs.diagnosis:
        verdict = inputs.diagnosis.get("verdict", {})
        lines.append(f"Diagnosis: {escape(verdict.get('explanation', ''))}")
    return "<div class='summary' id='summary'>" + " ".join(lines) + "</div>"


def _test_section(
    recordings: list[Recording], metadata: list[dict[str, Any] | None], live: bool
) -> str:
    parts = ["<h2 id='test'>The test</h2>"]
    if live:
        parts.append(
            "<p>Written by the worker while the session ran, from its live data; it is "
            "rewritten from the files once the daemon has closed the log.</p>"
        )
    for recording, meta in zip(recordings, metadata, strict=True):
        integrity = recording.integrity
        state = (
            "intact"
            if integrity.intact
            else "<span class='warn'>"
            + escape(
                "; ".join(
                    [*([integrity.cut] if integrity.cut else [])]
                    + [d.describe() for d in integrity.damaged]
                )
            )
            + "</span>"
        )
        rows = [
            ("file", escape(recording.path.name)),
            ("frames", f"{recording.n_frames}"),
            ("time span", f"{recording.duration_s:.1f} s"),
            ("integrity", state),
        ]
        if meta:
            kept = meta.get("integrity") or {}
            rows += [
                ("made by", escape(f"{meta.get('source')}, started {meta.get('started_utc')}")),
                (
                    "log kept",
                    escape(
                        f"{kept.get('frames')} frames, {kept.get('lost')} lost, "
                        + ("closed cleanly" if kept.get("closed") else "not closed cleanly")
                        + (f" ({kept['failure']})" if kept.get("failure") else "")
                    ),
                ),
            ]
            plan = meta.get("plan")
            if plan:
                rows.append(("plan", escape(_plan(plan))))
            outcome = meta.get("outcome")
            if outcome:
                ended = outcome.get("status", "")
                if outcome.get("reason"):
                    ended += f" ({outcome['reason']})"
                rows.append(("ended", escape(ended)))
                health = outcome.get("health") or {}
                rows.append(("health", escape(", ".join(f"{k} {v}" for k, v in health.items()))))
        else:
            rows.append(("metadata", "<span class='missing'>none travels with this file</span>"))
        parts.append(table_html(["", ""], rows, header=False))
        runs = _runs(recording)
        if runs:
            parts.append(
                table_html(
                    ["chirp", "amplitude / N*m", "band / Hz", "from / s", "to / s"],
                    [
                        (
                            str(i + 1),
                            f"{run.amplitude_nm:g}",
                            f"{run.f1_hz:.2f} - {run.f2_hz:.2f}",
                            f"{run.start_s:.1f}",
                            f"{run.end_s:.1f}",
                        )
                        for i, run in enumerate(runs)
                    ],
                )
            )
        else:
            parts.append("<p class='warn'>No chirp run in the test torque.</p>")
    return "\n".join(parts)


def _frf_section(recordings: list[Recording]) -> str:
    estimates = []
    problems = []
    for recording in recordings:
        if "test_torque" not in recording.roles:
            continue
        data = recording.test_data()
        for run in find_runs(data.test_torque):
            try:
                estimates.append(estimate_frf(data, run))
            except DtidError as error:
                problems.append(f"{recording.path.name} @ {run.amplitude_nm:g} N*m: {error}")
    parts = ["<h2 id='frf'>Frequency responses</h2>"]
    if estimates:
        parts.append(
            figure_html(
                frf_figure(estimates),
                "frf",
                "|G_DRV|, |G_ENG| and the coherence of every chirp run (the paper's Fig. 3).",
            )
        )
    else:
        parts.append("<p class='missing'>No frequency response could be estimated.</p>")
    parts += [f"<p class='warn'>{escape(p)}</p>" for p in problems]
    return "\n".join(parts)


def _identification_section(document: dict[str, Any] | None, recordings: list[Path]) -> str:
    parts = ["<h2 id='identification'>Identification</h2>"]
    if document is None:
        command = "dtid identify " + " ".join(p.name for p in recordings) + " --json "
        parts.append(
            "<p class='missing'>Not identified. Make it with <code>"
            + escape(command + IDENTIFICATION_FILE)
            + "</code> (beside the recordings) or pass <code>--identification</code>.</p>"
        )
        return "\n".join(parts)
    parameters = document.get("parameters", {})
    units = document.get("units", {})
    intervals = document.get("intervals", {})
    verdicts = document.get("identifiable", {})
    fixed = document.get("fixed", {})
    tests = document.get("target_tests") or {}
    headers = ["parameter", "value", "unit", "95 % interval", "identifiable"]
    headers += ["target test"] if tests else []
    rows = []
    for name, value in parameters.items():
        interval = intervals.get(name) or tests.get(name, {}).get("interval")
        shown = "-"
        if interval:
            shown = f"{_num(interval.get('lower'))} - {_num(interval.get('upper'))}"
        row = [
            escape(name),
            _num(value),
            escape(units.get(name, "")),
            shown,
            escape("fixed" if name in fixed else verdicts.get(name, "-")),
        ]
        if tests:
            row.append(escape(_target_cell(tests[name])) if name in tests else "-")
        rows.append(row)
    parts.append(table_html(headers, rows, numeric=(1,)))
    for name, edge in (document.get("at_bounds") or {}).items():
        unit = "" if units.get(name, "1") == "1" else f" {escape(units[name])}"
        parts.append(
            f"<p class='warn'>{escape(name)} ended at the {escape(edge['side'])} end of its"
            f" search box ({_num(edge['lower'])} - {_num(edge['upper'])}{unit}): the vehicle"
            " may lie beyond it, and the parameters that trade with it are bent to make up."
            " Widen the box with <code>--bounds</code> if it can.</p>"
        )
    if tests:
        parts.append(
            "<p>Target tests (an adaptive campaign's round): the likelihood-ratio test at the"
            " estimate less and plus its target. Confirmed where both ends are rejected: the 95 %"
            " interval lies within the target. Its interval is read from the points tested"
            " where no profile was made.</p>"
        )
    nrmse = document.get("nrmse", {})
    nrmse_rows = [
        (escape(label), role, f"{value:.4f}")
        for role in ("fit", "validation")
        for label, value in (nrmse.get(role) or {}).items()
    ]
    if nrmse_rows:
        parts.append(table_html(["run", "role", "NRMSE"], nrmse_rows, numeric=(2,)))
    comparison = document.get("comparison")
    if comparison:  # dtid identify --compare FILE
        css = " class='warn'" if comparison.get("fits_worse") else ""
        parts.append(f"<p{css}>Compared: {escape(str(comparison.get('sentence', '')))}.</p>")
    curves = document.get("curves") or []
    if curves:
        measured = [
            SimpleNamespace(
                frequency_hz=np.asarray(c["frequency_hz"]),
                drv_db=np.asarray(c["measured_db"]),
                run=SimpleNamespace(amplitude_nm=c["amplitude_nm"]),
            )
            for c in curves
        ]
        figure = fit_figure(
            measured,
            [np.asarray(c["model_db"] or np.full(len(c["frequency_hz"]), np.nan)) for c in curves],
            [c["role"] for c in curves],
        )
        parts.append(
            figure_html(
                figure, "fit", "Measured and identified |G_DRV| per run (the paper's Fig. 6)."
            )
        )
    else:
        parts.append("<p class='missing'>The identification JSON holds no fit curves.</p>")
    profiles = document.get("profiles") or {}
    if profiles:
        shaped = {
            name: SimpleNamespace(
                values=np.asarray(p["values"]),
                objective=np.asarray(p["objective"], dtype=float),  # null: could not idle
                verdict=verdicts.get(name, ""),
            )
            for name, p in profiles.items()
        }
        parts.append(
            figure_html(
                profiles_figure(shaped), "profiles", "Likelihood profiles (the paper's Fig. 5)."
            )
        )
    else:
        parts.append(
            "<p class='missing'>No profiles (identified with <code>--profile-points 0</code>).</p>"
        )
    return "\n".join(parts)


def _diagnosis_section(
    document: dict[str, Any] | None, figure: Path | None, recordings: list[Path]
) -> str:
    parts = ["<h2 id='diagnosis'>Diagnosis</h2>"]
    if document is None:
        command = "dtid diagnose " + " ".join(p.name for p in recordings)
        parts.append(
            "<p class='missing'>Not diagnosed. Make it with <code>"
            + escape(f"{command} --json {DIAGNOSIS_FILE} --plot diagnosis.png")
            + "</code>.</p>"
        )
        return "\n".join(parts)
    verdict = document.get("verdict", {})
    adequate = "yes" if document.get("adequate") else "no"
    parts.append(f"<p>{escape(verdict.get('explanation', ''))}</p>")
    parts.append(
        table_html(
            ["", ""],
            [
                ("the model explains the recordings", adequate),
                (
                    "mechanisms accepted",
                    escape(", ".join(verdict.get("mechanisms") or []) or "none"),
                ),
                (
                    "indistinguishable here",
                    escape(", ".join(verdict.get("indistinguishable") or []) or "none"),
                ),
                ("cylinders (torque factor by place in the firing order)", _cylinders(document)),
            ],
            header=False,
        )
    )
    bands = document.get("mismatch") or []
    if bands:
        parts.append(
            table_html(
                ["FRF", "amplitude / N*m", "band / Hz", "excess / dB", "p", "kind"],
                [
                    (
                        escape(b.get("frf", "")),
                        f"{b.get('amplitude_nm', 0):g}",
                        f"{b.get('f_lo_hz', 0):.2f} - {b.get('f_hi_hz', 0):.2f}",
                        f"{b.get('excess_db', 0):+.2f}",
                        f"{b.get('p_value', 0):.2g}",
                        "smooth trend" if b.get("kind") == "trend" else "bins",
                    )
                    for b in bands
                ],
                numeric=(3, 4),
            )
        )
    if figure is not None:
        data = base64.b64encode(figure.read_bytes()).decode("ascii")
        parts.append(
            "<figure id='fig-diagnosis'><img alt='mismatch map' "
            f"src='data:image/png;base64,{data}'><figcaption>The mismatch map: measured and model "
            "|G_DRV| over the standardised residual, before and after.</figcaption></figure>"
        )
    return "\n".join(parts)


def _cylinders(document: dict[str, Any]) -> str:
    """The strokes' verdict on the cylinders, as table text."""
    cylinders = document.get("cylinders")
    if not cylinders:
        return "not tested (no torque request on the bus)"
    factors = "; ".join(
        f"{escape(name)}: " + ", ".join(f"{f:.3f}" for f in values)
        for name, values in cylinders.get("factors", {}).items()
    )
    verdict = "unequal" if cylinders.get("significant") else "equal within their scatter"
    return f"{verdict} (p = {cylinders.get('p_value', 1.0):.2g}; {factors})"


def _versions_section(
    recordings: list[Path], metadata: list[dict[str, Any] | None], live: bool
) -> str:
    now = software_versions()
    rows = [(escape(name), escape(version)) for name, version in now.items()]
    parts = [
        "<h2 id='versions'>Software and data</h2>",
        "<p>This report was made with:</p>",
        table_html(["package", "version"], rows),
    ]
    data_rows = []
    for path, meta in zip(recordings, metadata, strict=True):
        recorded = (meta or {}).get("software") or {}
        interface = (meta or {}).get("interface") or {}
        dbc = interface.get("dbc") or {}
        signal_map = interface.get("signal_map") or {}
        data_rows.append(
            (
                escape(path.name),
                "(being written)" if live or not path.exists() else _sha256(path)[:16],
                escape(recorded.get("drivetrain-id", "-")),
                escape(f"{dbc.get('file', '-')} {str(dbc.get('sha256', ''))[:12]}"),
                escape(f"{signal_map.get('file', '-')} {str(signal_map.get('sha256', ''))[:12]}"),
            )
        )
    parts.append(
        table_html(
            ["recording", "SHA-256", "recorded with dtid", "DBC (SHA-256)", "signal map (SHA-256)"],
            data_rows,
        )
    )
    return "\n".join(parts)


# --- helpers ------------------------------------------------------------------------------------


def _metadata(path: Path) -> dict[str, Any] | None:
    """The recording's metadata; during an .mf4 session, its journal's."""
    try:
        return session_log_metadata(path)
    except RecordingError:
        return None


def _runs(recording: Recording) -> list:
    if "test_torque" not in recording.roles:
        return []
    return list(find_runs(recording.series("test_torque")))


def figure_html(figure: Any, name: str, caption: str) -> str:
    """A matplotlib figure as an embedded PNG, with its id ``fig-NAME`` and caption."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return (
        f"<figure id='fig-{name}'><img alt='{escape(name)}' src='data:image/png;base64,{data}'>"
        f"<figcaption>{escape(caption)}</figcaption></figure>"
    )


def table_html(
    headers: Sequence[str],
    rows: Sequence[Sequence[str]],
    header: bool = True,
    numeric: Sequence[int] = (),
) -> str:
    """A table of cells already escaped (``numeric`` columns right-aligned)."""
    head = "<tr>" + "".join(f"<th>{h}</th>" for h in headers) + "</tr>" if header else ""
    body = "".join(
        "<tr>"
        + "".join(
            f"<td class='num'>{cell}</td>" if i in numeric else f"<td>{cell}</td>"
            for i, cell in enumerate(row)
        )
        + "</tr>"
        for row in rows
    )
    return f"<table>{head}{body}</table>"


def _plan(plan: Mapping[str, Any]) -> str:
    amplitudes = plan.get("amplitudes_nm") or []
    return (
        f"chirps at {', '.join(f'{a:g}' for a in amplitudes)} N*m, "
        f"{plan.get('duration_s', '?')} s each, {plan.get('f1_hz', '?')} - "
        f"{plan.get('f2_hz', '?')} Hz"
    )


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _target_cell(test: dict[str, Any]) -> str:
    """A target test's outcome and the half-width it tested (% of the estimate; in the
    parameter's unit for an estimate of zero)."""
    estimate = test.get("estimate") or 0.0
    half = max((abs(end - estimate) for end in test.get("ends", []) if end is not None), default=0)
    width = f"+-{100.0 * half / abs(estimate):.3g} %" if estimate else f"+-{half:.3g}"
    if test.get("confirmed"):
        return f"confirmed at {width}"
    reasons = [
        f"the estimate is at its bound {side}" if end is None else f"the end {side} fits"
        for side, end, done in zip(
            ("below", "above"), test.get("ends", []), test.get("rejected", []), strict=True
        )
        if not done
    ]
    return f"not confirmed at {width}: " + ", ".join(reasons)


def _num(value: Any) -> str:
    if value is None:
        return "open"
    return f"{value:.4g}"


def _join(values: Any) -> str:
    return ", ".join(f"{v:.3f}" for v in values)


def escape(text: Any) -> str:
    """Text for HTML."""
    return html.escape(str(text), quote=True)


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
