"""Which speed sensor does a recording's truth fit? Eq. (17) at the truth with each arithmetic.

The speed sensor's arithmetic (``[sensors] speed_average``: a tooth timer's ``"times"``, the
default, or eq. (9)'s ``"speeds"``) is vehicle data the identification cannot read off a
recording: at the optimum the drivetrain absorbs the difference. At the truth it cannot, so
there the right sensor shows. For each randomised-trial vehicle given (``--truths``: its own
idle loop, engine, noise and sensor, the recording's noise seed 100 + N as in
``identification_trial.py``) and, when present, each vehicle of ``../shared/independent``
(``--independent``), it prints eq. (17) of the identifying runs at the true drivetrain (K and
T_loss as measured) with each sensor in the model, the mean over ``--seeds`` model seeds, and
per run.

    PYTHONPATH=. python benchmarks/speed_sensor.py --truths 0 1 2 3 4 5 6 --independent
"""

from __future__ import annotations

import argparse
import dataclasses
import tomllib
from pathlib import Path

import numpy as np

from benchmarks.identification_trial import PLAN, draw_truth, draw_vehicle
from dtid.identification.model.response import model_drv_db
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import identification_runs
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.objective import nrmse
from dtid.identification.search.runs import engine_gain
from dtid.simulator.kernel import SPEED_AVERAGES
from dtid.simulator.parameters import NAMES, DrivetrainParameters
from dtid.simulator.simulate import simulate
from dtid.simulator.vehicle_data import VehicleData, load_vehicle_data
from dtid.workflow import measured_tests

INDEPENDENT = Path(__file__).resolve().parents[2] / "shared" / "independent"


def at_truth(tests: list[MeasuredTest], truth: DrivetrainParameters, seeds: int) -> np.ndarray:
    """NRMSE of each identifying run at the truth, averaged over ``seeds`` model seeds."""
    selection = identification_runs(tests)
    idle = float(np.mean([t.idle_torque_nm for t in selection.tests]))
    row = truth.replace(K=engine_gain(selection.tests), T_loss=idle).as_array()[None]
    values = []
    for seed in range(seeds):
        per_run = []
        for test, runs in zip(selection.tests, selection.runs, strict=True):
            model = dataclasses.replace(test.model_test(runs), seed=seed)
            for i, curves in zip(runs, model_drv_db(row, model), strict=True):
                per_run.append(float(nrmse(test.estimates[i].drv_db, curves)[0]))
        values.append(per_run)
    return np.mean(values, axis=0)


def line(name: str, own: str, fits: dict[str, np.ndarray]) -> str:
    """One vehicle's row: eq. (17) with each sensor, per run in brackets."""
    cells = [
        f"{average} {fit.sum():.4f} ({', '.join(f'{v:.4f}' for v in fit)})"
        for average, fit in fits.items()
    ]
    best = min(fits, key=lambda average: fits[average].sum())
    return f"{name:>10} (sensor {own}): " + " | ".join(cells) + f" -> fits {best}"


def main() -> None:
    """Print eq. (17) at the truth with each speed sensor, vehicle by vehicle."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--truths", type=int, nargs="*", default=[0, 1, 2, 3, 4, 5, 6])
    parser.add_argument("--independent", action="store_true", help="../shared/independent too")
    parser.add_argument("--seeds", type=int, default=4, help="model seeds averaged")
    args = parser.parse_args()
    for n in args.truths:
        truth, vehicle = draw_truth(n), draw_vehicle(n)
        data = from_simulation(simulate(truth, PLAN, vehicle, seed=100 + n))
        fits = {}
        for average in SPEED_AVERAGES:
            known = VehicleData(vehicle.engine, average, ("all",), "truth")
            fits[average] = at_truth(
                [MeasuredTest.from_data("trial", data, 0.25, known)], truth, args.seeds
            )
        print(line(f"truth {n}", vehicle.speed_average, fits), flush=True)
    folders = sorted(INDEPENDENT.glob("vehicle_*")) if args.independent else []
    if args.independent and not folders:
        print(f"no independent recordings in {INDEPENDENT}")
    for folder in folders:
        with (folder / "truth.toml").open("rb") as handle:
            table = tomllib.load(handle)["drivetrain"]
        truth = DrivetrainParameters(**{name: table[name] for name in NAMES})
        files = sorted(folder.glob("run_A*.*"))
        fits = {}
        for average in SPEED_AVERAGES:
            vehicle = dataclasses.replace(
                load_vehicle_data(folder / "truth.toml"), speed_average=average
            )
            tests = measured_tests(
                files, folder / "oem_vehicle.dbc", folder / "signals.toml", vehicle
            )
            fits[average] = at_truth(tests, truth, args.seeds)
        print(line(folder.name, "not disclosed", fits), flush=True)


if __name__ == "__main__":
    main()
