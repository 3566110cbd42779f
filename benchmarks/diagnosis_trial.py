"""Diagnosis trial: blind cases of concealed physics, and how often ``dtid diagnose`` names it.

Each case draws a vehicle as the identification trial does (drivetrain within +-40 % of the
reference, its own idle controller, ECU timing, engine and noise:
:func:`benchmarks.identification_trial.draw_vehicle`), then, at random, no mechanism (a clean
case, with probability ``--clean``) or one mechanism of the library with its parameters drawn
from their typical ranges (:attr:`dtid.simulator.mechanisms.MechanismParameter.typical`; a
signed parameter gets a random sign). It simulates the paper's test (5, 10 and 2 N*m, 60 s
chirps) with the mechanism concealed (nothing in the recording but its physics), identifies
(default search, profiles off) and diagnoses with the whole library, as ``dtid identify`` and
``dtid diagnose`` do.

Per case it records the concealed mechanism, how much it changes |G_DRV| or |G_ENG|'s shape
(the largest change over the runs' bins, dB, at the truth: model with and without it on the
recorded test), what the diagnosis named first, the named mechanism's main parameter against
the truth, the held-out NRMSE before and after, and the identified drivetrain's errors
(``error_percent``; with a mechanism accepted, ``error_after_percent`` of the drivetrain
refitted with it). The summary
gives the issue's figures: among cases whose effect reaches 1.5 dB, the share named first
correctly (and how many of them the identification absorbed: declared adequate, the mechanism
listed as indistinguishable); clean cases declared adequate; the main parameter within 25 %;
the held-out NRMSE's fall where an effect was accepted (the identification's |G_DRV| NRMSE,
and each accepted step's own held-out measure, ``held_out_gain``: |G_DRV| NRMSE, |G_ENG| RMS z
for an engine-path mechanism, the strokes' departure for a cylinder imbalance); and the
confusion matrix.

    PYTHONPATH=. python benchmarks/diagnosis_trial.py --cases 12 [--first 1] [--clean 0.25]
    PYTHONPATH=. python benchmarks/diagnosis_trial.py --from-log run1.log run2.log  # summary

A recording the identification refuses (its FRF too incoherent, say) is recorded as refused.

Writes ``benchmarks/results/diagnosis_trial.json``. A benchmark, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.identification_trial import PLAN, draw_truth, draw_vehicle
from dtid.errors import AnalysisError
from dtid.identification.diagnosis.diagnose import diagnose_report
from dtid.identification.model.response import model_curves
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import run_identification
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.parameterization import theta_from_parameters
from dtid.jsonfile import json_number, write_json
from dtid.simulator.mechanisms import BY_NAME, MECHANISMS, Effects, kernel_parameters
from dtid.simulator.parameters import DrivetrainParameters, reference_parameters
from dtid.simulator.simulate import simulate
from dtid.simulator.vehicle_data import VehicleData

RESULTS = Path(__file__).resolve().parent / "results"
VISIBLE_DB = 1.5
"""Cases whose effect changes |G_DRV| or |G_ENG|'s shape by at least this somewhere count for the
naming rate."""


def draw_effect(index: int, clean: float) -> Effects:
    """No mechanism with probability ``clean``, else one of the library at a typical magnitude."""
    rng = np.random.default_rng(5000 + index)
    if rng.random() < clean:
        return Effects()
    mechanism = MECHANISMS[int(rng.integers(len(MECHANISMS)))]
    values = {}
    for spec in mechanism.parameters:
        value = float(rng.uniform(*spec.typical))
        if spec.lower < spec.neutral and rng.random() < 0.5:  # a signed parameter
            value = 2 * spec.neutral - value
        values[spec.name] = value
    return Effects(values)


def effect_db(truth: DrivetrainParameters, effects: Effects, test: MeasuredTest) -> float:
    """Largest change over every run's bins that the mechanism makes in |G_DRV| or in the shape
    of |G_ENG| (its change less the mean change: the map compares |G_ENG| in shape), dB."""
    if not effects.mechanisms:
        return 0.0
    rows = np.vstack(
        [kernel_parameters(truth.as_array()), kernel_parameters(truth.as_array(), effects)]
    )
    curves = model_curves(rows, test.model_test(range(len(test.estimates))))
    drv = max(float(np.nanmax(np.abs(c.drv_db[1] - c.drv_db[0]))) for c in curves)
    shape = [c.eng_db[1] - c.eng_db[0] for c in curves]
    if not all(np.isfinite(s).any() for s in shape):
        return drv
    level = float(np.nanmean(np.concatenate(shape)))
    return max(drv, *(float(np.nanmax(np.abs(s - level))) for s in shape))


def simulate_case(index: int, clean: float) -> tuple[DrivetrainParameters, Effects, MeasuredTest]:
    """One case's truth, concealed mechanism and simulated test (the engine data given)."""
    truth, vehicle = draw_truth(index), draw_vehicle(index)
    effects = draw_effect(index, clean)
    options = dataclasses.replace(vehicle, effects=effects)
    data = from_simulation(simulate(truth, PLAN, options, seed=700 + index))
    engine = VehicleData(vehicle.engine, vehicle.speed_average, ("all",), "the truth")
    return truth, effects, MeasuredTest.from_data(f"case {index}", data, 0.25, engine)


