"""Diagnosis ceiling: could the blind trial's missed mechanisms be named from these runs at all?

The diagnosis refits each candidate on the identifying runs and accepts it only where the
improvement is significant there and the held-out run follows (issue 17's rule). Where the blind
trial (:mod:`benchmarks.diagnosis_trial`) misses a visible mechanism, two causes are possible:
the diagnosis's search did not find the mechanism's optimum, or the identifying runs do not
carry it (a drivetrain without it explains them as well). This benchmark tells them apart with
what the product never has, the truth. For each case it simulates and identifies the trial's
recording again (the same draws and seed), refits the model without the mechanism as the
diagnosis does (:meth:`dtid.identification.diagnosis.refit.Refit.refit`), and fits the model
*with* the concealed mechanism in the truth's own basin: polished from the truth (all setup-4
parameters and the mechanism's free) and searched from there
(:meth:`dtid.identification.diagnosis.refit.Refit.search`), the better of the two kept. The
diagnosis's own test (:meth:`dtid.identification.diagnosis.refit.Refit.test`) then compares
them: the likelihood ratio, its p-value alone and family-wise over the candidates the
diagnosis tests on |G_DRV| (:data:`CANDIDATES`, Sidak), and the held-out run's gain.

A mechanism this test finds insignificant at the truth, or whose held-out run does not follow
it there, cannot be accepted by any search on these runs under the issue's rule: the miss is
the data's (``acceptable`` false). One it accepts (``acceptable``: significant family-wise and
the held-out run better) is a miss of the diagnosis.

    PYTHONPATH=. python benchmarks/diagnosis_ceiling.py               # the trial's misses
    PYTHONPATH=. python benchmarks/diagnosis_ceiling.py --cases 6 15

Writes ``benchmarks/results/diagnosis_ceiling.json``. A benchmark, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
import datetime
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.diagnosis_trial import RESULTS, VISIBLE_DB, simulate_case
from dtid.identification.diagnosis.bin_statistics import sidak
from dtid.identification.diagnosis.refit import ACCEPT_P, REFIT_SETTINGS, Extra, Refit
from dtid.identification.pipeline import run_identification
from dtid.identification.search.identify import refine
from dtid.jsonfile import json_number, write_json
from dtid.simulator.mechanisms import BY_NAME, EXTRA_INDEX, MECHANISMS, kernel_parameters
from dtid.simulator.parameters import reference_parameters

CANDIDATES = len(MECHANISMS) - 1
"""Candidates the diagnosis refits on |G_DRV| against one model (the library but the cylinder
imbalance, which the strokes decide): the family of its Sidak correction on the trial's runs."""


def visible_misses(trial: Path) -> list[int]:
    """The cases of a trial's results whose concealed mechanism reaches :data:`VISIBLE_DB` and
    was not named first."""
    cases = json.loads(trial.read_text())["cases"]
    return [
        c["case"]
        for c in cases
        if c.get("concealed")
        and "refused" not in c
        and c["effect_db"] >= VISIBLE_DB
        and c["named"] != c["concealed"]
    ]


def ceiling_case(index: int, clean: float) -> dict[str, object]:
    """One case's test of the concealed mechanism fitted in the truth's basin."""
    began = time.perf_counter()
    truth, effects, test = simulate_case(index, clean)
    name = effects.mechanisms[0]
    mechanism = BY_NAME[name]
    report = run_identification([test], reference_parameters(), profile_points=0)
    refit = Refit(report.identification.parameters, report.fit, report.validation)
    baseline, baseline_value = refit.refit(Extra(refit.base, refit.start_row(), ()))
    true_row = kernel_parameters(truth.as_array(), effects)
    extra = Extra(refit.base, true_row, (mechanism,))
    objective = refit.objective(extra)
    start = np.clip(extra.unit_of(true_row), 0.0, 1.0)  # K and T_loss stay the identified ones
    polished, polished_value = refine(objective, start, REFIT_SETTINGS)
    searched = extra.unit_of(refit.search(extra, [polished])[0])
    values = objective(np.vstack([polished, searched]))
    best = extra.parameters([polished, searched][int(np.argmin(values))][None])[0]
    tested = refit.test((name,), best, baseline, len(mechanism.parameters), tried=1)
    family = 1.0 if tested.p_value >= 1.0 else sidak(tested.p_value, CANDIDATES)
    return {
        "case": index,
        "concealed": name,
        "effect": effects.as_dict(),
        "baseline_objective": baseline_value,
        "at_truth": {
            "parameters": {n: float(best[EXTRA_INDEX[n]]) for n in mechanism.names()},
            "objective": float(np.min(values)),
            "objective_polished": polished_value,
            "statistic": tested.statistic,
            "p_value": tested.p_value,
            "p_family": family,
            "held_out_gain": json_number(tested.validation_gain),
            "nrmse": tested.nrmse,
            "baseline_nrmse": refit.run_nrmse(baseline),
        },
        "acceptable": bool(family < ACCEPT_P and not tested.validation_gain <= 0),
        "seconds": time.perf_counter() - began,
    }


def main() -> None:
    """Run the cases and print each row."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cases", type=int, nargs="+", help="case numbers (default: the trial's visible misses)"
    )
    parser.add_argument("--trial", type=Path, default=RESULTS / "diagnosis_trial.json")
    parser.add_argument(
        "--clean", type=float, default=0.25, help="the trial's share of clean cases"
    )
    parser.add_argument("--out", type=Path, default=RESULTS / "diagnosis_ceiling.json")
    args = parser.parse_args()
    began = time.perf_counter()
    rows = []
    for index in args.cases or visible_misses(args.trial):
        rows.append(ceiling_case(index, args.clean))
        print(json.dumps(rows[-1]), flush=True)
    document = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "seconds": time.perf_counter() - began,
        "acceptable_at_truth": [r["case"] for r in rows if r["acceptable"]],
        "cases": rows,
    }
    args.out.parent.mkdir(exist_ok=True)
    write_json(args.out, document)


if __name__ == "__main__":
    main()
