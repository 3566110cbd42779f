"""Does the model at the truth fit significantly worse than the optimum? (issue 15, part 4)

The truth of a vehicle is tested against the identified optimum as ``dtid identify --compare``
tests any parameter set (:mod:`dtid.identification.uncertainty.comparison`). On vehicles the
model side can repeat exactly (the randomised trial: the product's simulator with each truth's
own idle loop, engine and noise, which the model reads from the recording or is given) the test
should reject the truth about 5 % of the time: that is its calibration. On the independent
recordings a rejection says the model is still wrong about that vehicle by more than its
recordings' scatter.

    PYTHONPATH=. python benchmarks/truth_test.py --independent ../shared/independent/vehicle_1
    PYTHONPATH=. python benchmarks/truth_test.py --trial 1 2 3  # the trial's truths 1-3

Each case identifies with the default box and search (``--profile-points 0``), as
``benchmarks/identification_trial.py`` and docs/accuracy.md do, and prints one line. Not a
test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.identification_trial import PLAN, _drivetrain_of, trial_recording
from dtid.identification.pipeline import IdentificationReport, run_identification
from dtid.simulator.parameters import DrivetrainParameters, reference_parameters
from dtid.simulator.vehicle_data import load_vehicle_data
from dtid.workflow import measured_tests


def independent(folder: Path) -> tuple[IdentificationReport, DrivetrainParameters]:
    """An independent vehicle's three recordings identified as docs/accuracy.md does, and its
    truth."""
    tests = measured_tests(
        sorted(folder.glob("run_A*.*")),
        folder / "oem_vehicle.dbc",
        folder / "signals.toml",
        load_vehicle_data(folder / "truth.toml"),
    )
    truth = _drivetrain_of(str(folder / "truth.toml"))
    return run_identification(tests, reference_parameters(), profile_points=0), truth


def trial(
    index: int, sweep: tuple[float, float]
) -> tuple[IdentificationReport, DrivetrainParameters]:
    """The randomised trial's truth ``index`` simulated and identified as
    ``benchmarks/identification_trial.py --truth index`` does, and its truth."""
    truth, _, measured = trial_recording(index, sweep)
    return run_identification([measured], reference_parameters(), profile_points=0), truth


def main() -> None:
    """Identify each case, test its truth, print one line each and a count."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--independent", nargs="*", type=Path, default=[], metavar="DIR")
    parser.add_argument("--trial", nargs="*", type=int, default=[], metavar="N")
    parser.add_argument(
        "--sweep", nargs=2, type=float, default=(PLAN.f1_hz, PLAN.f2_hz), metavar=("F1", "F2")
    )
    args = parser.parse_args()
    cases = [(str(f), lambda f=f: independent(f)) for f in args.independent]
    cases += [(f"truth {n}", lambda n=n: trial(n, args.sweep)) for n in args.trial]
    rejected = 0
    for name, run in cases:
        began = time.perf_counter()
        report, truth = run()
        identified = time.perf_counter()
        comparison = report.compared(truth, "the truth").comparison
        assert comparison is not None
        rejected += comparison.fits_worse
        test = comparison.test
        print(
            f"{name}: eq. 17 truth {test.objective_other:.4f}, optimum "
            f"{test.objective_optimum:.4f}; likelihood ratio {test.statistic:.1f} over "
            f"{comparison.free} parameters, the drawn recordings' median "
            f"{np.median(test.null):.1f} and 95th percentile {test.critical:.1f}, p = "
            f"{test.p_value:.3g} (identification {identified - began:.0f} s, test "
            f"{time.perf_counter() - identified:.1f} s)",
            flush=True,
        )
    print(f"truth rejected at 5 %: {rejected} of {len(cases)}")


if __name__ == "__main__":
    main()
