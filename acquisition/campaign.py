"""The adaptive test (``[test] adaptive = true``): rounds of chirp tests until the targets are met.

``dtid acquire`` runs the ``[test]`` plan as round 1 of a campaign. Each round is a test session
of its own (:class:`dtid.acquisition.daemon.Daemon`: safety envelope, log, event stream, abort),
in a folder inside the campaign's folder, and its ``session`` event tells the worker it is part
of a campaign (:func:`round_fields`: the earlier rounds' logs, the budget spent, the targets).
After each round the worker identifies every round so far together (eq. 17 summed over all
their identifying runs; the first round's validation chirp stays held out) and publishes, topic
``plan``, the precision the recorded runs reach and the shortest next round that meets the
targets within the budget left (``dtid plan --after``). The engine idles meanwhile with no test
torque. :func:`next_round` then decides, and the campaign

* stops ``targets_met`` when the recorded runs meet every target, the model explains the
  recordings and the round's parameters agree with the previous round's (the worker's
  ``agreement``: no parameter moved by more than its predicted scatter allows,
  :mod:`dtid.identification.planning.agreement`);
* stops ``inconsistent`` when the targets are said met but the parameters jumped between the
  rounds: one of the two searches ended at another optimum, and a precision predicted there
  does not hold (where the targets are not met, the rounds go on and the jump is recorded);
* stops ``inadequate`` when the targets are said met but the model at what was identified does
  not explain the recordings (the worker's ``fit``: the diagnosis's global adequacy test), as
  after a search that ended at another optimum (the campaign trial's truth 4, which agreed with
  itself round after round);
* stops ``time_budget`` when the next round is longer than the budget left;
* stops ``aborted`` when a round aborted (no further round on a vehicle that left the safety
  envelope or an operator stopped), or on SIGINT/SIGTERM while it waits for the worker;
* stops ``no_plan`` when the worker sent no plan within ``[test] replan_wait_s``, reported an
  error, or planned a round the configuration refuses (above the amplitude cap);
* else runs the plan as the next round.

``campaign.json`` in the campaign's folder records every round (session, log, plan, test time,
status), the precision reached after each and why the campaign stopped; it is rewritten after
every round, so a campaign cut short still says what ran.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import zmq

from dtid.acquisition.config import AcquisitionConfig
from dtid.acquisition.daemon import (
    DEFAULT_LINGER_S,
    DEFAULT_WAIT_S,
    Daemon,
    DaemonResult,
    on_stop_signals,
)
from dtid.acquisition.ipc import endpoint
from dtid.acquisition.plan import TestPlan, plan_from_document
from dtid.acquisition.recorder import new_session_directory
from dtid.acquisition.security import Security
from dtid.errors import ConfigError
from dtid.jsonfile import write_json

logger = logging.getLogger(__name__)

CAMPAIGN_FILE = "campaign.json"
"""The campaign's record in its folder."""
STOP_REASONS = {
    "targets_met": "the recorded runs meet every precision target",
    "time_budget": "the next round would exceed the test-time budget left",
    "inconsistent": "the targets are said met but the parameters jumped between the rounds",
    "inadequate": "the targets are said met but the model does not explain the recordings",
    "aborted": "a round was aborted",
    "no_plan": "the worker gave no plan for the next round",
}
"""Why a campaign stopped, by key of ``campaign.json``'s ``stopped``."""
POLL_MS = 200
"""Longest wait for a worker message before the wait is checked again, ms."""


@dataclass(frozen=True)
class Decision:
    """What follows a round.

    Attributes
    ----------
    plan
        The next round's test plan, or None to stop.
    stopped
        Key of :data:`STOP_REASONS` when stopping, else None.
    message
        One sentence for the operator and ``campaign.json``.
    """

    plan: TestPlan | None
    stopped: str | None
    message: str


