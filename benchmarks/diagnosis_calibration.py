"""Diagnosis calibration: how often the mismatch map cries wolf, and how small a miss it sees.

Simulated recordings (the paper's test, 5, 10 and 2 N*m with 60 s chirps) of random vehicles
as in the identification trial (drivetrain within +-40 % of the reference, their own idle
controller, ECU timing, engine and noise; :func:`benchmarks.identification_trial.draw_vehicle`),
each with its own noise seed. For each recording the mismatch map of ``dtid diagnose`` is made

* at the truth (K and T_loss as measured from the recording, as an identification gets them):
  a right model, so any band is a false alarm; the family-wise error asked for is 1 %;
* at the truth with one coupling value off by a factor (``--errors``, default c12 and c23 at
  +5, +10 and +20 %): how often the map declares the model inadequate;
* the strokes' test of equal cylinders (:mod:`dtid.identification.diagnosis.imbalance`): these
  engines have equal cylinders, so a significant spread is a false alarm too.

No identification is run (that is ``--identified N``: the first N recordings are also identified
with the default search and diagnosed as ``dtid diagnose`` would, two or three minutes each;
their ``adequate`` is the whole diagnosis's verdict, the map's own is ``map_adequate``).

    PYTHONPATH=. python benchmarks/diagnosis_calibration.py [--recordings 20] [--identified 0]
        [--first 1] [--errors NAME=FACTOR ...] [--out FILE]

Prints the counts and writes ``benchmarks/results/diagnosis_calibration.json`` (or ``--out``).
A benchmark, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import time
from pathlib import Path

from benchmarks.identification_trial import PLAN, draw_truth, draw_vehicle
from dtid.identification.diagnosis.diagnose import diagnose_report
from dtid.identification.diagnosis.imbalance import stroke_test
from dtid.identification.diagnosis.mismatch import MismatchMap, mismatch_map
from dtid.identification.diagnosis.refit import ACCEPT_P
from dtid.identification.gain_choice import held_gain
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import identification_runs, run_identification, validation_runs
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.runs import engine_gain
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.simulate import simulate
from dtid.simulator.vehicle_data import VehicleData

RESULTS = Path(__file__).resolve().parent / "results"
ERRORS = ("c12=1.05", "c12=1.1", "c12=1.2", "c23=1.05", "c23=1.1", "c23=1.2")


def recording(index: int, noise_seed: int | None = None) -> tuple[object, MeasuredTest]:
    """Truth and measured test of random vehicle ``index`` (noise seed 500 + index unless
    given: the identification trial's recording of that vehicle has 100 + index)."""
    truth, vehicle = draw_truth(index), draw_vehicle(index)
    seed = 500 + index if noise_seed is None else noise_seed
    data = from_simulation(simulate(truth, PLAN, vehicle, seed=seed))
    engine = VehicleData(vehicle.engine, vehicle.speed_average, ("all",), "the truth")
    return truth, MeasuredTest.from_data(f"vehicle {index}", data, 0.25, engine)


def verdict(found: MismatchMap) -> dict[str, object]:
    """A map's verdict, global p-value and bands (``frf @ A N*m: f_lo-f_hi Hz, excess, p,
    kind``)."""
    return {
        "adequate": found.adequate,
        "p": found.global_p_value,
        "bands": [
            f"{b.frf} @ {b.amplitude_nm:g} N*m: {b.f_lo_hz:.1f}-{b.f_hi_hz:.1f} Hz, "
            f"{b.excess_db:+.2f} dB, p = {b.p_value:.1g}, {b.kind}"
            for b in found.bands
        ],
    }


def main() -> None:
    """Run the calibration and print its counts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=int, default=20)
    parser.add_argument("--first", type=int, default=1, help="index of the first vehicle")
    parser.add_argument(
        "--errors", nargs="*", default=list(ERRORS), metavar="NAME=FACTOR", help="none: no wrong"
    )
    parser.add_argument("--identified", type=int, default=0, help="recordings also identified")
    parser.add_argument(
        "--out", type=Path, default=RESULTS / "diagnosis_calibration.json", help="the JSON written"
    )
    args = parser.parse_args()
    began = time.perf_counter()
    cases: list[dict[str, object]] = []
    for index in range(args.first, args.first + args.recordings):
        truth, test = recording(index)
        fit, valid = identification_runs([test]), validation_runs([test])
        selections = [("fit", fit), ("validation", valid)]
        kept = fit.tests[0]
        identifying = dataclasses.replace(
            kept, estimates=tuple(kept.estimates[i] for i in fit.runs[0])
        )
        gain = held_gain(fit.tests, fit.runs, engine_gain([identifying]))[0]
        base = truth.replace(K=gain, T_loss=kept.idle_torque_nm)
        row: dict[str, object] = {"vehicle": index}
        row["truth"] = verdict(mismatch_map(base, selections))
        strokes = stroke_test(fit, valid)
        if strokes is not None:
            row["cylinders"] = {"p": strokes.p_value, "share": strokes.share}
        for item in args.errors:
            name, factor = item.split("=")
            wrong = base.replace(**{name: getattr(base, name) * float(factor)})
            row[item] = verdict(mismatch_map(wrong, selections))
        if index < args.first + args.identified:
            report = run_identification([test], reference_parameters(), profile_points=0)
            diagnosis = diagnose_report(report)
            row["identified"] = {  # the whole diagnosis's verdict: map, strokes, the checks
                **verdict(diagnosis.mismatch),
                "map_adequate": diagnosis.mismatch.adequate,
                "adequate": diagnosis.adequate,
                "accepted": list(diagnosis.mechanisms),
                "diagnose_s": diagnosis.seconds,
                "objective": report.identification.objective,
                "objective_at_truth": report.fit_objective(truth),
            }
        cases.append(row)
        print(json.dumps(row))
    summary: dict[str, object] = {}
    for key in ["truth", *args.errors, "identified"]:
        rows = [case[key] for case in cases if key in case]
        if rows:
            flagged = sum(not r["adequate"] for r in rows)  # type: ignore[index]
            engine = sum(any(b.startswith("eng") for b in r["bands"]) for r in rows)  # type: ignore[index]
            trend = sum(any(b.endswith("trend") for b in r["bands"]) for r in rows)  # type: ignore[index]
            summary[key] = {
                "inadequate": flagged,
                "of": len(rows),
                "with_eng_bands": engine,
                "with_trend_bands": trend,
            }
            print(
                f"{key:>10}: declared inadequate {flagged} of {len(rows)} ({engine} in |G_ENG|, "
                f"{trend} with a trend)"
            )
    spread = [case["cylinders"]["p"] for case in cases if "cylinders" in case]  # type: ignore[index]
    if spread:
        summary["cylinders"] = {"significant": sum(p < ACCEPT_P for p in spread), "of": len(spread)}
        print(
            f" cylinders: a spread found on {summary['cylinders']['significant']} of {len(spread)}"
        )
    document = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "seconds": time.perf_counter() - began,
        "summary": summary,
        "cases": cases,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(document, indent=1) + "\n")


if __name__ == "__main__":
    main()
