"""JSON documents the tool writes (``--json`` outputs, the worker's files; docs/schemas.md)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path

from dtid.errors import ConfigError, RecordingError


def json_number(value: float) -> float | None:
    """A number as strict JSON carries it: None where it is not finite (NaN, infinity)."""
    return float(value) if math.isfinite(value) else None


def finite(values: Iterable[float]) -> list[float | None]:
    """Numbers as strict JSON carries them (:func:`json_number`): a profile point whose model
    could not idle has an infinite statistic, written as None."""
    return [json_number(v) for v in values]


def write_json(path: Path, document: object) -> None:
    """Write a JSON document (strict: no NaN or infinity), naming the file when that fails.

    Raises
    ------
    RecordingError
        If the file cannot be written.
    ConfigError
        If the document holds a value JSON cannot carry.
    """
    try:
        text = json.dumps(document, indent=1, allow_nan=False) + "\n"
    except ValueError as error:
        raise ConfigError(f"cannot write {path}: {error}") from None
    try:
        Path(path).write_text(text)
    except OSError as error:
        raise RecordingError(f"cannot write {path}: {error.strerror}") from None
