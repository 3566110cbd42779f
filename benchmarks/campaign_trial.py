"""Does the adaptive campaign reach the targets? Rounds on one random truth, in simulated time.

What ``[test] adaptive = true`` does on the vehicle (:mod:`dtid.acquisition.campaign` and the
worker), without the bus: round 1 is the paper's test, recorded on the truth (one of the
identification trial's random drivetrains with its own idle loop, ECU timing, engine and noise,
which the model side does not share: it reads the loop from each recording and is told the
engine); after each round every round so far is identified together by the whole search
(with the worker's check of the targets, the likelihood-ratio test at their ends, or with
``--checks profiles`` whole profiles of ``--profile-points 5``; the previous round's optimum
polished too), the next round is planned at what was identified with every recorded run counted
in and the budget left, as the worker plans it (a target is met only where its profile interval
or target test confirms the prediction: :mod:`dtid.identification.planning.confirmation`), the
rounds are compared (:mod:`dtid.identification.planning.agreement`) and the fit tested
(:func:`dtid.identification.diagnosis.mismatch.adequacy`); until the plan says the targets are
met (``targets_met``, or ``inconsistent`` where the parameters jumped from the previous round,
``inadequate`` where the model does not explain the recordings) or the next round does not
fit. The errors of the last identification against the truth, next to the targets, say whether
the campaign kept its word.

    PYTHONPATH=. python benchmarks/campaign_trial.py --truth 2 \
        --json benchmarks/results/campaign_trial/truth2.json
"""

from __future__ import annotations

import argparse
import time

from benchmarks.identification_trial import draw_truth, draw_vehicle
from benchmarks.plan_trial import relative_errors
from dtid.acquisition.campaign import next_round
from dtid.acquisition.config import AcquisitionConfig, SafetyConfig
from dtid.acquisition.plan import TestPlan
from dtid.identification.diagnosis.mismatch import adequacy
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import run_identification
from dtid.identification.planning.agreement import agreement, scatter
from dtid.identification.planning.design import (
    DEFAULT_TARGETS_PERCENT,
    PRECISION_NAMES,
    SIGMAS,
    plan_test,
    predict,
    run_designs,
    shortest_test_s,
    target_half_widths,
)
from dtid.identification.planning.information import RESOLUTION_HZ
from dtid.identification.planning.spread import DEFAULT_VEHICLES, RECORDED
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.runs import amplitude_levels
from dtid.jsonfile import write_json
from dtid.simulator.controller import IdleController
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_data import VehicleData


