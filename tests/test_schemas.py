"""Every ``--json`` output fits its published schema (docs/schemas), and the schemas are strict
enough to refuse a document that breaks the contract."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
from conftest import CommandOutputs
from json_schemas import SCHEMAS, validate


@pytest.fixture(scope="module")
def outputs(command_outputs: CommandOutputs) -> dict[str, object]:
    """The documents of `dtid inspect`, `frf`, `identify` and `diagnose` on a short test."""
    documents = dict(command_outputs.documents)
    documents["recording-metadata"] = documents["inspect"]["metadata"]
    return documents


@pytest.mark.parametrize(
    "name", ["inspect", "frf", "identification", "diagnosis", "recording-metadata"]
)
def test_each_output_fits_its_schema(outputs: dict[str, object], name: str) -> None:
    validate(outputs[name], name)


def test_every_schema_file_is_tested() -> None:
    assert {p.name.split(".")[0] for p in SCHEMAS.glob("*.schema.json")} == {
        "inspect",
        "frf",
        "identification",
        "diagnosis",
        "recording-metadata",
        "plan",  # validated in tests/test_plan.py (dtid plan's own fixture)
        "campaign",  # validated in tests/test_campaign.py (the campaign on a virtual bus)
    }


@pytest.mark.parametrize(
    ("name", "path", "value"),
    [
        ("identification", ("parameters",), {"J_sum": 0.3}),
        ("identification", ("identifiable", "c12"), "maybe"),
        ("identification", ("idle_loop",), {"x": {"mode": "own_controller"}}),
        ("frf", ("runs", 0, "amplitude_nm"), -5.0),
        ("inspect", ("roles",), {"rpm": {}}),
        ("inspect", ("metadata", "integrity", "lost"), -1),
        ("recording-metadata", ("interface", "roles", "speed"), "no signal"),
        ("diagnosis", ("adequate",), "yes"),
        ("diagnosis", ("verdict", "mechanisms"), "none"),
    ],
)
def test_a_broken_contract_is_refused(
    outputs: dict[str, object], name: str, path: tuple, value: object
) -> None:
    document = json.loads(json.dumps(outputs[name]))
    target = document
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    with pytest.raises(jsonschema.ValidationError):
        validate(document, name)


def test_the_schema_page_names_every_schema() -> None:
    page = (Path(__file__).resolve().parents[1] / "docs" / "schemas.md").read_text()
    for schema in SCHEMAS.glob("*.schema.json"):
        assert f"schemas/{schema.name}" in page
