"""Engine torque tables against closed forms of eqs. (2), (4) and (5)."""

from __future__ import annotations

import numpy as np

from dtid.simulator.angle_grid import N_CYL, STEP_RAD, STEPS_PER_CYCLE, STEPS_PER_STROKE
from dtid.simulator.engine import EngineGeometry, EngineTables, engine_tables

PHI = np.arange(STEPS_PER_CYCLE) * STEP_RAD


def _step_mean(values: np.ndarray) -> np.ndarray:
    return 0.5 * (values + np.roll(values, -1))


def _cylinder_sum(table: np.ndarray) -> np.ndarray:
    return sum(np.roll(table, STEPS_PER_STROKE * i) for i in range(N_CYL))


def test_combustion_orders_of_four_cylinders() -> None:
    # Summed over four cylinders fired every pi, only orders 2 and 4 of eq. (2) survive and
    # sin(4 pi/4) = 0 removes order 4: T_cmb = T_m (1 + 4/pi sin(2 phi)).
    total = _cylinder_sum(engine_tables().combustion_shape)
    np.testing.assert_allclose(total, _step_mean(1 + 4 / np.pi * np.sin(2 * PHI)), atol=1e-12)


def test_inertia_torque_of_four_cylinders() -> None:
    # Eq. (5) summed over four cylinders: orders 1 and 3 cancel,
    # T_j / omega^2 = -m r^2 (2 sin 2phi + lambda^2 sin 4phi).
    g = EngineGeometry()
    lam = g.crank_radius_m / g.rod_length_m
    expected = (
        -g.oscillating_mass_kg
        * g.crank_radius_m**2
        * (2 * np.sin(2 * PHI) + lam**2 * np.sin(4 * PHI))
    )
    np.testing.assert_allclose(engine_tables().inertia, _step_mean(expected), atol=1e-12)


def test_compression_torque_is_lossless_and_periodic_per_stroke() -> None:
    table = engine_tables().compression
    assert abs(table.mean()) < 1e-9 * np.abs(table).max()  # isentropic: no net work
    np.testing.assert_allclose(table, np.roll(table, STEPS_PER_STROKE), atol=1e-9)
    # peak torque of a few tens of N*m at 0.35 bar manifold pressure, as at idle
    assert 20 < np.abs(table).max() < 100


def test_disabled_engine_delivers_the_stroke_mean() -> None:
    tables = EngineTables.disabled()
    np.testing.assert_array_equal(_cylinder_sum(tables.combustion_shape), 1.0)
    assert not tables.compression.any() and not tables.inertia.any()
