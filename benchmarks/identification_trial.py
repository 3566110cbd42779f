"""Identification trial: accuracy and wall time on a simulated vehicle the model does not know.

For truth N > 0 it draws a vehicle at random: the drivetrain within +-40 % of the reference, and,
so that the model side shares nothing with the data generator but the paper's physics, the
vehicle's own idle controller (PI or PID, gains over a decade, an output delay, a stroke latch,
a filtered error), its idle speed, engine gain, loss torque, crank-train data and noise levels
(:func:`draw_vehicle`). Truth 0 is the reference vehicle with the product's own ECU. It simulates
the test (5, 10 and 2 N*m, 60 s chirps), identifies from 5 and 10 N*m in the default box with the
reference vehicle as prior and the vehicle's engine data given (``--vehicle`` does that for a
user; ``--engine-unknown`` keeps the reference engine), validates on 2 N*m, and prints each
parameter's error, the NRMSEs, the wall time and the parameter sets simulated. It also runs the
search's last two stages from the truth and compares the two optima on the same fresh draws of
the model (neither optimised on them): where the nearest optimum fits better by more than the
difference's standard error allows, the search missed it; within it, the data do not choose
between the two (and the optimum started at the truth keeps near it along directions the data
cannot see); where it fits worse, the data prefer what was found. Not a test: nothing is
asserted.

    PYTHONPATH=. python benchmarks/identification_trial.py  # the reference vehicle as truth
    PYTHONPATH=. python benchmarks/identification_trial.py --truth 1  # a random vehicle
    PYTHONPATH=. python benchmarks/identification_trial.py --truth 1 --profile-points 7
    PYTHONPATH=. python benchmarks/identification_trial.py --truth 1 --sweep 0.5 20  # as the
        # independent recordings sweep, past the strokes' Nyquist frequency
    PYTHONPATH=. python benchmarks/identification_trial.py --truth 1 --sweep 0.5 20 \
        --around ../shared/independent/vehicle_1/truth.toml  # drivetrains drawn around another
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import tomllib

import numpy as np

from dtid.acquisition.plan import TestPlan
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import IdentificationReport, run_identification
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.identify import SearchSettings, refine
from dtid.identification.search.levenberg_marquardt import CHOICE_SEEDS, on_fresh_draws
from dtid.identification.search.objective import Objective
from dtid.identification.search.parameterization import THETA_NAMES, theta_from_parameters
from dtid.simulator.controller import IdleController
from dtid.simulator.engine import EngineGeometry
from dtid.simulator.parameters import (
    NAMES,
    DrivetrainParameters,
    parse_parameters,
    reference_parameters,
)
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_data import VehicleData

TRUTH_SPREAD = 0.4
"""Random truths lie within +-40 % of the reference."""
PLAN = TestPlan(amplitudes_nm=(5.0, 10.0, 2.0), validation_nm=0.0)
"""The test: the paper's amplitudes, 60 s chirps, the validation chirp last."""


def draw_truth(index: int, around: DrivetrainParameters | None = None) -> DrivetrainParameters:
    """The reference (or ``around``) for index 0, else a drivetrain within +-40 % of it, its
    loss torque 10-18 N*m and engine gain 0.85-1.05."""
    reference = reference_parameters() if around is None else around
    if index == 0:
        return reference
    rng = np.random.default_rng(index)
    factors = rng.uniform(1 - TRUTH_SPREAD, 1 + TRUTH_SPREAD, 10)
    values = reference.as_array() * np.r_[factors, 1.0, 1.0]
    values[10], values[11] = rng.uniform(10.0, 18.0), rng.uniform(0.85, 1.05)
    return DrivetrainParameters.from_array(values)


def _drivetrain_of(path: str) -> DrivetrainParameters:
    """The drivetrain parameters of a TOML file: its ``[drivetrain]`` table's (or its top
    level's) keys among :data:`NAMES`, the rest ignored (an independent recording's truth file
    has an idle set-point and noise levels beside them)."""
    with open(path, "rb") as handle:
        document = tomllib.load(handle)
    table = document.get("drivetrain", document)
    return parse_parameters({n: table[n] for n in NAMES if n in table}, source=path)


