"""What the worker plans after a session: the follow-up test, and a campaign round's precision.

No transport here (see :mod:`dtid.identification.service.worker`, which calls these in its loop or
its threads and publishes what they return). The planning itself is
:mod:`dtid.identification.planning`'s, as ``dtid plan --after`` runs it; this module gathers what
a session gives it: the identification's fit and validation runs, the campaign's targets and
budget left, the previous round's result.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from dtid.acquisition.config import SafetyConfig
from dtid.errors import DtidError
from dtid.identification.diagnosis.mismatch import adequacy
from dtid.identification.frf.runs import ChirpRun
from dtid.identification.pipeline import IdentificationReport
from dtid.identification.planning.agreement import agreement, plan_scatter
from dtid.identification.planning.spread import RECORDED
from dtid.identification.search.runs import amplitude_levels
from dtid.simulator.controller import IdleController
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions
from dtid.simulator.vehicle_data import VehicleData

if TYPE_CHECKING:  # imported where used: planning is needed only with a campaign or follow-up
    from dtid.identification.planning.design import Design
    from dtid.identification.planning.information import PlanInformation

logger = logging.getLogger(__name__)

FOLLOW_UP_FILE = "follow-up.json"
"""The follow-up test's plan beside the session's log (``[worker] plan_follow_up``)."""

PreviousRound = tuple[dict[str, float], dict[str, float]]
"""A campaign's previous round: what it identified and the scatter its plan predicted for the
runs recorded then (absolute, 1 sigma)."""


@dataclass(frozen=True)
class FollowUp:
    """A planned follow-up test.

    Attributes
    ----------
    document
        ``dtid plan --json``'s document, with ``agreement`` (a campaign round after the first) and
        ``fit`` (in a campaign) added.
    information
        The planning information it was designed with (linearised at the identified values).
    recorded
        The recorded runs it counts, as designs: what the next round adds to.
    """

    document: dict[str, Any]
    information: PlanInformation
    recorded: list[Design]


def campaign_targets(campaign: Mapping[str, Any] | None) -> dict[str, float]:
    """A campaign's targets over ``dtid plan``'s defaults, parsed as ``dtid plan --target``
    parses them (``NAME = 0`` drops one); outside a campaign the defaults.

    Raises
    ------
    ConfigError
        If the campaign's targets do not parse.
    """
    from dtid.identification.planning.design import parse_targets

    items = ((campaign or {}).get("targets") or {}).items()
    return parse_targets([f"{name}={value}" for name, value in items])


def campaign_widths(
    campaign: Mapping[str, Any] | None,
) -> Callable[[Mapping[str, float]], Mapping[str, float]] | None:
    """In a campaign round, what the identification's target tests are given: from the
    identified values, each campaign target's half-width (SI units); None outside a campaign.

    Raises
    ------
    ConfigError
        If the campaign's targets do not parse.
    """
    if campaign is None:
        return None
    from dtid.identification.planning.design import target_half_widths

    targets = campaign_targets(campaign)
    return lambda theta: target_half_widths(theta, targets)


def information_at_prior(
    prior: DrivetrainParameters, identify_nm: Sequence[float], vehicle: VehicleData
) -> PlanInformation:
    """The planning information at the prior (as ``dtid plan`` measures it, about 10 s): what a
    campaign's first round counts its runs with before anything is identified."""
    from dtid.identification.planning.design import planning_prior
    from dtid.identification.planning.information import measure_information

    planning, _ = planning_prior(prior)
    return measure_information(planning, identify_nm, vehicle=vehicle if vehicle.given else None)


def precision_so_far(
    information: PlanInformation,
    recorded: Sequence[Design],
    runs: Sequence[ChirpRun],
    identify_nm: Sequence[float],
) -> tuple[dict[str, float], int] | None:
    """The precision a campaign's runs reach so far, % at 2 sigma per parameter: the earlier
    rounds' recorded runs and this round's identifying runs, predicted with the last round's
    planning information (linearised at what it identified; in round 1 at the prior).

    Parameters
    ----------
    information
        The last round's planning information.
    recorded
        The earlier rounds' runs, as designs.
    runs
        This round's runs with an FRF, in recording order; those not at an identifying amplitude
        are left out.
    identify_nm
        The identifying amplitudes, N*m.

    Returns
    -------
    tuple of dict and int, or None
        The precision per parameter and the runs it counts (the earlier rounds' and this
        round's); None until the information matrix is regular (two amplitudes: before that a
        stiffness and its free play are not separable), or without a run at an identifying
        amplitude.
    """
    from dtid.identification.planning.design import AMPLITUDE_MATCH, SIGMAS, Design, predict

    new = [
        Design(
            (min(identify_nm, key=lambda a: abs(a - run.amplitude_nm)),),
            (1,),
            run.duration_s,
            *sorted((run.f1_hz, run.f2_hz)),
            validation_nm=0.0,
        )
        for run in runs
        if any(abs(run.amplitude_nm - a) <= AMPLITUDE_MATCH * a for a in identify_nm)
    ]
    if not new:
        return None
    try:
        with np.errstate(all="ignore"):
            precision = predict(information, None, [*recorded, *new])
    except (DtidError, np.linalg.LinAlgError):
        return None
    if not all(np.isfinite(v) and v >= 0 for v in precision.values()):
        return None
    return {k: round(100 * SIGMAS * v, 2) for k, v in precision.items()}, len(recorded) + len(new)


