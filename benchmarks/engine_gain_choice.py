"""Which K the search holds: eq. (24)'s against the strokes' own, on random vehicles.

Eq. (24) reads the engine's torque gain K as the mean of the measured |G_ENG|
(:func:`dtid.identification.search.runs.engine_gain`); the idle loop also reads K stroke by
stroke, each stroke's mean torque against the request it latched (``idle_loop.engine_gain``).
The search holds eq. (24)'s unless the two differ by more than
:data:`dtid.identification.gain_choice.GAIN_DISAGREE` (:func:`dtid.identification.
gain_choice.held_gain`). This simulates the recordings of
:mod:`benchmarks.diagnosis_calibration` (random vehicles with their own idle loops, ECU timing,
engines and noise; the vehicle's engine data given) and identifies each twice with the default
search, holding each K in turn:

    PYTHONPATH=. python benchmarks/engine_gain_choice.py --vehicles 53 34 51
    PYTHONPATH=. python benchmarks/engine_gain_choice.py --trial --vehicles 6 14

(``--trial``: the identification trial's recordings of its truths N,
:mod:`benchmarks.identification_trial`, instead of the calibration's.)

Prints, per vehicle and K, the K, eq. (17) at the optimum and at the truth (with that K), and
every searched parameter's error against the truth, %. A benchmark, not a test: nothing is
asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

from benchmarks.diagnosis_calibration import recording
from dtid.identification.pipeline import identification_runs, run_identification
from dtid.identification.search.parameterization import THETA_NAMES, theta_from_parameters
from dtid.identification.search.runs import engine_gain
from dtid.simulator.parameters import reference_parameters


def main() -> None:
    """Identify each vehicle with both gains and print a row for each."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, nargs="+", default=[53])
    parser.add_argument(
        "--trial",
        action="store_true",
        help="the identification trial's recordings of these truths (noise seed 100 + N)",
    )
    args = parser.parse_args()
    for index in args.vehicles:
        truth, test = recording(index, 100 + index if args.trial else None)
        true_theta = theta_from_parameters(truth)
        fit = identification_runs([test])
        kept = fit.tests[0]
        identifying = dataclasses.replace(
            kept, estimates=tuple(kept.estimates[i] for i in fit.runs[0])
        )
        spans = [(e.run.start_s, e.run.end_s) for e in identifying.estimates]
        gains = {"eq. 24": engine_gain([identifying]), "strokes": kept.loop.engine_gain(spans)[0]}
        for label, gain in gains.items():
            began = time.perf_counter()
            report = run_identification(
                [test], reference_parameters(), profile_points=0, fixed={"K": gain}
            )
            found = report.identification
            row = {
                "vehicle": index,
                "K": label,
                "value": found.parameters.K,
                "true_K": truth.K,
                "objective": found.objective,
                "objective_at_truth": report.fit_objective(truth),
                "error_percent": {
                    n: round(100 * (found.theta[n] / true_theta[n] - 1), 1) for n in THETA_NAMES
                },
                "seconds": round(time.perf_counter() - began, 1),
            }
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
