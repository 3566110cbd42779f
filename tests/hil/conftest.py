"""Fixtures of the hardware-in-the-loop scenarios (see README.md in this folder).

``hil_bus`` is the bus of ``DTID_HIL_BUS`` and skips the test, with the reason, where that bus
cannot be had (no network namespace here, no vcan0 on the laptop). ``scenario_config`` writes a
scenario's configuration file; ``run_hil_scenario`` runs a script of ``scenarios/`` on the bus.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dtid.acquisition.config import AcquisitionConfig
from hil.config import write_scenario_config
from hil.namespace import HilBus, bus_unavailable, hil_bus, run_scenario

SCENARIOS = Path(__file__).parent / "scenarios"


@pytest.fixture(scope="session")
def hil_bus_spec() -> HilBus:
    """The HIL bus; skips when it cannot be had here."""
    try:
        bus = hil_bus()
    except ValueError as error:
        pytest.fail(str(error))
    reason = bus_unavailable(bus)
    if reason:
        pytest.skip(reason)
    return bus


@pytest.fixture
def scenario_config(
    tmp_path: Path, hil_bus_spec: HilBus
) -> Callable[..., tuple[Path, AcquisitionConfig]]:
    """``scenario_config(sections=None, name="dtid.toml")``: write the scenario's config file
    into the test's folder (see :func:`hil.config.write_scenario_config`)."""

    def write(
        sections: Mapping[str, Mapping[str, Any]] | None = None, name: str = "dtid.toml"
    ) -> tuple[Path, AcquisitionConfig]:
        return write_scenario_config(tmp_path, hil_bus_spec, sections, name)

    return write


@pytest.fixture(scope="session")
def compiled_kernels() -> None:
    """Compile the numba kernels into their on-disk cache before any scenario starts.

    On a fresh clone the vehicle, daemon and worker would otherwise compile at the same time
    as the test runs; on one clean-clone CI run the vehicle's first frame went out 5.3 s late
    and the first chirp's coherence fell to 0.32. The scenarios test the running product, not
    its first start after an install.
    """
    from dtid.acquisition.plan import TestPlan
    from dtid.simulator.parameters import reference_parameters
    from dtid.simulator.plant_stepper import PlantStepper
    from dtid.simulator.simulate import SimulationOptions, replay_batch, simulate

    reference = reference_parameters()
    result = simulate(reference, TestPlan(amplitudes_nm=(1.0,), validation_nm=0.0, duration_s=2.0))
    t, value = result.request_t, result.test_torque_nm
    params = np.repeat(reference.as_array()[None], 2, axis=0)
    replay_batch(params, t, value, np.ones(2), 1.0, SimulationOptions())
    PlantStepper(reference).advance(0.01, 0.0)


@pytest.fixture
def run_hil_scenario(
    hil_bus_spec: HilBus, compiled_kernels: None
) -> Callable[..., subprocess.CompletedProcess[str]]:
    """``run_hil_scenario("name.py", *args, timeout=120)``: run ``scenarios/name.py`` with its
    processes on the HIL bus (in one private network namespace for udp_multicast)."""

    def run(script: str, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
        return run_scenario(SCENARIOS / script, *args, bus=hil_bus_spec, timeout=timeout)

    return run
