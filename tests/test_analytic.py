"""Eqs. (20)-(23): one amplitude cannot split stiffness from free play; two can."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, optimize

from dtid.errors import AnalysisError
from dtid.identification.search.analytic import (
    free_play_for,
    inseparable,
    linearized_stiffness,
    stiffness_and_play,
)
from dtid.simulator.couplings import dead_zone


def test_two_amplitudes_recover_stiffness_and_play() -> None:
    c, eps = 300.0, 0.02
    c1, c2 = linearized_stiffness(c, eps, 2.0), linearized_stiffness(c, eps, 10.0)
    assert c1 < c2 < c  # the small amplitude sees the softer spring
    assert stiffness_and_play(2.0, c1, 10.0, c2) == pytest.approx((c, eps), rel=1e-12)


def test_one_amplitude_leaves_a_family() -> None:
    """Eq. (22): every stiffness above c_lin has a play giving the same c_lin."""
    c_lin, amplitude = linearized_stiffness(300.0, 0.02, 5.0), 5.0
    for c_star in (250.0, 400.0, 1e4):
        eps_star = free_play_for(c_lin, c_star, amplitude)
        assert eps_star > 0
        assert linearized_stiffness(c_star, eps_star, amplitude) == pytest.approx(c_lin)


def test_equal_amplitudes_or_stiffening_are_refused() -> None:
    with pytest.raises(AnalysisError, match="two different amplitudes"):
        stiffness_and_play(5.0, 200.0, 5.0, 200.0)
    with pytest.raises(AnalysisError, match="do not soften"):
        stiffness_and_play(2.0, 300.0, 10.0, 200.0)


def test_eq21_against_a_dead_zone_spring_in_quasi_static_loading() -> None:
    """The amplitude of a dead-zone spring under a slow sine gives the c_lin of eq. (21)."""
    c, eps, amplitude = 300.0, 0.02, 4.0

    def deflection(torque: float) -> float:  # solve c * dead_zone(delta) = torque
        return optimize.brentq(lambda d: c * dead_zone(d, eps / 2) - torque, -1.0, 1.0)

    peak = max(deflection(amplitude * math.sin(x)) for x in np.linspace(0, math.pi, 181))
    assert amplitude / peak == pytest.approx(linearized_stiffness(c, eps, amplitude), rel=1e-6)
    # and the energy it stores at the peak is that of the spring beyond the play only
    stored = integrate.quad(lambda d: c * dead_zone(d, eps / 2), 0, peak)[0]
    assert stored == pytest.approx(amplitude**2 / (2 * c), rel=1e-6)


def test_one_amplitude_makes_each_free_spring_and_play_pair_inseparable() -> None:
    setup4 = ("J_sum", "x1", "x12", "c12", "c23", "d12", "d23", "Tc12", "eps12", "eps23")
    reasons = inseparable(setup4, amplitude_levels=1)
    assert set(reasons) == {"c12", "eps12", "c23", "eps23"}
    assert reasons["c12"] == reasons["eps12"] != reasons["c23"]
    assert "eq. 22" in reasons["c23"] and "two amplitudes" in reasons["c23"]
    assert inseparable(setup4, amplitude_levels=2) == {}
    # with the play fixed (or absent from the model) the stiffness alone is identifiable
    assert set(inseparable(("c12", "d12", "c23", "eps23"), amplitude_levels=1)) == {"c23", "eps23"}
