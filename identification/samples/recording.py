"""Read a CAN recording into the time series the FRF pipeline works on."""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dtid.acquisition.logfile import Integrity, read_log_checked
from dtid.dbc.ecu_requests import applied_test_torque
from dtid.dbc.interface import RoleSeries, VehicleInterface
from dtid.dbc.roles import DEFAULT_REQUEST_TIMEOUT_S
from dtid.errors import AnalysisError
from dtid.identification.samples.channels import select_channels
from dtid.identification.samples.crank_sampling import (
    SPEED_PER_REVOLUTION,
    STROKES_PER_REVOLUTION,
    crank_sampling,
)
from dtid.identification.samples.late_frames import retime_late_bursts
from dtid.identification.samples.testdata import Series, TestData

logger = logging.getLogger(__name__)

TIME_DECIMALS = 6
TIME_RESOLUTION_S = 10.0**-TIME_DECIMALS
"""Resolution of recording times, s: what ASC, candump and TRC logs store (BLF stores ns)."""


@dataclass(frozen=True)
class Recording:
    """A decoded CAN recording.

    Attributes
    ----------
    path
        The file.
    n_frames
        Frames in the file.
    duration_s
        Time from its first to its last frame, s.
    roles
        Decoded series per mapped role, times in s from the recording's first frame.
    missing_roles
        Required roles the signal map does not define.
    request_timeout_s
        How long the ECU applies a test-torque request when no valid one follows, s (the
        signal map's ``timeout_s``).
    integrity
        What of the file could not be read (cut short, damaged parts skipped); a live
        session's is intact.
    channels
        Per role whose message the file holds with its bus channel: frames per channel, as the
        file names the channels (:mod:`dtid.identification.samples.channels`); empty live.
    channel_problems
        Per role: why its frames cannot be read as one series (a message on several channels
        and none named in the signal map, or not on the one named); :meth:`test_data` refuses.
    """

    path: Path
    n_frames: int
    duration_s: float
    roles: dict[str, RoleSeries]
    missing_roles: tuple[str, ...]
    request_timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S
    integrity: Integrity = dataclasses.field(default_factory=Integrity)
    channels: Mapping[str, Mapping[str, int]] = dataclasses.field(default_factory=dict)
    channel_problems: Mapping[str, str] = dataclasses.field(default_factory=dict)

    def series(self, role: str) -> Series:
        """The role's samples as a :class:`dtid.identification.samples.testdata.Series`."""
        decoded = self.roles[role]
        return Series(decoded.timestamps, decoded.values)

    def test_data(self, warn: bool = True) -> TestData:
        """The signals of the FRF pipeline; raises AnalysisError naming what is missing.

        Parameters
        ----------
        warn
            Log the pauses in the test-torque requests (:meth:`warn_pauses`) and the requests
            the ECU drops; a caller that reads a growing session again and again warns once per
            new pause instead.
        """
        missing = [
            role
            for role in ("speed", "mean_torque", "test_torque")
            if role not in self.roles or len(self.roles[role].timestamps) == 0
        ]
        if missing:
            raise AnalysisError(
                f"{self.path}: no {', '.join(missing)} frames found (check that the signal map "
                "names the messages this recording carries; `dtid inspect` lists what it holds)"
            )
        mixed = [p for r, p in self.channel_problems.items() if r in (*CRANK_ROLES, "test_torque")]
        if mixed:
            raise AnalysisError(mixed[0])
        if warn:
            self.warn_pauses()
        request = self.roles.get("torque_request")
        with_request = request is not None and len(request.timestamps) > 1
        series = {
            role: self._crank_series(role)
            for role in CRANK_ROLES
            if role != "torque_request" or with_request
        }
        problems = sampling_problems(series)
        for role in ("speed", "mean_torque"):
            if role in problems:
                raise AnalysisError(
                    f"{self.path}: {problems[role]}; map the engine speed the ECU computes once "
                    "per crank event and the indicated mean torque once per stroke "
                    "(docs/vehicle.md, Signal maps)"
                )
        if "torque_request" in problems:
            if warn:
                self.warn_request_left_out(problems["torque_request"])
            del series["torque_request"]
        return TestData(
            speed=series["speed"],
            mean_torque=series["mean_torque"],
            test_torque=self._applied_test_torque(warn),
            torque_request=series.get("torque_request"),
        )

    def warn_request_left_out(self, problem: str) -> None:
        """Log that the torque request is left out for ``problem`` in its sampling."""
        logger.warning(
            "%s: %s; the model is driven by the measured mean torque instead, as for a "
            "recording without the role, and K of eq. (3) needs --fix K=VALUE "
            "(docs/model-assumptions.md)",
            self.path,
            problem,
        )

    def sampling_problems(self) -> dict[str, str]:
        """What is wrong with the sampling of each crank-synchronous role the recording holds
        (:func:`sampling_problems`, on the series :meth:`test_data` reads), by role."""
        return sampling_problems(
            {
                role: self._crank_series(role, warn=False)
                for role in CRANK_ROLES
                if role in self.roles and len(self.roles[role].timestamps) > 1
            }
        )

    def warn_pauses(self, reported: int = 0) -> int:
        """Log a warning when the test-torque requests pause longer than the ECU's timeout more
        often than ``reported`` times; return how often they do."""
        t = self.roles["test_torque"].timestamps if "test_torque" in self.roles else np.empty(0)
        gaps = np.diff(t)
        pauses = gaps[gaps > self.request_timeout_s]
        if len(pauses) > reported:
            logger.warning(
                "%s: %d pause(s) in the test-torque requests longer than the ECU's timeout "
                "(%.3f s; the longest %.3f s); the test torque is taken as zero after the "
                "timeout, as the ECU applied it",
                self.path,
                len(pauses),
                self.request_timeout_s,
                float(np.max(pauses)),
            )
        return len(pauses)

    def _applied_test_torque(self, warn: bool = True) -> Series:
        """The test torque the ECU applied, from the requests the recording holds, N*m (with a
        warning for the requests the ECU drops when ``warn``).

        The ECU's own rules (:func:`dtid.dbc.ecu_requests.applied_test_torque`): a request holds
        until the next, zero once ``request_timeout_s`` has passed without one (the tool
        stalled, frames were lost) and while its enable signal, where mapped, is 0; a request
        whose checksum or alive counter is wrong is dropped, as the ECU dropped it. Holding the
        last request over such a pause, as the plain series would, makes the FRF's excitation
        and the model's replay differ from what drove the engine.
        """
        decoded = self.roles["test_torque"]
        t, value, rules = applied_test_torque(
            decoded.timestamps,
            decoded.values.astype(float),
            decoded.extra,
            self.request_timeout_s,
        )
        if warn and rules.dropped:
            logger.warning(
                "%s: %s test-torque request(s) the ECU drops (%s); the test torque is taken as "
                "the ECU applied it",
                self.path,
                sum(rules.dropped.values()),
                ", ".join(f"{n} {reason}" for reason, n in sorted(rules.dropped.items())),
            )
        return Series(t, value)

    def _crank_series(self, role: str, warn: bool = True) -> Series:
        """A crank-synchronous role's samples: a frame repeating its predecessor's counter (a
        duplicate) dropped, where the map names the counter, and samples that came late in a
        burst re-timed (:func:`dtid.identification.samples.late_frames.retime_late_bursts`;
        logged when ``warn``)."""
        decoded = self.roles[role]
        t, value = decoded.timestamps, decoded.values
        counter = decoded.extra.get("counter")
        if counter is not None and len(counter) > 1:
            keep = np.concatenate(([True], np.diff(counter) != 0))
            t, value = t[keep], value[keep]
        retiming = retime_late_bursts(t)
        if retiming.n_moved and warn:
            logger.warning(
                "%s: %d '%s' samples arrived late in bursts (up to %.3f s); re-timed to their "
                "crank slots",
                self.path,
                retiming.n_moved,
                role,
                retiming.max_shift_s,
            )
        return Series(retiming.times, value)


