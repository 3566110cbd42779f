"""Would the phase of G_DRV help? Its fit at the truth and its information, on independent data.

Eq. (16) compares magnitudes only. The closed-loop estimate G = S_zy / S_zx (eq. 13) has a phase
too, and the model side estimates it the same way, so the phase could join the objective. For
each vehicle of ``../shared/independent`` (its 5 and 10 N*m recordings, its engine data) this
prints, at the truth and at the parameters of an identification JSON given with ``--at``:

* the phase of the measured G against the model's: the constant and the delay that fit their
  difference best (a timing of the vehicle's reports the model cannot know), and what is left,
  RMS in degrees, beside the magnitude's misfit in dB;
* each parameter's linearised 1-sigma precision (central differences of 3 %) from |G_DRV|
  alone, from the phase alone (a constant and a delay per run free) and from both, each bin's
  noise the misfit's RMS at the point and bins taken as independent (so the figures are lower
  bounds; their ratios are what to read).

The product's estimator keeps magnitudes; this captures the complex ratios on their way into
|G_DRV| (:func:`dtid.identification.frf.closed_loop.drivetrain_magnitude`). Not a test.

    PYTHONPATH=. python benchmarks/phase_information.py [--at vehicle_1=v1.json ...]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import tomllib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from dtid.identification.frf import closed_loop
from dtid.identification.model import response
from dtid.identification.pipeline import identification_runs
from dtid.identification.search.runs import engine_gain
from dtid.simulator.parameters import INDEX, NAMES, DrivetrainParameters
from dtid.simulator.vehicle_data import load_vehicle_data
from dtid.workflow import measured_tests

INDEPENDENT = Path(__file__).resolve().parents[2] / "shared" / "independent"
FREE = ("J1", "J2", "J3", "c12", "c23", "d12", "d23", "Tc12", "eps12", "eps23")
"""The drivetrain parameters whose precision is compared."""
STEP = 0.03
"""Relative step of the central differences (above the model's Monte Carlo jitter)."""
REALIZATIONS = 8
"""Model runs per parameter set."""


@contextlib.contextmanager
def ratios() -> Iterator[list[tuple[np.ndarray, np.ndarray]]]:
    """Record (frequency, S_zy / S_zx) of every |G_DRV| formed meanwhile, measured or model."""
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    original = closed_loop.drivetrain_magnitude

    def recording(f: np.ndarray, s_zy: np.ndarray, s_zx: np.ndarray, speed: float) -> np.ndarray:
        seen.append((np.asarray(f), np.asarray(s_zy / s_zx)))
        return original(f, s_zy, s_zx, speed)

    closed_loop.drivetrain_magnitude = response.drivetrain_magnitude = recording
    try:
        yield seen
    finally:
        closed_loop.drivetrain_magnitude = response.drivetrain_magnitude = original


def on_grid(grid: np.ndarray, f: np.ndarray, ratio: np.ndarray) -> np.ndarray:
    """The complex ratio on the measured grid (its magnitude and unwrapped phase interpolated)."""
    magnitude = np.interp(grid, f, np.abs(ratio))
    phase = np.interp(grid, f, np.unwrap(np.angle(ratio)))
    return magnitude * np.exp(1j * phase)


def timing(frequency: np.ndarray) -> np.ndarray:
    """A constant and a delay per frequency bin: the phase a report timing adds, (bins, 2)."""
    return np.vstack([np.ones_like(frequency), frequency]).T


def precision(jacobian: np.ndarray, sigma: np.ndarray, nuisance: np.ndarray | None) -> np.ndarray:
    """Linearised relative 1-sigma of each column of ``jacobian`` (weighted least squares, the
    ``nuisance`` columns free beside them)."""
    full = jacobian if nuisance is None else np.hstack([jacobian, nuisance])
    weighted = full / sigma[:, None]
    covariance = np.linalg.inv(weighted.T @ weighted)
    return np.sqrt(np.diag(covariance))[: jacobian.shape[1]]


def vehicle(folder: Path, points: dict[str, dict[str, float]]) -> None:
    """Print the phase's fit and information at each point for one vehicle."""
    files = sorted(f for f in folder.glob("run_A*.*") if not f.stem.endswith("A2"))
    with ratios() as measured:
        tests = measured_tests(
            files,
            folder / "oem_vehicle.dbc",
            folder / "signals.toml",
            load_vehicle_data(folder / "truth.toml"),
        )
    measured_by_name = {t.name: m for t, m in zip(tests, measured, strict=True)}
    selection = identification_runs(tests)
    k_gain = engine_gain(selection.tests)
    idle = float(np.mean([t.idle_torque_nm for t in selection.tests]))
    for label, values in points.items():
        base = DrivetrainParameters(**values).replace(K=k_gain, T_loss=idle).as_array()
        rows = [base]
        for name in FREE:
            for sign in (1, -1):
                row = base.copy()
                row[INDEX[name]] *= 1 + sign * STEP
                rows.append(row)
        mag, pha, mag_jac, pha_jac, nuisance = [], [], [], [], []
        for test, runs in zip(selection.tests, selection.runs, strict=True):
            (run,) = runs
            estimate = test.estimates[run]
            grid = estimate.frequency_hz
            data = on_grid(grid, *measured_by_name[test.name])
            model_test = dataclasses.replace(test.model_test(runs), realizations=REALIZATIONS)
            with ratios() as model:
                (db,) = response.model_drv_db(np.array(rows), model_test)
            phase = np.array([np.unwrap(np.angle(on_grid(grid, *m) / data)) for m in model])
            db = db - estimate.drv_db
            offset, delay = np.linalg.lstsq(timing(grid), phase[0], rcond=None)[0]
            left = phase[0] - timing(grid) @ [offset, delay]
            print(
                f"  {label:>6} {estimate.run.amplitude_nm:4.0f} N*m: the recording lags the model "
                f"by {delay / (2 * np.pi) * 1e3:.2f} ms and {-np.degrees(offset):+.2f} deg, then "
                f"{np.degrees(np.sqrt(np.mean(left**2))):.2f} deg RMS; "
                f"|G_DRV| {np.sqrt(np.mean(db[0] ** 2)):.3f} dB RMS"
            )
            mag.append(np.full(len(grid), np.sqrt(np.mean(db[0] ** 2))))
            pha.append(np.full(len(grid), np.sqrt(np.mean(left**2))))
            mag_jac.append((db[1::2] - db[2::2]).T / (2 * STEP))
            pha_jac.append((phase[1::2] - phase[2::2]).T / (2 * STEP))
            block = np.zeros((len(grid), 2 * len(selection.tests)))
            at = 2 * len(nuisance)
            block[:, at : at + 2] = timing(grid)
            nuisance.append(block)
        log_sigma = np.log(10) / 20 * np.concatenate(mag)  # dB -> the natural log of |G|
        rad_sigma = np.concatenate(pha)
        to_log = np.log(10) / 20
        j_mag, j_pha = to_log * np.vstack(mag_jac), np.vstack(pha_jac)
        n_block = np.vstack(nuisance)
        alone = precision(j_mag, log_sigma, None)
        phase_alone = precision(j_pha, rad_sigma, n_block)
        both = precision(
            np.vstack([j_mag, j_pha]),
            np.concatenate([log_sigma, rad_sigma]),
            np.vstack([np.zeros_like(n_block), n_block]),
        )
        print(f"  {label:>6}: 1-sigma %, bins independent: |G_DRV| / phase / both")
        for name, a, p, b in zip(FREE, alone, phase_alone, both, strict=True):
            print(f"         {name:>6} {100 * a:6.2f} {100 * p:6.2f} {100 * b:6.2f}")


def main() -> None:
    """Print, per independent vehicle, the phase's fit and information."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--at", nargs="*", default=[], help="VEHICLE=identification.json: also at its parameters"
    )
    args = parser.parse_args()
    found = dict(item.split("=", 1) for item in args.at)
    folders = sorted(INDEPENDENT.glob("vehicle_*"))
    if not folders:
        print(f"no independent recordings in {INDEPENDENT}")
    for folder in folders:
        with (folder / "truth.toml").open("rb") as handle:
            table = tomllib.load(handle)["drivetrain"]
        points = {"truth": {n: table[n] for n in NAMES}}
        if folder.name in found:
            identified = json.loads(Path(found[folder.name]).read_text())["parameters"]
            points["found"] = {n: identified.get(n, table[n]) for n in NAMES}
        print(folder.name, flush=True)
        vehicle(folder, points)


if __name__ == "__main__":
    main()
