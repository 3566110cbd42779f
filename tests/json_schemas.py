"""Validate a ``--json`` document against its schema in docs/schemas (JSON Schema 2020-12)."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
from referencing import Registry, Resource

SCHEMAS = Path(__file__).resolve().parents[1] / "docs" / "schemas"


def _registry() -> Registry:
    """Every schema by its ``$id``, so that one may refer to another by file name."""
    resources = []
    for path in SCHEMAS.glob("*.schema.json"):
        schema = json.loads(path.read_text())
        resources.append((schema["$id"], Resource.from_contents(schema)))
    return Registry().with_resources(resources)


def validate(document: object, name: str) -> None:
    """Raise ``jsonschema.ValidationError`` unless ``document`` fits its schema,
    ``docs/schemas/NAME.schema.json``."""
    schema = json.loads((SCHEMAS / f"{name}.schema.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.Draft202012Validator(schema, registry=_registry()).validate(document)