def main() -> None:
    """Run the campaign on the truth and compare the last identification with the targets."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--truth", type=int, default=2, help="random truth n (0: reference)")
    parser.add_argument("--max-time", type=float, default=1800.0, help="the budget, s")
    parser.add_argument("--max-rounds", type=int, default=6, help="rounds at most")
    parser.add_argument(
        "--plan-vehicles",
        type=int,
        default=DEFAULT_VEHICLES,
        help="vehicles each round is planned for besides the identified one (dtid worker's "
        "--plan-vehicles; 0: the identified parameters alone, as before 2026-11-27)",
    )
    parser.add_argument(
        "--profile-points",
        type=int,
        default=5,
        help="profile grid points of each round's identification (dtid worker's default: 5; 0: "
        "no intervals, the prediction alone decides, as before 2026-11-29)",
    )
    parser.add_argument(
        "--checks",
        choices=("target-tests", "profiles"),
        default="target-tests",
        help="how each round's targets are checked: the likelihood-ratio test at their ends "
        "(the worker in a campaign, since 2026-11-29) or whole profiles (before)",
    )
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    tested = args.profile_points > 0 and args.checks == "target-tests"

    truth, vehicle = draw_truth(args.truth), draw_vehicle(args.truth)
    known = VehicleData(vehicle.engine, vehicle.speed_average, ("all",), "the truth")
    tests: list[MeasuredTest] = []
    plan, spent, rounds, stopped = TestPlan(), 0.0, [], "max_rounds"
    identify_nm = sorted(set(plan.amplitudes_nm))
    before: tuple[dict[str, float], dict[str, float]] | None = None
    for number in range(1, args.max_rounds + 1):
        result = simulate(truth, plan, vehicle, seed=7000 + number)
        data = from_simulation(result)
        tests.append(MeasuredTest.from_data(f"round {number}", data, RESOLUTION_HZ, known))
        spent += plan.end_s
        began = time.perf_counter()
        report = run_identification(
            tests,
            reference_parameters(),
            identify_amplitudes=identify_nm,
            profile_points=0 if tested else args.profile_points,
            warm_starts=[before[0]] if before else (),
            target_widths=(
                (lambda theta: target_half_widths(theta, DEFAULT_TARGETS_PERCENT))
                if tested
                else None
            ),
        )
        seconds = time.perf_counter() - began
        checks_s = seconds - report.identification.seconds
        fit = report.fit
        assert fit is not None and report.validation is not None
        held_out = amplitude_levels(
            t.estimates[i].run.amplitude_nm
            for t, runs in zip(report.validation.tests, report.validation.runs, strict=True)
            for i in runs
        )
        setpoint = sum(t.setpoint_rpm for t in fit.tests) / len(fit.tests)
        info, recommendation = plan_test(
            report.identification.parameters,
            DEFAULT_TARGETS_PERCENT,
            SafetyConfig(),
            max_time_s=max(args.max_time - spent, shortest_test_s()),
            validation_nm=0.0,
            options=SimulationOptions(controller=IdleController(setpoint_rpm=setpoint)),
            recorded=run_designs(fit.tests, fit.runs),
            held_out_nm=held_out,
            spread=RECORDED,
            vehicles=args.plan_vehicles,
            identification=report.as_dict() if args.profile_points else None,
        )
        errors = relative_errors(report.identification.theta, truth)
        design = recommendation.design
        reached = predict(info, None, recommendation.recorded)
        fit_check = adequacy(report)
        sd = scatter(reached, info.prior)
        agreed = agreement(*before, report.parameters, sd) if before else None
        before = (report.parameters, sd)
        rounds.append(
            {
                "round": number,
                "test_time_s": plan.end_s,
                "amplitudes_nm": sorted(set(plan.amplitudes_nm)),
                "chirps": len(plan.chirps),
                "duration_s": plan.duration_s,
                "identification_s": round(seconds, 1),
                "checks_s": round(checks_s, 1),
                "errors": errors,
                "next": design.as_dict(setpoint) if design else None,
                "unmet_next": [u.name for u in recommendation.unmet],
                "unconfirmed": {c.name: c.as_dict() for c in recommendation.unconfirmed},
                "precision": {n: round(v, 5) for n, v in reached.items()},
                "agreement": agreed.as_dict() if agreed else None,
                "fit": fit_check,
                "objective": report.identification.objective,
                "validation_nrmse": list(report.identification.validation_nrmse.values()),
            }
        )
        missed = [n for n in PRECISION_NAMES if 100 * abs(errors[n]) > DEFAULT_TARGETS_PERCENT[n]]
        print(
            f"round {number}: {plan.end_s:.0f} s of test ({spent:.0f} s in all), identified in "
            f"{seconds:.0f} s ({checks_s:.0f} s of it checking the targets); outside the targets: "
            + (", ".join(f"{n} {100 * errors[n]:+.1f} %" for n in missed) or "none")
            + f"; next: {design if design else 'none (the plan says the targets are met)'}"
            + (f"; from the previous round: {agreed.summary()}" if agreed else "")
            + (f"; fit adequate: {fit_check['adequate']}" if fit_check else "")
            + "".join(f"; {c.name}: {c.reason()}" for c in recommendation.unconfirmed),
            flush=True,
        )
        if design is None and not recommendation.meets_targets:
            stopped = "no_plan"
            break
        if design is None:
            said_met = {
                "plan": None,
                "meets_targets": True,
                "agreement": agreed.as_dict() if agreed else None,
                "fit": fit_check,
            }
            stopped = str(next_round(said_met, args.max_time - spent, AcquisitionConfig()).stopped)
            break
        if design.test_time_s > args.max_time - spent:
            stopped = "time_budget"
            break
        plan = design.test_plan()
        identify_nm = sorted({*identify_nm, *design.amplitudes_nm})
    print(f"stopped: {stopped} after {spent:.0f} s of test")
    print(f"{'':>6} {'target':>7} {'error':>7}   (%; the last identification)")
    for name in PRECISION_NAMES:
        print(f"{name:>6} {DEFAULT_TARGETS_PERCENT[name]:7g} {100 * errors[name]:+7.1f}")
    if args.json:
        write_json(
            args.json,
            {
                "truth": args.truth,
                "max_time_s": args.max_time,
                "sigmas": SIGMAS,
                "targets_percent": DEFAULT_TARGETS_PERCENT,
                "stopped": stopped,
                "spent_s": spent,
                "rounds": rounds,
            },
        )


if __name__ == "__main__":
    main()
