"""What the worker writes beside a session's log: the result, its diagnosis, the HTML report.

No transport here (see :mod:`dtid.identification.service.worker`). Each writer raises
:class:`dtid.errors.DtidError` when a file cannot be written and returns the files it wrote; the
worker publishes either.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dtid.errors import DtidError
from dtid.identification.html_report import DIAGNOSIS_FILE
from dtid.identification.pipeline import IdentificationReport
from dtid.identification.service.live import LiveSession
from dtid.jsonfile import write_json

if TYPE_CHECKING:
    from dtid.identification.diagnosis.diagnose import Diagnosis

logger = logging.getLogger(__name__)

CLOSE_WAIT_S = 30.0
"""Longest wall time the worker waits, after a session's end, for the daemon to close its log
(an .mf4 session's conversion included) before it rewrites the report from the files."""


def write_result(
    report: IdentificationReport,
    document: Mapping[str, Any],
    json_path: Path,
    plot_path: Path | None,
) -> list[str]:
    """Write the identification's JSON document and, unless ``plot_path`` is None, its Fig. 6;
    the files written."""
    write_json(json_path, dict(document))
    written = [str(json_path)]
    if plot_path is not None:
        from dtid.identification.plots import plot_fit

        plot_fit(*report.fit_curves(), plot_path)
        written.append(str(plot_path))
    return written


def write_diagnosis(diagnosis: Diagnosis, folder: Path, plot: bool) -> list[str]:
    """Write a diagnosis's JSON document (:data:`DIAGNOSIS_FILE`) and, with ``plot``, its mismatch
    map beside it; the files written, the JSON first."""
    path = folder / DIAGNOSIS_FILE
    write_json(path, diagnosis.as_dict())
    written = [str(path)]
    if plot:
        from dtid.identification.diagnosis.figure import plot_mismatch

        written.append(str(plot_mismatch(diagnosis, path.with_suffix(".png"))))
    return written


def write_session_report(
    live: LiveSession, result: Mapping[str, Any], diagnosis: Path | None
) -> Path:
    """Write the session's HTML report beside its log, from the live data, the result and the
    diagnosis JSON (with its figure, if drawn); the file written."""
    from dtid.identification.html_report import REPORT_FILE, ReportInputs, write_report

    path = live.log_path.parent / REPORT_FILE
    figure = diagnosis.with_suffix(".png") if diagnosis is not None else None
    inputs = ReportInputs(
        recordings=[live.recording()],
        files=[live.log_path],
        live=True,
        identification=dict(result),
        diagnosis=json.loads(diagnosis.read_text()) if diagnosis is not None else None,
        diagnosis_figure=figure if figure is not None and figure.exists() else None,
        title=live.log_path.parent.name,
    )
    write_report(inputs, path)
    return path


def rewrite_report(live: LiveSession, identification: Path, diagnosis: Path | None) -> None:
    """The session's report again, from the closed log, once the daemon's metadata says it is
    closed (the end event comes before the close); waits :data:`CLOSE_WAIT_S` at most. Without
    metadata beside the log (a log that is not the daemon's) the live report stays. Run in a
    thread of its own: failures are logged, not raised."""
    from dtid.acquisition.metadata import session_log_metadata
    from dtid.identification.html_report import REPORT_FILE, gather, write_report

    log = live.log_path
    deadline = time.monotonic() + CLOSE_WAIT_S
    while True:
        try:
            metadata, being_written = session_log_metadata(log), False
        except DtidError:  # an .mf4 file still being written from its journal
            metadata, being_written = None, True
        if metadata is None and not being_written:
            return
        if metadata is not None and (metadata.get("integrity") or {}).get("closed"):
            break
        if time.monotonic() > deadline:
            logger.warning("the daemon did not close %s within %.0f s", log, CLOSE_WAIT_S)
            return
        time.sleep(0.2)
    try:
        inputs = gather([log], live.interface, identification, diagnosis)
        inputs.title = log.parent.name
        write_report(inputs, log.parent / REPORT_FILE)
    except DtidError as error:
        logger.warning("the session's report from its closed log: %s", error)