CRANK_ROLES = {
    "speed": SPEED_PER_REVOLUTION,
    "mean_torque": STROKES_PER_REVOLUTION,
    "torque_request": SPEED_PER_REVOLUTION,
}
"""The roles read once per crank event or stroke, and how many samples a revolution each."""


def sampling_problems(series: Mapping[str, Series]) -> dict[str, str]:
    """What is wrong with each crank-synchronous role's sampling
    (:mod:`dtid.identification.samples.crank_sampling`), by role; a role sampled as
    :data:`CRANK_ROLES` says, or too short to tell, is not listed. Needs the ``speed``."""
    speed = series.get("speed")
    if speed is None:
        return {}
    out = {}
    for role, values in series.items():
        sampling = crank_sampling(values.t, speed.t, speed.value.astype(float))
        problem = None if sampling is None else sampling.problem(role, CRANK_ROLES[role])
        if problem is not None:
            out[role] = problem
    return out


def _in_time_order(series: RoleSeries, start: float, path: Path) -> RoleSeries:
    """The series with times from the recording's start, sorted (stably) if frames came late."""
    t = np.round(series.timestamps - start, TIME_DECIMALS)
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(t) < 0):
        logger.warning(
            "%s: %d frames of role '%s' arrive out of time order; sorted by timestamp",
            path,
            int(np.sum(np.diff(t) < 0)),
            series.role,
        )
    return RoleSeries(
        role=series.role,
        timestamps=t[order],
        values=series.values[order],
        extra={key: value[order] for key, value in series.extra.items()},
        n_bad=series.n_bad,
        not_measured=series.not_measured,
    )


