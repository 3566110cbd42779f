"""The docs point at code that exists: each ``file``: ``name`` of the method page's equation
table names a file of the repository and a function, class or constant defined in it."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_equation_table_names_existing_code() -> None:
    page = (ROOT / "docs" / "method.md").read_text()
    table = page[page.index("## The paper's equations in the code") :]
    table = table[: table.index("\n## ")]
    rows = [line for line in table.splitlines() if line.startswith("| eq")]
    assert len(rows) >= 15
    for row in rows:
        where = row.split("|")[3]
        for path, names in re.findall(r"`([\w/]+\.py)`(?:: ([^;(]+))?", where):
            source = (ROOT / path).read_text()
            for name in re.findall(r"`([\w.]+)`", names or ""):
                defined = name.split(".")[-1]
                pattern = rf"(def|class) {defined}\b|^{defined}\b.*=|^    def {defined}\b"
                assert re.search(pattern, source, re.M), f"{path}: {name} ({row[:40]})"


def test_the_diagnosis_page_lists_the_library_as_the_code_has_it() -> None:
    from dtid.simulator.mechanisms import MECHANISMS

    page = (ROOT / "docs" / "diagnosis.md").read_text()
    table = page[page.index("## The library") :]
    table = table[: table.index("\n### ")]
    rows = {
        row.split("|")[1].strip(" `"): row for row in table.splitlines() if row.startswith("| `")
    }
    assert list(rows) == [m.name for m in MECHANISMS]
    for mechanism in MECHANISMS:
        for parameter in mechanism.parameters:
            assert f"`{parameter.name}`" in rows[mechanism.name], parameter.name