def draw_vehicle(index: int) -> SimulationOptions:
    """The product's own ECU, engine and noise for index 0; else drawn at random: idle speed
    750-1000 rpm; a PI with kp 0.05-0.5 N*m/rpm (log-uniform) and its integral corner at
    0.05-0.5 Hz, a derivative term on a third of the vehicles, an output delay of 0-3 crank
    events, a stroke latching the request 0-2 events before it starts, the error low-passed
    on half of them; the crank train within typical petrol-engine ranges; a combustion
    variation of 1-4 %, torque-sensor noise of 0.1-0.5 N*m and speed noise of 0.1-0.4 rpm;
    a speed sensor that averages step speeds or, on half of them, tooth times."""
    if index == 0:
        return SimulationOptions()
    rng = np.random.default_rng(1000 + index)
    kp = float(np.exp(rng.uniform(np.log(0.05), np.log(0.5))))
    controller = IdleController(
        setpoint_rpm=float(rng.uniform(750.0, 1000.0)),
        kp_nm_per_rpm=kp,
        ki_nm_per_rpm_s=kp * 2 * np.pi * float(rng.uniform(0.05, 0.5)),
        kd_nm_per_rpm_s=float(rng.uniform(0.0, 0.015)) if rng.random() < 1 / 3 else 0.0,
        delay_samples=int(rng.integers(0, 4)),
        latch_samples=int(rng.integers(0, 3)),
        error_tau_s=float(rng.uniform(0.01, 0.05)) if rng.random() < 0.5 else 0.0,
    )
    engine = EngineGeometry(
        bore_m=float(rng.uniform(0.075, 0.09)),
        crank_radius_m=float(rng.uniform(0.04, 0.048)),
        rod_length_m=float(rng.uniform(0.13, 0.16)),
        compression_ratio=float(rng.uniform(9.0, 12.0)),
        manifold_pressure_pa=float(rng.uniform(0.3e5, 0.45e5)),
        isentropic_exponent=float(rng.uniform(1.28, 1.38)),
        oscillating_mass_kg=float(rng.uniform(0.4, 0.6)),
    )
    return SimulationOptions(
        speed_average="times" if rng.random() < 0.5 else "speeds",
        combustion_variation=float(rng.uniform(0.01, 0.04)),
        speed_noise_rpm=float(rng.uniform(0.1, 0.4)),
        torque_noise_nm=float(rng.uniform(0.1, 0.5)),
        engine=engine,
        controller=controller,
    )


def trial_recording(
    index: int,
    sweep: tuple[float, float] = (PLAN.f1_hz, PLAN.f2_hz),
    around: DrivetrainParameters | None = None,
    vehicle: SimulationOptions | None = None,
    noise_seed: int | None = None,
    engine_known: bool = True,
) -> tuple[DrivetrainParameters, SimulationOptions, MeasuredTest]:
    """Truth ``index`` (drawn around ``around``, :func:`draw_truth`), its vehicle (``vehicle``,
    else :func:`draw_vehicle`) and the test (:data:`PLAN` swept over ``sweep``, Hz) simulated
    with noise seed ``noise_seed`` (100 + index unless given), as a measured test whose engine
    and speed sensor the model knows (``engine_known``; else the reference's)."""
    truth = draw_truth(index, around)
    vehicle = vehicle or draw_vehicle(index)
    plan = dataclasses.replace(PLAN, f1_hz=sweep[0], f2_hz=sweep[1])
    seed = 100 + index if noise_seed is None else noise_seed
    measured = MeasuredTest.from_data(
        "simulated",
        from_simulation(simulate(truth, plan, vehicle, seed=seed)),
        0.25,
        VehicleData(vehicle.engine, vehicle.speed_average, ("all",), "the truth")
        if engine_known
        else VehicleData(),
    )
    return truth, vehicle, measured


def fit_objective(report: IdentificationReport) -> Objective:
    """Eq. (17) over the report's identifying runs, in its parameterization's coordinates."""
    par = report.parameterization
    assert par is not None
    return Objective(
        par,
        [t.model_test(runs) for t, runs in zip(report.fit.tests, report.fit.runs, strict=True)],
        [
            [t.estimates[i].drv_db for i in runs]
            for t, runs in zip(report.fit.tests, report.fit.runs, strict=True)
        ],
    )