def previous_round(identification: Path, follow_up: Path) -> PreviousRound | None:
    """What the worker identified in a campaign's previous round and the scatter its plan
    predicted then, from that round's identification JSON and follow-up plan; None, with a
    warning, where either is missing or unreadable (the round is then identified without the warm
    start and the rounds are not compared)."""
    try:
        identified, plan = (json.loads(path.read_text()) for path in (identification, follow_up))
        values = {str(k): float(v) for k, v in identified["parameters"].items()}
        return values, plan_scatter(plan)
    except (OSError, KeyError, TypeError, ValueError, AttributeError) as error:
        logger.warning("the previous round (%s) is not compared: %s", follow_up.parent, error)
        return None


def plan_follow_up(
    report: IdentificationReport,
    result: Mapping[str, Any],
    *,
    safety: SafetyConfig,
    vehicle: VehicleData,
    vehicles: int,
    campaign: Mapping[str, Any] | None = None,
    before: PreviousRound | None = None,
    fit: Mapping[str, Any] | None = None,
) -> FollowUp:
    """Plan the test after an identified session, as ``dtid plan --after`` plans it.

    In a campaign (:mod:`dtid.acquisition.campaign`) the targets are the campaign's and the next
    round must fit in its budget left (at least the shortest test is planned, so the campaign sees
    how long the next round would be). The result's profile intervals or, in a campaign, its
    target tests confirm the targets the prediction says are met, or keep them unmet
    (``intervals`` in the plan).

    Parameters
    ----------
    report
        The session's identification (its fit and validation runs are the recorded ones; the
        validation's amplitudes are held out of the plan).
    result
        Its JSON document (the intervals or target tests that confirm a target).
    safety
        The daemon's safety envelope, which caps the amplitude and speed excursion.
    vehicle
        The vehicle's data besides its drivetrain.
    vehicles
        Vehicles planned for besides the identified one (``--spread recorded``).
    campaign
        The session's campaign entry, or None.
    before
        A campaign round's previous round (its values and predicted scatter are compared with
        this round's: ``agreement``).
    fit
        The diagnosis's adequacy test of the result, if it ran (in a campaign it is computed
        otherwise).

    Raises
    ------
    DtidError, KeyError, TypeError, ValueError
        If the campaign entry is malformed or no test can be planned.
    """
    from dtid.identification.planning.design import (
        DEFAULT_MAX_TIME_S,
        plan_test,
        run_designs,
        shortest_test_s,
    )
    from dtid.identification.planning.document import plan_document

    identified = report.fit
    assert identified is not None
    validation = report.validation
    held_out = amplitude_levels(
        t.estimates[i].run.amplitude_nm
        for t, runs in (zip(validation.tests, validation.runs, strict=True) if validation else ())
        for i in runs
    )
    idle = sum(t.setpoint_rpm for t in identified.tests) / len(identified.tests)
    targets = campaign_targets(campaign)
    max_time_s = DEFAULT_MAX_TIME_S
    if campaign is not None:
        left = float(campaign["max_time_s"]) - float(campaign["spent_s"])
        left -= float(campaign["test_time_s"])  # this round's
        max_time_s = max(left, shortest_test_s())
    information, recommendation = plan_test(
        report.identification.parameters,
        targets,
        safety,
        max_time_s=max_time_s,
        validation_nm=0.0,
        options=SimulationOptions(controller=IdleController(setpoint_rpm=idle)),
        recorded=run_designs(identified.tests, identified.runs),
        held_out_nm=held_out,
        vehicle=vehicle if vehicle.given else None,
        spread=RECORDED,
        vehicles=vehicles,
        identification=dict(result),
    )
    limits = {
        "max_amplitude_nm": safety.max_amplitude_nm,
        "max_time_s": max_time_s,
        "speed_window_rpm": safety.speed_window_rpm,
    }
    document = plan_document(information, recommendation, targets, limits)
    if before is not None and recommendation.recorded:
        values, sd = before
        document["agreement"] = agreement(
            values, sd, report.parameters, plan_scatter(document)
        ).as_dict()
    if campaign is not None:
        document["fit"] = dict(fit) if fit else adequacy(report)
    return FollowUp(document, information, list(recommendation.recorded))
