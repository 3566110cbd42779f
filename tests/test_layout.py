"""Dependencies point one way: each layer imports only the layers below it (docs/layout.md).

The layers, in the order the data flow: the errors and file helpers every layer raises and
writes; the vehicle's CAN interface (``dbc``); the test on the bus (``acquisition``); the plant
(``simulator``); the identification, itself in stages (samples -> FRFs -> model -> search ->
uncertainty -> the pipeline that strings them -> the worker service); the Python API; the
command line. A module imports its own layer or a lower one, never a higher one.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {
    "api": "dtid",
    "cli": "dtid.cli",
    "acquisition": "dtid.acquisition",
    "dbc": "dtid.dbc",
    "simulator": "dtid.simulator",
    "identification": "dtid.identification",
}
"""Source folder -> the package it is installed as (pyproject's package-dir)."""

LAYERS = (
    ("dtid.errors", "dtid.jsonfile"),
    ("dtid.dbc",),
    ("dtid.acquisition",),
    ("dtid.simulator",),
    ("dtid.identification.samples",),
    ("dtid.identification.frf",),
    ("dtid.identification.model",),
    ("dtid.identification.search",),
    ("dtid.identification.uncertainty",),
    (
        "dtid.identification.gain_choice",
        "dtid.identification.pipeline",
        "dtid.identification.setups",
        "dtid.identification.plots",
    ),
    (
        "dtid.identification.diagnosis",
        "dtid.identification.html_report",
        "dtid.identification.planning",
    ),
    ("dtid.identification.fleet",),
    ("dtid.identification.service",),
    ("dtid.workflow", "dtid"),
    ("dtid.cli",),
)
"""Module prefixes per layer, lowest first."""


def layer(module: str) -> int:
    """The layer of a module: that of its longest matching prefix."""
    best, found = -1, None
    for index, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best:
                best, found = len(prefix), index
    if found is None:
        raise AssertionError(f"{module} is in no layer of LAYERS")
    return found


def modules() -> dict[str, Path]:
    """Every module of the source folders by its installed name."""
    found = {}
    for folder, package in FOLDERS.items():
        for path in (ROOT / folder).rglob("*.py"):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((package, *parts))] = path
    return found


def imports(path: Path) -> set[str]:
    """The modules a file imports (absolute imports; the code base uses no relative ones)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: relative import"
            names.add(node.module or "")
    return names


BARE = ("acquisition", "identification", "simulator", "dbc", "cli", "api")


@pytest.mark.parametrize("module", sorted(modules()))
def test_a_module_imports_only_its_own_layer_or_lower(module: str) -> None:
    path = modules()[module]
    own = layer(module)
    for name in imports(path):
        top = name.split(".")[0]
        assert top not in BARE, f"{module} imports {name}: the installed name is dtid.{name}"
        if top != "dtid" or name == "dtid":
            continue
        assert layer(name) <= own, (
            f"{module} (layer {own}, {LAYERS[own]}) imports {name} "
            f"(layer {layer(name)}, {LAYERS[layer(name)]}): dependencies point downwards only"
        )


def test_the_package_root_imports_nothing_eagerly() -> None:
    """``import dtid.errors`` from the lowest layer must not pull the API (and a cycle) in: the
    root imports the API on first use only, inside its ``__getattr__``."""
    tree = ast.parse((ROOT / "api" / "__init__.py").read_text())
    eager = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
    assert all(getattr(n, "module", None) in {"__future__", "typing"} for n in eager)


def test_every_source_folder_is_a_layer() -> None:
    on_disk = {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}
    assert on_disk - {"benchmarks"} == set(FOLDERS)  # benchmarks: not installed