def nearest_optimum(
    truth: DrivetrainParameters, report: IdentificationReport, settings: SearchSettings
) -> tuple[dict[str, float], float]:
    """The optimum the search's last two stages reach from the truth (setup-4 values by name)
    and eq. (17) there, on the draws that optimisation ran on (so lower than on others: compare
    with :func:`on_the_same_draws`)."""
    objective = fit_objective(report)
    true_theta = theta_from_parameters(truth)
    start = np.clip(objective.parameterization.unit(_row(true_theta))[0], 0.0, 1.0)
    unit, value = refine(objective, start, settings)
    theta = objective.parameterization.theta(unit[None])[0]
    return dict(zip(THETA_NAMES, map(float, theta), strict=True)), value


def on_the_same_draws(
    report: IdentificationReport, settings: SearchSettings, *thetas: dict[str, float]
) -> np.ndarray:
    """Eq. (17) of each setup-4 set on the model's draws that choose between the search's ends
    (:data:`~dtid.identification.search.levenberg_marquardt.CHOICE_SEEDS`, each with the final
    stages' realizations): (seeds, sets). Each optimum is the least of many evaluations on its
    own draws, so only values on draws neither was optimised on compare them; a paired
    difference within its standard error says the data do not choose between the two."""
    objective = fit_objective(report).replacing(realizations=settings.final_realizations)
    units = np.clip(objective.parameterization.unit(np.vstack([_row(t) for t in thetas])), 0, 1)
    return on_fresh_draws(objective, units, CHOICE_SEEDS)


def _row(theta: dict[str, float]) -> np.ndarray:
    """Setup-4 values by name as one row (1, 10)."""
    return np.array([[theta[n] for n in THETA_NAMES]])