def next_round(
    document: Mapping[str, Any] | None,
    budget_left_s: float,
    config: AcquisitionConfig,
) -> Decision:
    """Decide from the worker's plan what follows a completed round.

    Parameters
    ----------
    document
        The worker's ``plan`` message (``dtid plan --json``'s document), None when none came.
    budget_left_s
        Test time (bus) the campaign may still spend, s.
    config
        The configuration (the next plan must pass its checks: the amplitude cap; the DBC's
        range is checked when the round starts, as for any test).
    """
    if document is None:
        return Decision(None, "no_plan", "the worker gave no plan for the next round")
    if document.get("plan") is None:
        if document.get("meets_targets"):
            return _met(document)
        unmet = "; ".join(
            f"{u.get('name')}: {u.get('reason')}" for u in document.get("unmet") or []
        )
        return Decision(
            None,
            "no_plan",
            "the worker's plan holds no next round" + (f" (unmet: {unmet})" if unmet else ""),
        )
    period = config.test.request_period_s
    try:
        plan = plan_from_document(document, "the worker's plan", period)
        replace(config, test=plan)  # the configuration's checks: the amplitude cap
    except ConfigError as error:
        return Decision(None, "no_plan", f"the next round is refused: {error}")
    if plan.end_s > budget_left_s * (1 + 1e-9):
        return Decision(
            None,
            "time_budget",
            f"the next round ({plan.end_s:.0f} s) is longer than the {max(budget_left_s, 0):.0f} "
            "s of test time left ([test] max_time_s)",
        )
    return Decision(plan, None, "")


def _met(document: Mapping[str, Any]) -> Decision:
    """``targets_met``, unless the rounds disagree (``inconsistent``) or the model does not
    explain the recordings (``inadequate``): then the precision said met does not hold."""
    agreement = document.get("agreement") or {}
    fit = document.get("fit") or {}
    if agreement.get("agree", True) is False:
        stopped = "inconsistent"
        why = (
            f"from the previous round {agreement.get('summary')}: one of the two "
            "identifications ended at another optimum (check the fits: dtid diagnose, dtid profile)"
        )
    elif fit.get("adequate", True) is False:
        stopped = "inadequate"
        why = (
            f"the model does not explain the recordings ({fit.get('bands')} significant bands, "
            f"global p = {float(fit.get('global_p_value') or 0.0):.2g}): the search may have "
            "ended at another optimum, or the model lacks physics (dtid diagnose)"
        )
    else:
        return Decision(None, "targets_met", STOP_REASONS["targets_met"])
    return Decision(
        None, stopped, f"the targets are said met, but {why}; the precision does not hold"
    )


def round_fields(
    campaign_id: str,
    number: int,
    rounds: list[dict[str, Any]],
    config: AcquisitionConfig,
) -> dict[str, Any]:
    """The ``campaign`` entry of a round's ``session`` event, for the worker.

    Keys: ``id``, ``round`` (1-based), ``logs`` (the earlier completed rounds' logs, identified
    together with this one), ``identify_nm`` (every round's identifying amplitudes so far and
    this one's, N*m), ``spent_s`` (test time of the earlier rounds, s), ``test_time_s`` (this
    round's, s), ``max_time_s``, ``targets`` (% at 2 sigma; empty: ``dtid plan``'s defaults).
    """
    done = [r for r in rounds if r["status"] == "completed"]
    levels = {a for r in done for a in r["plan"]["amplitudes_nm"]}
    levels |= set(config.test.amplitudes_nm)
    return {
        "id": campaign_id,
        "round": number,
        "logs": [r["log"] for r in done],
        "identify_nm": sorted(levels),
        "spent_s": sum(r["test_time_s"] for r in rounds),
        "test_time_s": config.test.end_s,
        "max_time_s": config.campaign.max_time_s,
        "targets": dict(config.campaign.targets),
    }


