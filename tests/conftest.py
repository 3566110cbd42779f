"""Shared fixtures: simulated tests of the reference vehicle, computed once per session."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from dtid.acquisition.plan import TestPlan
from dtid.identification.samples.testdata import TestData, from_simulation
from dtid.simulator.parameters import DrivetrainParameters, reference_parameters
from dtid.simulator.simulate import SimulationOptions, SimulationResult, simulate

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
"""Third-party DBCs and CAN logs beside the repository (never copied into it)."""


@pytest.fixture
def realdata() -> Path:
    """The third-party data folder; skips the test when it is not present."""
    if not REALDATA.is_dir():
        pytest.skip(f"third-party CAN data not present in {REALDATA}")
    return REALDATA


@pytest.fixture(scope="session")
def reference() -> DrivetrainParameters:
    return reference_parameters()


@pytest.fixture(scope="session")
def reference_test(reference: DrivetrainParameters) -> SimulationResult:
    """The default three-amplitude test with realistic noise, seed 1."""
    return simulate(
        reference,
        TestPlan(amplitudes_nm=(2.0, 5.0, 10.0), validation_nm=0.0),
        SimulationOptions(),
        seed=1,
    )


@pytest.fixture(scope="session")
def reference_data(reference_test: SimulationResult) -> TestData:
    return from_simulation(reference_test)


HELD = ["J_sum=0.28", "x1=0.625", "x12=0.857", "c23=80", "d23=0.3", "Tc12=0.3", "eps23=0.012"]
"""The reference's values, held so that the search (c12, d12, eps12 free) takes seconds where the
search is not the subject (the JSON contracts, the report)."""


@dataclass(frozen=True)
class CommandOutputs:
    """A short simulated test and what the commands made of it, in one folder: ``test.blf``,
    ``inspect.json``, ``frf.json``, ``identification.json``, ``diagnosis.json`` and
    ``diagnosis.png``."""

    folder: Path
    recording: Path
    documents: dict[str, Any]


@pytest.fixture(scope="session")
def command_outputs(tmp_path_factory: pytest.TempPathFactory) -> CommandOutputs:
    """`dtid simulate`, `inspect`, `frf`, `identify` (c12 and eps12 free, a small search
    budget, three profile points) and `diagnose` (of that identification, two mechanisms of the
    library: the whole library's document is tests/test_diagnosis.py's) on a 20 s chirp test,
    run once: their consumers check contracts and the report's text, not accuracy."""
    from dtid.cli import main

    folder = tmp_path_factory.mktemp("commands")
    recording = folder / "test.blf"
    assert main(["simulate", str(recording), "--duration", "20"]) == 0
    commands = {
        "inspect": ["inspect", str(recording)],
        "frf": ["frf", str(recording)],
        "identification": [
            "identify",
            str(recording),
            "--generations",
            "2",
            "--popsize",
            "4",
            "--polish-evaluations",
            "40",
            "--profile-points",
            "3",
            "--fix",
            *HELD,
            "d12=1.0",
        ],
        "diagnosis": [
            "diagnose",
            str(recording),
            "--identification",
            str(folder / "identification.json"),
            "--plot",
            str(folder / "diagnosis.png"),
            *("--mechanisms", "gearbox_drag", "torque_lag"),  # screened: no refit, seconds
        ],
    }
    documents = {}
    for name, command in commands.items():
        path = folder / f"{name}.json"
        assert main([*command, "--json", str(path)]) == 0
        documents[name] = json.loads(path.read_text())
    return CommandOutputs(folder, recording, documents)
