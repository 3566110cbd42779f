"""``dtid plan``'s JSON document (docs/schemas/plan.schema.json), from a recommendation.

Written by ``dtid plan`` and by the worker's follow-up plan alike.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from dtid.identification.planning.design import (
    PAPER_DESIGN,
    SIGMAS,
    Recommendation,
    Unmet,
    predict_worst,
)
from dtid.identification.planning.information import PlanInformation


def plan_document(
    info: PlanInformation,
    recommendation: Recommendation,
    targets: Mapping[str, float],
    limits: Mapping[str, float],
) -> dict[str, object]:
    """``dtid plan``'s JSON (docs/schemas/plan.schema.json): the recommended plan, its predicted
    precision (relative, 1 sigma, with the runs recorded so far), test time and unmet targets,
    the amplitudes that identify, the recorded runs and their precision, the paper's plan
    beside it, and, where the recorded runs' identification was given, its profile intervals
    against the targets (``intervals``)."""
    design = recommendation.design
    paper = predict_worst(info, PAPER_DESIGN)
    recorded = recommendation.recorded
    confirmation = (
        {"intervals": {c.name: c.as_dict() for c in recommendation.intervals}}
        if recommendation.intervals
        else {}
    )
    identify = sorted(
        {a for d in [*recorded, *([design] if design else [])] for a in d.amplitudes_nm}
    )
    return {
        "plan": design.as_dict(info.setpoint_rpm) if design else None,
        "predicted_precision": _rounded(recommendation.precision),
        "test_time_s": design.test_time_s if design else 0.0,
        "identify_nm": identify,
        "recorded": {
            "runs": [
                {
                    "amplitude_nm": d.amplitudes_nm[0],
                    "duration_s": d.duration_s,
                    "f1_hz": d.f1_hz,
                    "f2_hz": d.f2_hz,
                }
                for d in recorded
            ],
            "predicted_precision": (
                _rounded(predict_worst(info, None, recorded)) if recorded else None
            ),
        },
        "unmet": _unmet_entries(recommendation, targets),
        "meets_targets": recommendation.meets_targets,
        "targets_percent": dict(targets),
        "sigmas": SIGMAS,
        "limits": dict(limits),
        "paper": {
            "plan": PAPER_DESIGN.as_dict(info.setpoint_rpm),
            "predicted_precision": _rounded(paper),
            "test_time_s": PAPER_DESIGN.test_time_s,
        },
        "prior": info.prior.as_dict(),
        "spread": {
            "percent": round(100.0 * max(info.spread.values(), default=0.0), 3),
            "percent_by_parameter": {n: round(100.0 * w, 3) for n, w in info.spread.items()},
            "vehicles": len(info.around),
            "correlated": info.spread_correlated,
            "predicted_precision_at_prior": _rounded(recommendation.per_vehicle[0]),
            "vehicles_meeting": {
                name: sum(SIGMAS * 100.0 * p[name] <= target for p in recommendation.per_vehicle)
                for name, target in targets.items()
            },
        },
        "notes": list(info.notes),
        "information": {
            "amplitudes_nm": list(info.amplitudes_nm),
            "seeds": info.seeds,
            "speed_excursion_rpm": [
                round(lv.speed_excursion_rpm, 1) if math.isfinite(lv.speed_excursion_rpm) else None
                for lv in info.levels
            ],
            "excluded": {f"{a:g}": why for a, why in recommendation.excluded.items()},
            "designs_tried": recommendation.designs_tried,
        },
        **confirmation,
    }


def _unmet_entries(
    recommendation: Recommendation, targets: Mapping[str, float]
) -> list[dict[str, object]]:
    """The JSON's ``unmet``: the design's, and each target its profile interval does not
    confirm (its own target, the interval's half-width and why, in place of the entry the
    design's tightened target made)."""
    unconfirmed = {c.name: c for c in recommendation.unconfirmed}
    entries = [u.as_dict() for u in recommendation.unmet if u.name not in unconfirmed]
    for name, check in unconfirmed.items():
        reason = check.reason()
        if any(u.name == name for u in recommendation.unmet):
            reason += ", which the test within the limits does not reach"
        entries.append(Unmet(name, targets[name], check.half_width_percent, reason).as_dict())
    return entries


def _rounded(precision: Mapping[str, float]) -> dict[str, float]:
    return {name: round(value, 5) for name, value in precision.items()}
