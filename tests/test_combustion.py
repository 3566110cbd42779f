"""The combustion variation told apart from the torque sensor's noise."""

from __future__ import annotations

import numpy as np
import pytest

from dtid.acquisition.plan import TestPlan
from dtid.identification.model.combustion import stroke_variation, variation_and_noise
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.testdata import TestData, from_simulation
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, simulate


def test_stroke_variation_of_a_known_sequence() -> None:
    rng = np.random.default_rng(0)
    torque = 15.0 * (1 + 0.03 * rng.standard_normal(20000)) + np.linspace(0, 2, 20000)
    assert stroke_variation(torque) == pytest.approx(0.03 * 15 / np.mean(torque), rel=0.02)


@pytest.mark.parametrize(("variation", "noise"), [(0.03, 0.3), (0.02, 0.0), (0.0, 0.4)])
def test_variation_and_noise_of_known_strokes(variation: float, noise: float) -> None:
    """Strokes swept from 5 to 25 N*m as a chirp sweeps them: the relative variation and the
    additive noise come back, a missing one as about zero."""
    rng = np.random.default_rng(4)
    delivered = 15 + 10 * np.sin(0.3 * np.arange(4000))
    measured = delivered * (1 + variation * rng.standard_normal(4000))
    measured += noise * rng.standard_normal(4000)
    v, s = variation_and_noise(delivered, measured)
    assert v == pytest.approx(variation, abs=0.002)
    assert s == pytest.approx(noise, abs=0.03)


def test_too_few_strokes_give_nothing() -> None:
    assert all(np.isnan(variation_and_noise(np.ones(10), np.ones(10))))


def test_a_simulated_recording_gives_its_truth_back(reference: DrivetrainParameters) -> None:
    """The simulator's 3 % and 0.3 N*m (the idle scatter, sensor noise included, 0.036)."""
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=30.0)
    data = from_simulation(simulate(reference, plan, SimulationOptions(), seed=7))
    measured = MeasuredTest.from_data("x", data, 0.25)
    assert measured.loop.combustion_variation == pytest.approx(0.03, rel=0.1)
    assert measured.loop.torque_noise_nm == pytest.approx(0.3, rel=0.15)
    assert measured.combustion_variation == measured.loop.combustion_variation
    bare = MeasuredTest.from_data(
        "without T_ecu", TestData(data.speed, data.mean_torque, data.test_torque), 0.25
    )
    assert np.isnan(bare.loop.combustion_variation)
    idle_scatter = np.hypot(0.03, 0.3 / reference.T_loss)  # the model adds none then
    assert bare.combustion_variation == pytest.approx(idle_scatter, rel=0.15)


def test_a_few_wild_strokes_do_not_move_the_noise() -> None:
    """Twenty strokes whose request the log lost (off by 5-15 N*m at high load) among 4000."""
    rng = np.random.default_rng(5)
    delivered = 15 + 10 * np.sin(0.3 * np.arange(4000))
    measured = delivered * (1 + 0.03 * rng.standard_normal(4000)) + 0.3 * rng.standard_normal(4000)
    wild = np.flatnonzero(delivered > 22)[:20]
    measured[wild] += rng.uniform(5, 15, len(wild))
    v, s = variation_and_noise(delivered, measured)
    assert v == pytest.approx(0.03, abs=0.002)
    assert s == pytest.approx(0.3, abs=0.03)