@dataclass
class CampaignResult:
    """How a campaign ended.

    Attributes
    ----------
    folder
        The campaign's folder (``campaign.json`` and one session folder per round).
    rounds
        Each round's record as in ``campaign.json``.
    stopped
        Key of :data:`STOP_REASONS`.
    message
        Why, in one sentence.
    results
        Each round's :class:`DaemonResult`.
    """

    folder: Path
    rounds: list[dict[str, Any]]
    stopped: str
    message: str
    results: list[DaemonResult] = field(default_factory=list)

    @property
    def exit_status(self) -> int:
        """The last round's exit status (3 when it was aborted, else 0)."""
        return self.results[-1].exit_status if self.results else 3


class Campaign:
    """Rounds of chirp tests on the bus until the worker's plan says the targets are met.

    Parameters
    ----------
    config
        The configuration; ``[test]`` is round 1, ``config.campaign`` the budget and targets.
    linger_s, wait_s, report
        As :class:`dtid.acquisition.daemon.Daemon`, for every round.
    """

    def __init__(
        self,
        config: AcquisitionConfig,
        linger_s: float = DEFAULT_LINGER_S,
        wait_s: float = DEFAULT_WAIT_S,
        report: Callable[[str], None] = lambda line: None,
    ) -> None:
        self.config = config
        self.linger_s = linger_s
        self.wait_s = wait_s
        self.report = report

    def run(self) -> CampaignResult:
        """Run rounds until the campaign stops; return how it ended.

        Raises
        ------
        ConfigError, DbcError, RecordingError
            As :meth:`dtid.acquisition.daemon.Daemon.run`, before the first round runs. (The
            ``[test] targets`` names are checked by ``dtid acquire`` before; the worker refuses
            an unknown one with its first plan.)
        """
        config = self.config
        folder = new_session_directory(Path(config.output.directory))
        campaign_id = folder.name
        self.report(
            f"adaptive campaign {campaign_id}: up to {config.campaign.max_time_s:g} s of test "
            f"time; record {folder / CAMPAIGN_FILE}"
        )
        result = CampaignResult(folder, [], "aborted", "stopped before a round ended (an error)")
        context = zmq.Context()
        security = Security(config.pipeline.keys, context)
        results = context.socket(zmq.SUB)
        results.setsockopt(zmq.RCVHWM, 0)  # read only between rounds: keep all that comes
        results.setsockopt(zmq.LINGER, 0)
        results.setsockopt(zmq.SUBSCRIBE, b"")
        try:
            address = endpoint(config.pipeline.results)
            security.connect(results, address, "results")
            results.connect(address)  # before round 1: no plan can pass unseen
            round_config = replace(config, output=replace(config.output, directory=folder))
            while True:
                number = len(result.rounds) + 1
                fields = round_fields(campaign_id, number, result.rounds, round_config)
                self.report(
                    f"round {number}: {len(round_config.test.chirps)} chirps, "
                    f"{round_config.test.end_s:.0f} s (spent so far {fields['spent_s']:.0f} s)"
                )
                outcome = Daemon(
                    round_config, self.linger_s, self.wait_s, self.report, campaign=fields
                ).run()
                result.results.append(outcome)
                record = {
                    "round": number,
                    "session": outcome.session_dir.name,
                    "log": str(outcome.log_path),
                    "plan": round_config.test.as_dict(),
                    "test_time_s": round_config.test.end_s,
                    "status": outcome.status,
                    "reason": outcome.reason,
                    "precision": None,
                    "agreement": None,
                    "fit": None,
                }
                result.rounds.append(record)
                if outcome.status != "completed":
                    result.stopped = "aborted"
                    result.message = f"round {number} was aborted ({outcome.reason})"
                    break
                result.message = f"waiting for the worker's plan after round {number}"
                self._write(result)
                self.report(f"round {number} done; waiting for the worker's plan of the next")
                try:
                    with _signals_interrupt():
                        document = _await_plan(
                            results, outcome.session_dir.name, config.campaign.replan_wait_s
                        )
                except KeyboardInterrupt:
                    result.message = (
                        f"stopped by a signal while waiting for the worker's plan after round "
                        f"{number} (completed)"
                    )
                    break
                if document is not None:
                    record["precision"] = (document.get("recorded") or {}).get(
                        "predicted_precision"
                    )
                    record["unmet"] = document.get("unmet")
                    record["agreement"] = document.get("agreement")
                    record["fit"] = document.get("fit")
                    self.report(_reached(number, document))
                spent = sum(r["test_time_s"] for r in result.rounds)
                decision = next_round(document, config.campaign.max_time_s - spent, config)
                if decision.plan is None:
                    assert decision.stopped is not None
                    result.stopped, result.message = decision.stopped, decision.message
                    if document is not None and document.get("error"):
                        result.message += f": {document['error']}"
                    break
                round_config = replace(round_config, test=decision.plan)
        finally:
            self._write(result)
            results.close(linger=0)
            security.close()
            context.term()
        self.report(f"campaign stopped: {result.stopped} ({result.message})")
        return result

    def _write(self, result: CampaignResult) -> None:
        config = self.config.campaign
        write_json(
            result.folder / CAMPAIGN_FILE,
            {
                "campaign": result.folder.name,
                "max_time_s": config.max_time_s,
                "targets": dict(config.targets),
                "spent_s": sum(r["test_time_s"] for r in result.rounds),
                "rounds": result.rounds,
                "stopped": result.stopped,
                "message": result.message,
            },
        )


