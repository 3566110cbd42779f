"""The profiles' threshold against one drawn from the model's own recordings.

A profile interval ends where the likelihood-ratio statistic, small-sample corrected, crosses
3.84 (docs/method.md, *Profiles*): chi-square with one degree of freedom, the noise's
correlation over bins read from the residuals. ``dtid identify --compare`` showed that with ten
parameters at once that reading is too short (the fit follows errors correlated along the
sweep further than it says: docs/method.md, *Another drivetrain against the identified one*).
Does it hold for one parameter? For each of the randomised trial's stored recordings
(``benchmarks/results/identification_trial/truthN.json``: the trial's truth N, its search's
optimum), this draws recordings of the model at that optimum, fits each to first order with all
parameters free and with one held, and takes the 95th percentile of the profile's statistic
over the draws, in the product's corrected units: where it lies near 3.84 the threshold is
right. It also re-reads each stored profile's interval with either threshold.

    PYTHONPATH=. python benchmarks/profile_thresholds.py --truths 21 22 23  # ... 50

Not a test: nothing is asserted. The intervals re-read here cross the threshold between the
stored profile points alone (no neighbour smoothing, no bisection at the new threshold), so
their misses differ from the trial's own count; compare the two thresholds' counts.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.identification_trial import trial_recording
from dtid.identification.model.response import model_drv_db
from dtid.identification.pipeline import run_identification
from dtid.identification.search.identify import SearchSettings
from dtid.identification.search.parameterization import THETA_NAMES, theta_from_parameters
from dtid.identification.uncertainty.comparison import jacobian_db, model_recordings
from dtid.identification.uncertainty.profile import interval_and_verdict
from dtid.identification.uncertainty.statistic import (
    CONFIDENCE,
    THRESHOLD,
    independent_bins,
    small_sample_factor,
    statistic,
)
from dtid.simulator.parameters import reference_parameters

RESULTS = Path(__file__).parent / "results" / "identification_trial"
DRAWS = 60
NO_SEARCH = SearchSettings(
    generations=1, popsize=2, polish_evaluations=5, polish_starts=1, scan_starts=0,
    final_starts=1, newton_iterations=0,
)  # fmt: skip
"""The identification's operating point and box without its search: the optimum is stored."""


def thresholds(index: int) -> tuple[dict[str, float], dict[str, tuple[bool, bool]]]:
    """Truth ``index``'s drawn threshold per parameter (corrected units) and whether its stored
    profile's interval holds the truth with (3.84, the drawn threshold)."""
    stored = json.loads((RESULTS / f"truth{index}.json").read_text())
    truth, _, measured = trial_recording(index)
    report = run_identification([measured], reference_parameters(), settings=NO_SEARCH,
                                profile_points=0)  # fmt: skip
    par, fit = report.parameterization, report.fit
    assert par is not None and fit is not None
    true_theta = theta_from_parameters(truth)
    found = [true_theta[n] * (1 + stored["error_percent"][n] / 100) for n in THETA_NAMES]
    unit = np.clip(par.unit(np.array([found]))[0], 0.0, 1.0)
    objective = fit.objective(par).replacing(realizations=8, seed=9_200)
    measured_db = [data for run in objective.measured_db for data in run]
    row = par.parameters(unit[None])
    best = [curves[0] for test in objective.tests for curves in model_drv_db(row, test)]
    factor = small_sample_factor(independent_bins(measured_db, best), len(par.free))
    jac = jacobian_db(objective, unit)
    draws = model_recordings(objective, row, DRAWS)
    centre, noise = draws.mean(axis=0), draws - draws.mean(axis=0)
    edges = np.cumsum([len(data) for data in measured_db])[:-1]
    fitted = noise @ (jac @ np.linalg.pinv(jac)).T
    drawn, inside = {}, {}
    for j, name in enumerate(par.free):
        others = np.delete(jac, j, axis=1)
        held = noise @ (others @ np.linalg.pinv(others)).T
        lams = [
            statistic(*(np.split(centre + x, edges) for x in (e, f, h)))
            for e, f, h in zip(noise, fitted, held, strict=True)
        ]
        drawn[name] = float(np.quantile(lams, CONFIDENCE)) / factor
        profile = stored["profiles"].get(name)
        if profile:
            inside[name] = tuple(
                _holds(profile, threshold, true_theta[name])
                for threshold in (THRESHOLD, drawn[name])
            )
    return drawn, inside


def _holds(profile: dict, threshold: float, truth: float) -> bool:
    """Whether the stored profile's interval at ``threshold`` holds the truth: the profiles' own
    reading (:func:`dtid.identification.uncertainty.profile.interval_and_verdict`, crossing in
    the statistic's root) of the statistic less its margin, scaled so that ``threshold`` falls
    on their 3.84."""
    values = np.array(profile["values"], dtype=float)
    stat = np.array([np.inf if s is None else s for s in profile["statistic"]], dtype=float)
    stat -= np.array([0.0 if m is None else m for m in profile["margin"]], dtype=float)
    order = np.argsort(values)
    values, stat = values[order], stat[order] * THRESHOLD / threshold
    (lower, upper), _ = interval_and_verdict(values, stat, values[int(np.argmin(stat))])
    return (lower is None or lower <= truth) and (upper is None or truth <= upper)


def main() -> None:
    """Print each truth's drawn thresholds and the summary over them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--truths", nargs="+", type=int, required=True, metavar="N")
    args = parser.parse_args()
    every: list[float] = []
    misses = [0, 0]
    count = 0
    for index in args.truths:
        drawn, inside = thresholds(index)
        every += drawn.values()
        for held in inside.values():
            count += 1
            misses[0] += not held[0]
            misses[1] += not held[1]
        print(f"truth {index}: " + ", ".join(f"{n} {t:.1f}" for n, t in drawn.items()), flush=True)
    low, mid, high = np.quantile(every, [0.05, 0.5, 0.95])
    print(
        f"drawn thresholds: median {mid:.2f}, 5-95 % {low:.2f}-{high:.2f} (the product's "
        f"{THRESHOLD:.2f}); stored intervals re-read: {misses[0]} of {count} miss the truth "
        f"with {THRESHOLD:.2f}, {misses[1]} with the drawn thresholds"
    )


if __name__ == "__main__":
    main()