def run_case(index: int, clean: float) -> dict[str, object]:
    """Simulate, identify and diagnose one case; its figures."""
    truth, effects, test = simulate_case(index, clean)
    concealed = effects.mechanisms[0] if effects.mechanisms else None
    began = time.perf_counter()
    try:
        report = run_identification([test], reference_parameters(), profile_points=0)
    except AnalysisError as error:  # the product refuses the recording: a result too
        return {
            "case": index,
            "concealed": concealed,
            "effect": effects.as_dict(),
            "effect_db": effect_db(truth, effects, test),
            "refused": str(error),
        }
    identified_s = time.perf_counter() - began
    diagnosis = diagnose_report(report)
    named = diagnosis.mechanisms[0] if diagnosis.mechanisms else None
    row: dict[str, object] = {
        "case": index,
        "concealed": concealed,
        "effect": effects.as_dict(),
        "effect_db": effect_db(truth, effects, test),
        "adequate": diagnosis.adequate,
        "named": named,
        "accepted": list(diagnosis.mechanisms),
        "indistinguishable": list(diagnosis.indistinguishable),
        "absorbed": [entry.as_dict() for entry in diagnosis.absorbed],
        "bands": len(diagnosis.mismatch.bands),
        "global_p": diagnosis.mismatch.global_p_value,
        "cylinders_p": None if diagnosis.cylinders is None else diagnosis.cylinders.p_value,
        "identify_s": identified_s,
        "diagnose_s": diagnosis.seconds,
        "drivetrain_refit": None if diagnosis.refitted is None else diagnosis.refitted.as_dict(),
    }
    validation = sum(report.identification.validation_nrmse.values())
    row["validation_before"] = validation
    true_theta = theta_from_parameters(truth)
    row["error_percent"] = {  # the identified drivetrain: what an absorbed mechanism costs
        name: 100 * (value / true_theta[name] - 1)
        for name, value in report.identification.theta.items()
    }
    if diagnosis.accepted:
        last = diagnosis.accepted[-1]
        row["validation_after"] = sum(last.nrmse.get("validation", {}).values())
        row["held_out_gain"] = [  # each accepted step's own held-out measure (Candidate)
            {"mechanism": c.mechanisms[-1], "frf": c.frf, "gain": json_number(c.validation_gain)}
            for c in diagnosis.accepted
        ]
        after = theta_from_parameters(last.drivetrain())
        row["error_after_percent"] = {  # the drivetrain refitted with the accepted mechanisms
            name: 100 * (after[name] / true_theta[name] - 1) for name in report.identification.theta
        }
        if concealed and named == concealed:
            main = BY_NAME[concealed].main.name
            found, true = last.parameters()[main], effects.as_dict()[main]
            row["main_error"] = found / true - 1
    return row


