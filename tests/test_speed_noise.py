"""The speed sensor's noise read near the crank events' Nyquist frequency
(:mod:`dtid.identification.model.speed_noise`): against a synthetic signal, the simulator's
recordings and the independent implementation's (whose truth gives the noise)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from dtid.acquisition.plan import TestPlan
from dtid.identification.model.idle_loop import idle_loop
from dtid.identification.model.speed_noise import speed_noise_rpm
from dtid.identification.samples.testdata import from_simulation
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.workflow import measured_tests

INDEPENDENT = Path(__file__).resolve().parents[2] / "shared" / "independent"


def test_white_noise_is_read_under_a_half_revolution_averaged_motion() -> None:
    """Ten minutes of a speed of 56.7 reports per second (850 rpm, four per revolution): a 3 Hz
    swing of 30 rpm, a chirp of 5 rpm over 1-15 Hz and the firing pulsation of 40 rpm, all
    averaged over two reports as the sensor's half revolution does, plus white noise of 0.25
    rpm: the noise comes back within 5 % (one seed of six 3.8 % low: the band holds few bins),
    and the motion alone reads below 0.02 rpm."""
    rate, n = 56.7, 32768
    t = np.arange(n) / rate
    chirp_phase = 2 * np.pi * (1.0 * t + 14.0 / (2 * t[-1]) * t**2)
    firing = 40 * np.cos(np.pi * rate * t)
    motion = 30 * np.sin(2 * np.pi * 3 * t) + 5 * np.sin(chirp_phase) + firing
    averaged = 850 + 0.5 * (motion + np.concatenate(([motion[0]], motion[:-1])))
    noise = np.random.default_rng(0).normal(0, 0.25, n)
    assert speed_noise_rpm(averaged + noise, rate) == pytest.approx(0.25, rel=0.05)
    assert speed_noise_rpm(averaged, rate) < 0.02
    assert np.isnan(speed_noise_rpm(averaged[:500], rate))  # too short for the band


@pytest.mark.parametrize("noise", [0.0, 0.3, 0.6])
def test_the_simulators_speed_noise_is_read_off_its_recordings(
    noise: float, reference: DrivetrainParameters
) -> None:
    """The reference vehicle at 5 and 10 N*m with 0, 0.3 and 0.6 rpm on each report, seed 3:
    read within 5 % (0.013 rpm without noise: what of the motion leaks into the band)."""
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0)
    options = SimulationOptions(speed_noise_rpm=noise)
    data = from_simulation(simulate(reference, plan, options, seed=3))
    found = idle_loop(data).speed_noise_rpm
    if noise == 0:
        assert found < 0.03
    else:
        assert found == pytest.approx(noise, rel=0.05)


@pytest.mark.skipif(not INDEPENDENT.is_dir(), reason=f"no independent recordings at {INDEPENDENT}")
@pytest.mark.parametrize("name", ["vehicle_1", "vehicle_2"])
def test_the_independent_recordings_speed_noise_is_their_truths(name: str) -> None:
    """Each of the three files of a vehicle the product did not make: within 15 % of the noise its
    truth gives (0.2 rpm per speed event; measured 0.186-0.216)."""
    folder = INDEPENDENT / name
    truth = tomllib.loads((folder / "truth.toml").read_text())["noise"]["sigma_n"]
    files = sorted(p for p in folder.iterdir() if p.stem.startswith("run_"))
    for test in measured_tests(
        files, folder / "oem_vehicle.dbc", folder / "signals.toml", folder / "truth.toml"
    ):
        assert test.loop.speed_noise_rpm == pytest.approx(truth, rel=0.15), test.name
