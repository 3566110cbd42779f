"""Coupling physics of eq. (6): dead zone, Coulomb friction impulse, physical backlash."""

from __future__ import annotations

import math

import pytest

from dtid.simulator.couplings import (
    backlash_torque,
    backlash_update,
    dead_zone,
    dmf_smooth_torque,
    friction_impulse,
)


def test_dead_zone_eq7() -> None:
    assert dead_zone(0.005, 0.01) == 0.0
    assert dead_zone(0.03, 0.01) == pytest.approx(0.02)
    assert dead_zone(-0.03, 0.01) == pytest.approx(-0.02)
    assert dmf_smooth_torque(0.0, 2.0, 300.0, 1.0, 0.01) == pytest.approx(2.0)  # damper acts always


def test_friction_sticks_when_it_can_and_slips_otherwise() -> None:
    inv1, inv2, h = 1 / 0.15, 1 / 0.13, 1e-3
    # small relative velocity: the impulse removes it exactly (stick)
    p = friction_impulse(0.001, inv1, inv2, 0.3, h)
    assert 0.001 - p * (inv1 + inv2) == pytest.approx(0.0, abs=1e-15)
    # large relative velocity: the impulse is Tc * h against sliding
    assert friction_impulse(5.0, inv1, inv2, 0.3, h) == pytest.approx(0.3 * h)
    assert friction_impulse(-5.0, inv1, inv2, 0.3, h) == pytest.approx(-0.3 * h)


def test_backlash_transmits_nothing_inside_the_gap() -> None:
    half = 0.006
    assert backlash_torque(0.002, 1.0, 0.002, 80.0, 0.3, half) == 0.0
    # on the upper stop the coupling pushes, never pulls
    assert backlash_torque(0.01, 0.0, half, 80.0, 0.3, half) == pytest.approx(80.0 * 0.004)
    assert backlash_torque(0.006, -10.0, half, 80.0, 0.3, half) == 0.0


def test_backlash_state_relaxes_with_rate_c_over_d() -> None:
    # inside the gap the twist delta - b decays as exp(-c/d h) with delta held still
    b = backlash_update(0.001, 0.001, 0.0, 80.0, 0.3, 0.006, 1e-3)
    assert 0.001 - b == pytest.approx(0.001 * math.exp(-80.0 / 0.3 * 1e-3))
    # reaching the stop: the state rests on it
    assert backlash_update(0.02, 0.0, 0.0, 80.0, 0.3, 0.006, 1e-3) == 0.006
    # without damping the twist vanishes at once: a pure dead-zone spring
    assert backlash_update(0.003, 0.001, 0.0, 80.0, 0.0, 0.006, 1e-3) == 0.003


def test_no_play_is_a_plain_spring_damper() -> None:
    assert backlash_torque(0.01, 1.0, 0.0, 80.0, 0.3, 0.0) == pytest.approx(0.8 + 0.3)
    assert backlash_update(0.01, 0.0, 0.0, 80.0, 0.3, 0.0, 1e-3) == 0.0