def main() -> None:
    """Run one trial and print its figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--truth", type=int, default=0, help="0: reference; n: random truth n")
    parser.add_argument("--generations", type=int, default=SearchSettings().generations)
    parser.add_argument(
        "--polish",
        type=int,
        default=SearchSettings().polish_evaluations,
        help="Nelder-Mead evaluations per polish",
    )
    parser.add_argument(
        "--newton",
        type=int,
        default=SearchSettings().newton_iterations,
        help="most Levenberg-Marquardt steps",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the search")
    parser.add_argument(
        "--combustion-variation",
        type=float,
        help="fix the model's combustion variation (default: as measured at idle)",
    )
    parser.add_argument(
        "--global-realizations",
        type=int,
        default=SearchSettings().global_realizations,
        help="model realizations per parameter set in the global search",
    )
    parser.add_argument(
        "--engine-unknown",
        action="store_true",
        help="the model keeps the reference engine and speed sensor instead of the vehicle's",
    )
    parser.add_argument(
        "--noise-seed", type=int, help="seed of the recording's noise (default: 100 + truth)"
    )
    parser.add_argument(
        "--profile-points", type=int, default=0, help="profile grid points; 0: no intervals"
    )
    parser.add_argument("--json", help="write the profiles (values, statistic, margin) here")
    parser.add_argument(
        "--sweep",
        nargs=2,
        type=float,
        metavar=("F1", "F2"),
        default=(PLAN.f1_hz, PLAN.f2_hz),
        help="the chirps' sweep, Hz (default %(default)s; the independent recordings' 0.5 20)",
    )
    parser.add_argument(
        "--setpoint", type=float, help="the vehicle's idle speed, rpm (default: drawn)"
    )
    parser.add_argument(
        "--around",
        help="draw the drivetrains around this parameter file's (a vehicle file's "
        "[drivetrain]) instead of the reference's; the search's prior stays the reference",
    )
    args = parser.parse_args()

    around = None if args.around is None else _drivetrain_of(args.around)
    vehicle = draw_vehicle(args.truth)
    if args.setpoint is not None:  # the other draws stay
        controller = dataclasses.replace(vehicle.controller, setpoint_rpm=args.setpoint)
        vehicle = dataclasses.replace(vehicle, controller=controller)
    truth, vehicle, measured = trial_recording(
        args.truth, args.sweep, around, vehicle, args.noise_seed, not args.engine_unknown
    )
    settings = SearchSettings(
        generations=args.generations,
        polish_evaluations=args.polish,
        newton_iterations=args.newton,
        global_realizations=args.global_realizations,
        seed=args.seed,
    )
    began = time.perf_counter()
    fixed = (
        {}
        if args.combustion_variation is None
        else {"combustion_variation": args.combustion_variation}
    )
    report = run_identification(
        [measured],
        reference_parameters(),
        fixed=fixed,
        settings=settings,
        profile_points=args.profile_points,
    )
    result = report.identification
    true_theta = theta_from_parameters(truth)
    print(
        f"truth {args.truth}: search {result.seconds:.1f} s wall, {result.parameter_sets} "
        f"parameter sets ({result.objective_seconds:.1f} s in the objective); with profiles "
        f"{time.perf_counter() - began:.1f} s"
    )
    print(
        "stages: "
        + ", ".join(f"{k} {n} sets in {sec:.1f} s" for k, (n, sec) in result.stages.items())
    )
    print(f"vehicle: {vehicle.controller}, {vehicle.engine}")
    print(
        f"combustion variation: {vehicle.combustion_variation:.4f} true, "
        f"{report.fit.tests[0].combustion_variation:.4f} in the fit; torque noise "
        f"{vehicle.torque_noise_nm:.3f} N*m true, {measured.loop.torque_noise_nm:.3f} estimated"
    )
    print(f"fit NRMSE {result.fit_nrmse}, validation NRMSE {result.validation_nrmse}")
    if report.restart is not None:
        print(report.restart.message(report.restart.as_dict()["adopted"] is True))
    nearest, nearest_value = nearest_optimum(truth, report, settings)
    print(
        f"eq. (17): {result.objective:.4f} at the optimum found, "
        f"{report.fit_objective(truth):.4f} at the truth, "
        f"{nearest_value:.4f} at the optimum nearest the truth"
    )
    same = on_the_same_draws(report, settings, result.theta, nearest, true_theta)
    difference = same[:, 0] - same[:, 1]
    standard_error = float(np.std(difference, ddof=1) / np.sqrt(len(difference)))
    ratio = difference.mean() / standard_error
    print(
        f"on the same fresh draws: {same[:, 0].mean():.4f} found, {same[:, 2].mean():.4f} at "
        f"the truth, {same[:, 1].mean():.4f} nearest; found - nearest "
        f"{difference.mean():+.4f} +- {standard_error:.4f} (t {ratio:+.1f})"
    )
    for name in THETA_NAMES:
        error = 100 * (result.theta[name] / true_theta[name] - 1)
        near = 100 * (nearest[name] / true_theta[name] - 1)
        line = (
            f"{name:>6} {result.theta[name]:10.4g} truth {true_theta[name]:10.4g} {error:+6.1f} %"
            f" (nearest {near:+6.1f} %)"
        )
        if name in report.profiles:
            profile = report.profiles[name]
            lower, upper = profile.interval
            inside = (lower is None or lower <= true_theta[name]) and (
                upper is None or true_theta[name] <= upper
            )
            line += (
                f"  [{'-' if lower is None else f'{lower:.4g}'}, "
                f"{'-' if upper is None else f'{upper:.4g}'}] {profile.verdict:<10} "
                f"{'holds the truth' if inside else 'MISSES the truth'}"
            )
        print(line)
    if args.json:
        document = {
            "truth": args.truth,
            "seconds": result.seconds,
            "objective": {
                "found": result.objective,
                "truth": report.fit_objective(truth),
                "nearest": nearest_value,
                "same_draws": {
                    "found": float(same[:, 0].mean()),
                    "truth": float(same[:, 2].mean()),
                    "nearest": float(same[:, 1].mean()),
                    "difference_standard_error": standard_error,
                },
            },
            "error_percent": {n: 100 * (result.theta[n] / true_theta[n] - 1) for n in THETA_NAMES},
            "nearest_error_percent": {
                n: 100 * (nearest[n] / true_theta[n] - 1) for n in THETA_NAMES
            },
            "validation_nrmse": list(result.validation_nrmse.values()),
            "search_restart": report.restart.as_dict() if report.restart else None,
            "profiles": {name: prof.as_dict() for name, prof in report.profiles.items()},
        }
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump(document, out)


if __name__ == "__main__":
    main()