def summarise(cases: list[dict[str, object]]) -> dict[str, object]:
    """The issue's figures over the cases."""
    refused = [c for c in cases if "refused" in c]
    cases = [c for c in cases if "refused" not in c]
    visible = [c for c in cases if c["concealed"] and c["effect_db"] >= VISIBLE_DB]
    clean = [c for c in cases if not c["concealed"]]
    accepted = [c for c in cases if c["named"]]
    main = [c for c in cases if "main_error" in c]
    labels = ["none", *(m.name for m in MECHANISMS)]
    confusion = {
        truth: {
            named: sum(
                1
                for c in cases
                if (c["concealed"] or "none") == truth and (c["named"] or "none") == named
            )
            for named in labels
        }
        for truth in labels
    }
    return {
        "cases": len(cases),
        "refused": [(c["case"], c["concealed"]) for c in refused],
        "visible": len(visible),
        "named_first_right": sum(c["named"] == c["concealed"] for c in visible),
        "visible_adequate": sum(bool(c["adequate"]) for c in visible),
        "visible_listed_indistinguishable": sum(
            c["concealed"] in c["indistinguishable"]  # type: ignore[operator]
            for c in visible
        ),
        "visible_drivetrain_refit_adequate": sum(  # nothing named; the refit alone explains
            not c["named"] and bool((c.get("drivetrain_refit") or {}).get("adequate"))  # type: ignore[union-attr]
            for c in visible
        ),
        "clean": len(clean),
        "clean_adequate": sum(bool(c["adequate"]) for c in clean),
        "clean_nothing_accepted": sum(not c["named"] for c in clean),
        "main_within_25": sum(abs(c["main_error"]) <= 0.25 for c in main),  # type: ignore[arg-type]
        "main_of": len(main),
        "held_out_fall": [
            1 - c["validation_after"] / c["validation_before"]  # type: ignore[operator]
            for c in accepted
            if c["validation_before"]  # none: the held-out run was refused
        ],
        "held_out_gain": [  # on the measure that tested each: |G_DRV|, |G_ENG| or strokes
            [(g["mechanism"], g["frf"], g["gain"]) for g in c.get("held_out_gain", [])]  # type: ignore[union-attr]
            for c in accepted
        ],
        "confusion": {t: {n: k for n, k in row.items() if k} for t, row in confusion.items()},
    }


def _is_case(line: str) -> bool:
    return line.startswith('{"case"')


def main() -> None:
    """Run the cases and print the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=12)
    parser.add_argument("--first", type=int, default=1, help="index of the first case")
    parser.add_argument("--clean", type=float, default=0.25, help="share of clean cases")
    parser.add_argument("--out", type=Path, default=RESULTS / "diagnosis_trial.json")
    parser.add_argument(
        "--from-log",
        type=Path,
        nargs="+",
        metavar="LOG",
        help="summarise the case rows earlier runs printed instead of running cases",
    )
    args = parser.parse_args()
    began = time.perf_counter()
    cases = []
    if args.from_log:
        rows = [line for log in args.from_log for line in log.read_text().splitlines()]
        found = {row["case"]: row for row in map(json.loads, filter(_is_case, rows))}
        cases = [found[k] for k in sorted(found)]
    for index in range(args.first, args.first + args.cases) if not args.from_log else ():
        cases.append(run_case(index, args.clean))
        print(json.dumps(cases[-1]), flush=True)
    summary = summarise(cases)
    print(json.dumps(summary, indent=1))
    document = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "seconds": time.perf_counter() - began,
        "summary": summary,
        "cases": cases,
    }
    args.out.parent.mkdir(exist_ok=True)
    write_json(args.out, document)


if __name__ == "__main__":
    main()