def _reached(number: int, document: Mapping[str, Any]) -> str:
    """One line: the precision the rounds so far reach on each targeted parameter."""
    precision = (document.get("recorded") or {}).get("predicted_precision") or {}
    targets = document.get("targets_percent") or {}
    sigmas = float(document.get("sigmas") or 2.0)
    parts = [
        f"{name} {100 * sigmas * precision[name]:.1f}"
        + ("" if 100 * sigmas * precision[name] <= target else f" (target {target:g})")
        for name, target in targets.items()
        if name in precision
    ]
    line = f"after round {number}, % at {sigmas:g} sigma: " + ", ".join(parts)
    agreement = document.get("agreement")
    if agreement and agreement.get("agree") is False:
        line += "; jumped from the previous round: " + ", ".join(agreement.get("disagreeing") or [])
    return line


def _signals_interrupt() -> contextlib.AbstractContextManager[None]:
    """SIGINT and SIGTERM raise KeyboardInterrupt meanwhile (main thread only; a round's own
    handlers are the daemon's)."""

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    return on_stop_signals(handler)


def _await_plan(socket: zmq.Socket, session: str, wait_s: float) -> dict[str, Any] | None:
    """The worker's ``plan`` message for ``session``; None when nothing comes within ``wait_s``
    (wall). When the worker ends the session without a plan (its last ``progress``: ``done``,
    ``aborted``, or ``error`` without a message, after a failure) the answer is
    ``{"plan": None, "error": ...}`` with the last error it reported."""
    deadline = time.monotonic() + wait_s
    error = None
    while (left := deadline - time.monotonic()) > 0:
        if not socket.poll(min(POLL_MS, max(1, math.ceil(left * 1000)))):
            continue
        frames = socket.recv_multipart()
        try:
            topic, document = frames[0].decode(), json.loads(frames[-1])
        except (UnicodeDecodeError, ValueError):
            continue
        if not isinstance(document, dict) or document.get("session") != session:
            continue
        if topic == "plan":
            return document
        if topic != "progress":
            continue
        stage, message = document.get("stage"), document.get("message")
        if stage == "error" and message:
            error = str(message)
        elif stage in ("done", "aborted", "error"):
            ended = f"the worker ended the session ({stage}) without a plan"
            return {"plan": None, "meets_targets": False, "error": error or ended}
    logger.warning("no plan from the worker within %.0f s", wait_s)
    return None
