"""What the worker reads of a campaign's previous round (identification/service/follow_up.py); the
planning itself is tests/test_plan.py's, the worker's use of it tests/test_worker.py's."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from dtid.errors import ConfigError
from dtid.identification.planning.design import DEFAULT_TARGETS_PERCENT
from dtid.identification.service.follow_up import (
    FOLLOW_UP_FILE,
    campaign_targets,
    campaign_widths,
    previous_round,
)
from dtid.simulator.parameters import reference_parameters


def _round(folder: Path, identified: dict, precision: dict) -> tuple[Path, Path]:
    """A previous round's files as the worker wrote them: its identification and its plan."""
    identification = folder / "identification.json"
    identification.write_text(json.dumps({"parameters": identified}))
    plan = {
        "recorded": {"predicted_precision": precision},
        "prior": reference_parameters().as_dict(),
    }
    (folder / FOLLOW_UP_FILE).write_text(json.dumps(plan))
    return identification, folder / FOLLOW_UP_FILE


def test_the_previous_round_is_its_values_and_the_scatter_its_plan_predicted(
    tmp_path: Path,
) -> None:
    """The scatter is the plan's relative precision times the value it was planned at (its
    prior), not at what the round identified: c12 1 % of the prior's 300 N*m/rad is 3."""
    prior = reference_parameters()
    files = _round(tmp_path, {"c12": 310.0, "J_sum": 0.3}, {"c12": 0.01, "J_sum": 0.02})
    found = previous_round(*files)
    assert found is not None
    values, scatter = found
    assert values == {"c12": 310.0, "J_sum": 0.3}
    assert scatter["c12"] == pytest.approx(0.01 * prior.c12)
    assert scatter["J_sum"] == pytest.approx(0.02 * (prior.J1 + prior.J2 + prior.J3))


@pytest.mark.parametrize("damage", ["no plan", "not JSON", "no parameters", "a text value"])
def test_a_previous_round_that_cannot_be_read_is_not_compared_and_says_why(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, damage: str
) -> None:
    identification, plan = _round(tmp_path, {"c12": 310.0}, {"c12": 0.01})
    if damage == "no plan":
        plan.unlink()
    elif damage == "not JSON":
        identification.write_text("{ half a document")
    elif damage == "no parameters":
        identification.write_text(json.dumps({"nrmse": {}}))
    else:
        identification.write_text(json.dumps({"parameters": {"c12": "stiff"}}))
    with caplog.at_level(logging.WARNING):
        assert previous_round(identification, plan) is None
    assert f"the previous round ({tmp_path}) is not compared" in caplog.text


def test_a_campaigns_targets_parse_as_dtid_plans_and_give_the_target_tests_widths() -> None:
    """A campaign's targets replace or drop (0) `dtid plan`'s defaults, which a follow-up outside
    a campaign plans for; only a campaign's round has target tests. A target in % gives the
    half-width around the identified value the round's target test checks."""
    assert campaign_targets(None) == DEFAULT_TARGETS_PERCENT and campaign_widths(None) is None
    campaign = {"targets": {"c12": 2.0, "eps12": 5, "d23": 0}}
    expected = {**DEFAULT_TARGETS_PERCENT, "c12": 2.0, "eps12": 5.0}
    expected.pop("d23", None)
    assert campaign_targets(campaign) == expected
    widths = campaign_widths({"targets": {"c12": 2.0, "eps12": 5}})
    assert widths is not None
    assert widths({"c12": 300.0, "eps12": 0.02}) == pytest.approx({"c12": 6.0, "eps12": 0.001})
    with pytest.raises(ConfigError, match="nonsense"):
        campaign_targets({"targets": {"nonsense": 1.0}})
