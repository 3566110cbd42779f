"""Shared fixtures: simulated tests of the reference vehicle, computed once per session."""

from __future__ import annotations

from pathlib import Path

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
