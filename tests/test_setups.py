"""The findings of section IV-B for setups 1-4, measured with the rise of each profile.

The rise (left, right) of a profile is how far it climbs on each side of its minimum inside the
bounds (:attr:`identification.profile.Profile.rise`); below ``FLAT_RISE`` it is flat. The paper's
findings, stated after its list of setups, are the assertions.
"""

from __future__ import annotations

import pytest

from identification.profile import FLAT_RISE
from identification.setups import profile_setup, setup

pytestmark = pytest.mark.slow
CHIRP_S = 30.0
CLEAR = 0.1
"""A clear minimum climbs at least this far on each side (NRMSE units)."""


@pytest.fixture(scope="module")
def profiles() -> dict:
    return {n: profile_setup(setup(n), duration_s=CHIRP_S) for n in (1, 2, 3)}


def test_setup1_only_the_mass_ratio_is_identifiable(profiles: dict) -> None:
    """Setup 1: J_sum, c, d and K flat (they scale together, eq. 19); x a clear minimum."""
    for name in ("J_sum", "c12", "d12", "K"):
        assert max(profiles[1][name].rise) < FLAT_RISE, name
        assert profiles[1][name].verdict == "no"
    assert min(profiles[1]["x1"].rise) > CLEAR


def test_setup2_stiffness_and_play_flat_towards_larger_values(profiles: dict) -> None:
    """Setup 2: c and eps have a minimum, flatter on the increasing side."""
    for name in ("c12", "eps12"):
        left, right = profiles[2][name].rise
        assert min(left, right) > FLAT_RISE, name
        assert right < left, name


def test_setup3_two_signals_steepen_stiffness_and_play(profiles: dict) -> None:
    """Setup 3: c and eps clearly steeper than in setup 2, on both sides."""
    for name in ("c12", "eps12"):
        (left2, right2), (left3, right3) = profiles[2][name].rise, profiles[3][name].rise
        assert left3 > 2 * left2 and right3 > 2 * right2, name
