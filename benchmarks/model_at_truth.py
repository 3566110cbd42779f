"""Is the model right at the truth? Its |G_DRV| against the mean of many recordings of a vehicle.

One recording's |G_DRV| scatters by 0.1-0.2 dB, so a model error of a few hundredths of a dB
shows only in the mean of many. Each of ``--recordings`` recordings of the randomised trial's
vehicle ``--truth N`` (its own idle loop, engine and noise; noise seeds 500, 501, ...) is
repeated by the model at the true drivetrain, with the recording's own idle loop and K and
T_loss at their true values, and ``--realizations`` model runs (model seed = the recording's
index, so the model's own draws average out too). Per identifying run it prints the mean of
measured minus model, its RMS over the bins, and chi-square per bin of that mean against its
standard error: about 1 where the model is right, and the bins where |z| > 3.

    PYTHONPATH=. python benchmarks/model_at_truth.py --truth 1 --recordings 32
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from benchmarks.identification_trial import PLAN, draw_truth, draw_vehicle
from dtid.identification.model.response import model_drv_db
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.testdata import from_simulation
from dtid.simulator.simulate import simulate
from dtid.simulator.vehicle_data import VehicleData

RESOLUTION_HZ = 0.25
"""Welch resolution of the FRFs, Hz (the product's default)."""


def main() -> None:
    """Print the model's error at the truth, averaged over recordings."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--truth", type=int, default=1, help="randomised trial's truth")
    parser.add_argument("--recordings", type=int, default=32)
    parser.add_argument("--realizations", type=int, default=4, help="model runs per recording")
    args = parser.parse_args()
    truth, vehicle = draw_truth(args.truth), draw_vehicle(args.truth)
    known = VehicleData(vehicle.engine, vehicle.speed_average, ("all",), "truth")
    differences: list[list[np.ndarray]] = [[], []]
    for k in range(args.recordings):
        recording = from_simulation(simulate(truth, PLAN, vehicle, seed=500 + k))
        measured = MeasuredTest.from_data("trial", recording, RESOLUTION_HZ, known)
        test = dataclasses.replace(
            measured.model_test([0, 1], realizations=args.realizations), seed=k
        )
        for run, model in enumerate(model_drv_db(truth.as_array()[None], test)):
            differences[run].append(measured.estimates[run].drv_db - model[0])
    print(f"truth {args.truth}: {args.recordings} recordings, {args.realizations} model runs each")
    for run, rows in enumerate(differences):
        block = np.array(rows)
        mean = block.mean(axis=0)
        z = mean / (block.std(axis=0, ddof=1) / np.sqrt(len(block)))
        frequency = measured.estimates[run].frequency_hz
        off = [
            f"{f:.1f} Hz {m:+.2f} dB"
            for f, m, zi in zip(frequency, mean, z, strict=True)
            if abs(zi) > 3
        ]
        print(
            f"{measured.estimates[run].run.amplitude_nm:g} N*m: mean measured - model "
            f"{np.sqrt(np.mean(mean**2)):.3f} dB RMS (one recording "
            f"{np.sqrt(np.mean(block.std(axis=0, ddof=1) ** 2)):.3f}), chi-square per bin "
            f"{np.mean(z**2):.2f}; |z| > 3 at " + (", ".join(off) or "none")
        )


if __name__ == "__main__":
    main()
