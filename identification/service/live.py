"""The worker's view of one test session: events merged by ``seq``, data, FRFs, identification.

No transport here (see :mod:`dtid.identification.service.worker`): a :class:`EventLog` takes events
in any order, from the live stream or the daemon's replay, drops duplicates and hands them out in
``seq`` order, saying where a gap is; a :class:`LiveSession` applies them in that order and says
what can be computed now. Live and replayed events are the same events, so a worker that starts
late or restarts computes exactly what one that saw everything live computes.

The data of a session are built as ``dtid identify`` builds them from the daemon's log
(:func:`dtid.identification.samples.recording.recording_from_series`: times relative to the log's
first frame, rounded and sorted the same way), and the identification sees them only up to
:data:`dtid.identification.pipeline.HOLD_OUT_S` after the last identification chirp, so it can start
while the validation chirp is still being recorded and still give what ``dtid identify`` gives on
the whole log.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dtid.acquisition.stream import series_from_samples
from dtid.dbc.interface import VehicleInterface
from dtid.errors import DtidError
from dtid.identification.frf.closed_loop import DEFAULT_RESOLUTION_HZ, FrfEstimate, estimate_frf
from dtid.identification.frf.runs import ChirpRun, find_runs
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import (
    HOLD_OUT_S,
    RunSelection,
    cut_time,
    identification_runs,
    truncated,
    validation_runs,
)
from dtid.identification.samples.recording import Recording, recording_from_series, request_timeout
from dtid.identification.samples.testdata import TestData
from dtid.simulator.vehicle_data import VehicleData

logger = logging.getLogger(__name__)

ANALYSIS_ROLES = ("speed", "mean_torque", "test_torque", "torque_request")
"""Roles whose samples must have arrived up to a time before the data up to it are used."""
FRF_MARGIN_S = 0.5
"""Data needed past a chirp's end before its FRF is estimated, s (bus time): the vehicle's
frames answering the last requests arrive a little later, and a run ends only after a pause of
:data:`dtid.identification.frf.runs.MIN_PAUSE_S`."""


class EventLog:
    """The events of one session, merged by ``seq``: duplicates dropped, gaps found.

    Parameters
    ----------
    session
        The session id.
    """

    def __init__(self, session: str) -> None:
        self.session = session
        self.next_seq = 0
        """The first ``seq`` not yet handed out (everything below it was)."""
        self._waiting: dict[int, dict[str, Any]] = {}
        self.duplicates = 0

    def add(self, event: Mapping[str, Any]) -> bool:
        """Keep an event of this session; False for one already seen."""
        seq = int(event["seq"])
        if seq < self.next_seq or seq in self._waiting:
            self.duplicates += 1
            return False
        self._waiting[seq] = dict(event)
        return True

    def take(self) -> list[dict[str, Any]]:
        """The events that now follow without a gap, in ``seq`` order."""
        ready = []
        while self.next_seq in self._waiting:
            ready.append(self._waiting.pop(self.next_seq))
            self.next_seq += 1
        return ready

    @property
    def gap(self) -> bool:
        """True when later events arrived but ``next_seq`` is missing (ask the replay for it)."""
        return bool(self._waiting)


@dataclass
class Chirp:
    """A chirp of the plan as the phase events tell it (times relative to the log start, s)."""

    index: int
    amplitude_nm: float
    start_s: float
    end_s: float | None = None
    frf: FrfEstimate | None = None
    failed: str | None = None


@dataclass
class LiveSession:
    """What the worker knows of one session, from its events in ``seq`` order.

    Parameters
    ----------
    start
        The session's ``session`` event (seq 0).
    interface
        The vehicle interface of the session (for the mapped and missing roles).
    resolution_hz
        Welch resolution of the FRFs.
    vehicle
        What the model knows of the vehicle besides its drivetrain (the reference's by default).
    pauses_reported
        Pauses in the test-torque requests warned about so far.
    request_left_out
        Whether the torque request was found sampled otherwise than crank-synchronously and
        left out (warned about once a session).
    """

    start: Mapping[str, Any]
    interface: VehicleInterface
    resolution_hz: float = DEFAULT_RESOLUTION_HZ
    vehicle: VehicleData = field(default_factory=VehicleData)
    samples: list[Mapping[str, Any]] = field(default_factory=list)
    frames: int = 0
    last_t: dict[str, float] = field(default_factory=dict)
    chirps: dict[int, Chirp] = field(default_factory=dict)
    phase: str | None = None
    health: Mapping[str, Any] | None = None
    end: Mapping[str, Any] | None = None
    pauses_reported: int = 0
    request_left_out: bool = False

    @property
    def id(self) -> str:
        """The session id."""
        return str(self.start["session"])

    @property
    def log_path(self) -> Path:
        """The daemon's raw log of the session."""
        return Path(self.start["log_path"])

    @property
    def name(self) -> str:
        """The name the session's test has in reports: the log path as the daemon gave it."""
        return str(self.start["log_path"])

    @property
    def log_start_s(self) -> float:
        """Timestamp of the log's first frame, s."""
        return float(self.start["log_start_s"])

    @property
    def amplitudes_nm(self) -> tuple[float, ...]:
        """The identification amplitudes of the plan, N*m."""
        return tuple(float(a) for a in self.start["plan"]["amplitudes_nm"])

    @property
    def campaign(self) -> Mapping[str, Any] | None:
        """The ``campaign`` entry of an adaptive campaign's round
        (:func:`dtid.acquisition.campaign.round_fields`), None for a test of its own."""
        campaign = self.start.get("campaign")
        return campaign if isinstance(campaign, Mapping) else None

    @property
    def identify_nm(self) -> tuple[float, ...]:
        """The amplitudes that identify, N*m: the plan's, or in a campaign every round's."""
        campaign = self.campaign
        if campaign is not None and campaign.get("identify_nm"):
            return tuple(float(a) for a in campaign["identify_nm"])
        return self.amplitudes_nm

    @property
    def validation_index(self) -> int | None:
        """Index of the validation chirp in the plan, or None without one."""
        has = float(self.start["plan"].get("validation_nm") or 0.0) > 0
        return len(self.amplitudes_nm) if has else None

    @property
    def data_s(self) -> float:
        """Seconds of data received: the latest sample of any role, from the log start."""
        return max(self.last_t.values(), default=self.log_start_s) - self.log_start_s

    def apply(self, event: Mapping[str, Any]) -> None:
        """Take the next event of the session (in ``seq`` order)."""
        kind = event["kind"]
        if kind == "samples":
            self.samples.append(event)
            self.frames += int(event.get("frames", 0))
            for role, entry in event["roles"].items():
                if entry["t"]:
                    self.last_t[role] = max(self.last_t.get(role, -float("inf")), entry["t"][-1])
        elif kind == "phase":
            t = float(event["t_s"]) - self.log_start_s
            self.phase = event["phase"]
            chirp = event.get("chirp") if event["phase"] == "chirp" else None
            index = None if chirp is None else int(chirp)
            under_way = [c.index for c in self.chirps.values() if c.end_s is None]
            if index is not None and under_way == [index]:
                return  # the chirp under way, told again
            self._close_chirp(t)
            if index is not None:
                self.chirps[index] = Chirp(index, float(event.get("amplitude_nm") or 0.0), t)
        elif kind == "health":
            self.health = event
        elif kind == "end":
            if event.get("status") == "completed":
                self._close_chirp(float(event["t_s"]) - self.log_start_s)
            self.end = event

    def _close_chirp(self, t: float) -> None:
        for chirp in self.chirps.values():
            if chirp.end_s is None:
                chirp.end_s = t

    def complete(self, index: int) -> bool:
        """True when chirp ``index`` of the plan was recorded to its end."""
        chirp = self.chirps.get(index)
        return chirp is not None and chirp.end_s is not None

    def reaches(self, t_s: float) -> bool:
        """True when the samples of every analysis role the session carries arrived up to
        ``t_s`` (from the log start), or the session ended (nothing more will come)."""
        if self.end is not None:
            return True
        roles = [r for r in ANALYSIS_ROLES if r in self.last_t] or ANALYSIS_ROLES[:1]
        return all(self.last_t.get(r, -float("inf")) - self.log_start_s >= t_s for r in roles)

    def recording(self) -> Recording:
        """The session's data so far as a recording, built as from the log."""
        decoded = series_from_samples(self.samples, self.interface.present_roles())
        return recording_from_series(
            self.log_path,
            decoded,
            self.log_start_s,
            self.frames,
            max(self.last_t.values(), default=self.log_start_s),
            self.interface.missing_roles(),
            request_timeout(self.interface),
        )

    def test_data(self) -> TestData:
        """The FRF pipeline's signals so far (a pause in the requests, and a torque request
        left out for its sampling, are reported once)."""
        recording = self.recording()
        self.pauses_reported = recording.warn_pauses(self.pauses_reported)
        data = recording.test_data(warn=False)
        request = recording.roles.get("torque_request")
        mapped = request is not None and len(request.timestamps) > 1
        if data.torque_request is None and mapped and not self.request_left_out:
            problem = recording.sampling_problems().get("torque_request")
            if problem is not None:
                recording.warn_request_left_out(problem)
                self.request_left_out = True
        return data

    # --- FRFs ---------------------------------------------------------------------------------

    def frfs_due(self) -> list[Chirp]:
        """Completed chirps without an FRF whose data have all arrived."""
        return [
            c
            for c in sorted(self.chirps.values(), key=lambda c: c.index)
            if c.end_s is not None
            and c.frf is None
            and c.failed is None
            and self.reaches(c.end_s + FRF_MARGIN_S)
        ]

    def estimate(self, chirps: Sequence[Chirp], data: TestData) -> None:
        """Estimate the FRF of each chirp from the data (``failed`` says why one could not)."""
        runs = find_runs(data.test_torque)
        for chirp in chirps:
            run = _matching_run(runs, chirp)
            if run is None:
                chirp.failed = (
                    f"no chirp run of {chirp.amplitude_nm:g} N*m found in the test torque at "
                    f"{chirp.start_s:.1f}-{chirp.end_s:.1f} s"
                )
                continue
            try:
                chirp.frf = estimate_frf(data, run, self.resolution_hz)
            except DtidError as error:  # names what is wrong with the data
                chirp.failed = str(error)

    # --- identification and validation --------------------------------------------------------

    def identification_complete(self) -> bool:
        """True when every identification chirp was recorded to its end."""
        return all(self.complete(i) for i in range(len(self.amplitudes_nm)))

    def identification_due(self) -> bool:
        """True when the identification chirps are complete and the data past them arrived."""
        if not self.identification_complete():
            return False
        last = max(self.chirps[i].end_s for i in range(len(self.amplitudes_nm)))
        return self.reaches(last + HOLD_OUT_S)

    def identification_selection(
        self, data: TestData, earlier: Sequence[MeasuredTest] = ()
    ) -> RunSelection:
        """The identification runs, cut as :func:`dtid.identification.pipeline.identification_runs`
        cuts the whole log (the data past the cut, a validation chirp begun, are not used);
        with the ``earlier`` rounds' tests of a campaign before this one's."""
        runs = find_runs(data.test_torque)
        matched = [_matching_run(runs, self.chirps[i]) for i in range(len(self.amplitudes_nm))]
        ends = [r.end_s for r in matched if r is not None]
        if ends:
            data = truncated(data, cut_time(data.test_torque, max(ends)))
        test = MeasuredTest.from_data(self.name, data, self.resolution_hz, self.vehicle)
        return identification_runs([*earlier, test], self.identify_nm, self.resolution_hz)

    def validation_due(self) -> bool:
        """True when the validation chirp is complete and the data past it arrived."""
        index = self.validation_index
        if index is None or not self.complete(index):
            return False
        return self.reaches(self.chirps[index].end_s + HOLD_OUT_S)

    def validation_selection(self, data: TestData) -> RunSelection:
        """The validation runs, cut as :func:`dtid.identification.pipeline.validation_runs` cuts
        the whole log."""
        test = MeasuredTest.from_data(self.name, data, self.resolution_hz, self.vehicle)
        return validation_runs([test], self.amplitudes_nm, self.resolution_hz)


def _matching_run(runs: Sequence[ChirpRun], chirp: Chirp) -> ChirpRun | None:
    """The run that overlaps the chirp's phase most (None if none does)."""
    assert chirp.end_s is not None
    best, overlap = None, 0.0
    for run in runs:
        shared = min(run.end_s, chirp.end_s) - max(run.start_s, chirp.start_s)
        if shared > overlap:
            best, overlap = run, shared
    return best
