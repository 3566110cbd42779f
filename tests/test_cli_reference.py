"""docs/cli.md is the parser's own help: regenerate it with ``python -m dtid.cli.reference``."""

from __future__ import annotations

from pathlib import Path

from dtid.cli import COMMAND_NAMES
from dtid.cli.reference import render

PAGE = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


def test_the_reference_page_is_current() -> None:
    assert PAGE.read_text() == render(), (
        "docs/cli.md is stale: run `python -m dtid.cli.reference > docs/cli.md`"
    )


def test_every_command_has_a_section() -> None:
    page = PAGE.read_text()
    for name in COMMAND_NAMES:
        assert f"## `dtid {name}`" in page