def recording_from_series(
    path: Path,
    decoded: Mapping[str, RoleSeries],
    start_s: float,
    n_frames: int,
    end_s: float,
    missing_roles: tuple[str, ...],
    request_timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S,
) -> Recording:
    """A recording from decoded series with absolute times: the one constructor of both paths.

    :func:`load_recording` (a log file) and the worker (the daemon's samples events) both build
    their recordings here, so the same frames give the same series: times made relative to
    ``start_s`` (the log's first frame), rounded to :data:`TIME_RESOLUTION_S` and sorted stably.

    Parameters
    ----------
    path
        The log file (for names and messages).
    decoded
        Series per mapped role, absolute timestamps, in receive order.
    start_s
        Timestamp of the log's first frame, s.
    n_frames
        Frames recorded.
    end_s
        Timestamp of the last frame, s.
    missing_roles
        Required roles the signal map does not define.
    request_timeout_s
        The ECU's request timeout, s (the signal map's ``timeout_s`` of the test torque).
    """
    roles = {role: _in_time_order(series, start_s, path) for role, series in decoded.items()}
    return Recording(
        path=path,
        n_frames=n_frames,
        duration_s=end_s - start_s,
        roles=roles,
        missing_roles=missing_roles,
        request_timeout_s=request_timeout_s,
    )


def request_timeout(interface: VehicleInterface) -> float:
    """The ECU's test-torque request timeout the interface's signal map gives, s."""
    spec = interface.signal_map.roles.get("test_torque")
    return DEFAULT_REQUEST_TIMEOUT_S if spec is None else spec.timeout_s


def load_recording(path: str | os.PathLike[str], interface: VehicleInterface) -> Recording:
    """Read and decode a CAN recording (.blf, .asc, candump .log, .mf4, .trc or .csv).

    Times are made relative to the recording's first frame and rounded to
    :data:`TIME_RESOLUTION_S`, so every format gives the same series whatever absolute start time
    and precision it stores.

    Raises
    ------
    RecordingError
        If the file cannot be read.
    """
    path = Path(path)
    frames, integrity = read_log_checked(path)
    selection = select_channels(frames, interface, path)
    recording = recording_from_series(
        path,
        interface.decode(selection.frames),
        frames[0].timestamp,
        len(frames),
        frames[-1].timestamp,
        interface.missing_roles(),
        request_timeout(interface),
    )
    return dataclasses.replace(
        recording,
        integrity=integrity,
        channels=selection.found,
        channel_problems=selection.problems,
    )
