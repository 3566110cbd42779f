"""The two-mass reduction, eqs. (18) and (19), against the three-mass model and its own claims."""

from __future__ import annotations

import numpy as np
import pytest

from dtid.simulator.linear import (
    three_mass_frf,
    three_mass_modes,
    two_mass_characteristics,
    two_mass_frf,
)
from dtid.simulator.parameters import DrivetrainParameters

F = np.linspace(0.5, 40.0, 2000)


def test_three_mass_with_a_rigid_clutch_is_eq18(reference: DrivetrainParameters) -> None:
    """With c23 -> infinity, J2 and J3 move as one: eq. (6) reduces to eq. (18) with K = 1."""
    rigid = reference.replace(c23=1e9, d23=0.0)
    j_sum = rigid.J1 + rigid.J2 + rigid.J3
    expected = two_mass_frf(F, j_sum, rigid.J1 / j_sum, rigid.c12, rigid.d12, 1.0)
    np.testing.assert_allclose(three_mass_frf(rigid, F), expected, rtol=1e-5)


def test_eq19_characteristics_describe_eq18() -> None:
    j_sum, x, c, d, gain = 0.3, 0.55, 300.0, 0.8, 0.9
    ch = two_mass_characteristics(j_sum, x, c, d, gain)
    omega = 2 * np.pi * F
    # asymptotes: K/(J_sum omega) well below, K/(x J_sum omega) well above the resonance
    far = np.array([1e-3, 1e4])
    g_far = np.abs(two_mass_frf(far, j_sum, x, c, d, gain)) * 2 * np.pi * far
    assert g_far == pytest.approx([ch.low_gain, ch.high_gain], rel=1e-4)
    # poles and zeros of eq. (18), found numerically, have the frequencies and damping of eq. (19)
    poles = np.roots([x * (1 - x) * j_sum / c, d / c, 1.0])
    zeros = np.roots([(1 - x) * j_sum / c, d / c, 1.0])
    assert abs(poles[0]) == pytest.approx(ch.omega_d, rel=1e-9)
    assert abs(zeros[0]) == pytest.approx(ch.omega_n, rel=1e-9)
    assert -poles[0].real / abs(poles[0]) == pytest.approx(ch.damping_d, rel=1e-9)
    assert -zeros[0].real / abs(zeros[0]) == pytest.approx(ch.damping_n, rel=1e-9)
    # and |G| * omega peaks at the resonance, dips at the anti-resonance (lightly damped)
    g = np.abs(two_mass_frf(F, j_sum, x, c, d, gain)) * omega
    assert omega[np.argmax(g)] == pytest.approx(ch.omega_d, rel=0.05)
    assert omega[np.argmin(g)] == pytest.approx(ch.omega_n, rel=0.02)


def test_only_the_mass_ratio_is_structurally_identifiable() -> None:
    """Scaling J_sum, c, d and K by one factor leaves |G| and eq. (19) unchanged (section IV-A)."""
    base = (0.3, 0.55, 300.0, 0.8, 0.9)
    alpha = 1.7
    scaled = (0.3 * alpha, 0.55, 300.0 * alpha, 0.8 * alpha, 0.9 * alpha)
    np.testing.assert_allclose(two_mass_frf(F, *base), two_mass_frf(F, *scaled), rtol=1e-12)
    assert two_mass_characteristics(*base) == pytest.approx(two_mass_characteristics(*scaled))
    other_x = (0.3, 0.6, 300.0, 0.8, 0.9)
    assert not np.allclose(np.abs(two_mass_frf(F, *base)), np.abs(two_mass_frf(F, *other_x)))


def test_reference_modes_lie_in_the_band(reference: DrivetrainParameters) -> None:
    low, high = three_mass_modes(reference)
    assert 1.0 < low < high < 15.0
