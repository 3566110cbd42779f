"""A refit with and without its runner-up refine: eq. (17), the test's likelihood ratio, time.

A refit's search (:meth:`dtid.identification.diagnosis.refit.Refit.search`) refines its best
point and, where eq. (17) there lies within :data:`~dtid.identification.diagnosis.refit.
RUNNER_UP` of the best's, the runner-up too. This simulates and identifies one case of the
blind diagnosis trial (:mod:`benchmarks.diagnosis_trial`; default: case 27, a progressive
spring), screens the identified model as the diagnosis does, and refits one mechanism from the
screen's ladder (and the model without it) with the margin at zero and at its default, each
``--repeats`` times, alternating:

    PYTHONPATH=. python benchmarks/refit_runner_up.py
    PYTHONPATH=. python benchmarks/refit_runner_up.py --case 19 --mechanism progressive_spring

Prints one row per refit. A benchmark, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
import json
import time

from benchmarks.diagnosis_trial import simulate_case
from dtid.identification.diagnosis import refit as refit_module
from dtid.identification.diagnosis.mismatch import DRAWS, mismatch_map
from dtid.identification.diagnosis.refit import Extra, Refit, _ladder
from dtid.identification.pipeline import run_identification
from dtid.simulator.mechanisms import BY_NAME
from dtid.simulator.parameters import reference_parameters


def main() -> None:
    """Run the refits and print each row."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", type=int, default=27, help="blind-trial case number")
    parser.add_argument("--mechanism", default="progressive_spring")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--clean", type=float, default=0.25, help="the trial's clean share")
    args = parser.parse_args()
    _, _, test = simulate_case(args.case, args.clean)
    report = run_identification([test], reference_parameters(), profile_points=0)
    refit = Refit(report.identification.parameters, report.fit, report.validation)
    selections = [("fit", report.fit), ("validation", report.validation)]
    found = mismatch_map(report.identification.parameters, selections, DRAWS)
    row = refit.start_row()
    (screened,) = [s for s in refit.screen(found) if s.mechanism == args.mechanism]
    mechanism = (BY_NAME[args.mechanism],)
    k = len(mechanism[0].parameters)
    baseline, _ = refit.refit(Extra(refit.base, row, ()))
    default = refit_module.RUNNER_UP
    for _ in range(args.repeats):
        for margin in (0.0, default):
            refit_module.RUNNER_UP = margin
            for label, extra, ladder in (
                ("without", Extra(refit.base, row, ()), []),
                (args.mechanism, Extra(refit.base, row, mechanism), _ladder(screened, row, True)),
            ):
                began = time.perf_counter()
                reached, value = refit.refit(extra, ladder)
                seconds = time.perf_counter() - began
                statistic = None
                if label != "without":
                    tested = refit.test((args.mechanism,), reached, baseline, k, tried=1)
                    statistic = round(tested.statistic, 1)
                print(
                    json.dumps(
                        {
                            "case": args.case,
                            "refit": label,
                            "runner_up": margin,
                            "eq17": round(value, 5),
                            "statistic": statistic,
                            "seconds": round(seconds, 1),
                        }
                    ),
                    flush=True,
                )
    refit_module.RUNNER_UP = default


if __name__ == "__main__":
    main()
