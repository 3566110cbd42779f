"""Accuracy on recordings the product did not make (``../shared/independent``).

An independent implementation of the paper's test, with its own integrator, friction law,
engine data, idle controller, ECU timing and DBC, recorded two vehicles at 2, 5 and 10 N*m, one
chirp per file, with their truths. Identified as an engineer would (three files, the vehicle's
engine data from ``truth.toml``'s ``[engine]`` table, the default box and search):

* the model is right about these vehicles: started at the truth, the search's last stages end
  at an optimum within the issue's targets on every parameter, fitting the identification runs
  within an NRMSE of 0.045 each (with the product's own idle loop imposed, the truth fitted the
  10 N*m runs at 0.10-0.13); on vehicle_1, whose gearbox side is 5 % of the inertia, within
  twice the target on the gear coupling's stiffness (there the optimum nearest the truth lies
  at c23 +5.0 %, inside a profile interval of +-20 %: these recordings do not pin it);
* the search fits better than the truth, ends no higher than 1 % above the optimum nearest the
  truth, and finds the total inertia, the mass ratios, the DMF play and the DMF damping within
  their targets.

What is not asserted, because it does not hold on both: the stiffnesses, J3, the gear
coupling's damping and play, and the friction. The gear coupling trades along its mode's
frequency, and where a search ends in that valley depends on its path (2026-11-27, files in
sorted order: vehicle_1 c23 +12 %, d23 +9 %, eps23 -1 %; vehicle_2 c23 +2 %, the friction
+42 %; both below the optimum nearest the truth); see docs/accuracy.md. The test is
skipped, and says so, where the recordings are not beside the repository.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from dtid.identification.model.response import model_drv_db
from dtid.identification.pipeline import (
    IdentificationReport,
    identification_runs,
    run_identification,
)
from dtid.identification.search.identify import Objective, SearchSettings, refine
from dtid.identification.search.objective import nrmse
from dtid.identification.search.parameterization import THETA_NAMES, theta_from_parameters
from dtid.simulator.parameters import NAMES, DrivetrainParameters, reference_parameters
from dtid.simulator.vehicle_data import load_vehicle_data
from dtid.workflow import measured_tests

INDEPENDENT = Path(__file__).resolve().parents[2] / "shared" / "independent"
TARGETS = {
    "J_sum": 0.05,
    "x1": 0.05,
    "x12": 0.05,
    "c12": 0.05,
    "c23": 0.05,
    "eps12": 0.05,
    "eps23": 0.10,
    "d12": 0.25,
    "d23": 0.25,
    "Tc12": 0.20,
}
"""Issue 15's targets, relative: inertias, mass ratios, stiffnesses, DMF play 5 %, gear play
10 %, dampings 25 %, friction 20 %."""


def _vehicle(name: str, **vehicle: str) -> tuple[list, DrivetrainParameters, Path]:
    """The vehicle's three recordings with its engine data (``vehicle`` replaces other
    :class:`VehicleData` fields), its true drivetrain and its folder."""
    folder = INDEPENDENT / name
    if not folder.is_dir():
        pytest.skip(f"independent recordings not present in {folder}")
    files = sorted(folder.glob("run_A*.*"))
    tests = measured_tests(
        files,
        folder / "oem_vehicle.dbc",
        folder / "signals.toml",
        dataclasses.replace(load_vehicle_data(folder / "truth.toml"), **vehicle),
    )
    with (folder / "truth.toml").open("rb") as handle:
        table = tomllib.load(handle)["drivetrain"]
    return tests, DrivetrainParameters(**{n: table[n] for n in NAMES}), folder


class Nearest(NamedTuple):
    """The optimum nearest the truth: the search's last stages started at the truth."""

    errors: dict[str, float]
    """Relative error of each searched parameter against the truth."""
    value: float
    """Eq. (17) there."""
    parameters: np.ndarray
    """Its kernel parameter row, (1, n)."""
    model_tests: list
    """The model's repetitions of the identifying runs."""
    measured: list
    """Their measured |G_DRV| per run, dB."""


def _nearest_the_truth(report: IdentificationReport, truth: DrivetrainParameters) -> Nearest:
    """Refine from the truth on the report's identifying runs and parameterisation."""
    par, fit = report.parameterization, report.fit
    assert par is not None and fit is not None
    model_tests = [t.model_test(runs) for t, runs in zip(fit.tests, fit.runs, strict=True)]
    measured = [
        [t.estimates[i].drv_db for i in runs] for t, runs in zip(fit.tests, fit.runs, strict=True)
    ]
    true_theta = theta_from_parameters(truth)
    start = par.unit(np.array([[true_theta[n] for n in THETA_NAMES]]))[0]
    unit, value = refine(Objective(par, model_tests, measured), np.clip(start, 0.0, 1.0))
    theta = dict(zip(THETA_NAMES, par.theta(unit[None])[0], strict=True))
    errors = {n: theta[n] / true_theta[n] - 1 for n in THETA_NAMES}
    return Nearest(errors, value, par.parameters(unit[None]), model_tests, measured)


@pytest.mark.parametrize("name", ["vehicle_1", "vehicle_2"])
def test_independent_vehicle(name: str) -> None:
    tests, truth, _ = _vehicle(name)
    report = run_identification(tests, reference_parameters(), profile_points=0)
    result = report.identification
    true_theta = theta_from_parameters(truth)
    # the model: the optimum nearest the truth meets every target and fits each run
    nearest = _nearest_the_truth(report, truth)
    errors, value = nearest.errors, nearest.value
    targets = {**TARGETS, "c23": 2 * TARGETS["c23"]} if name == "vehicle_1" else TARGETS
    misses = {n: round(e, 3) for n, e in errors.items() if abs(e) > targets[n]}
    assert not misses, f"optimum nearest the truth (eq. 17 {value:.4f}): {misses}"
    for test, db_runs in zip(nearest.model_tests, nearest.measured, strict=True):
        for model, data in zip(model_drv_db(nearest.parameters, test), db_runs, strict=True):
            assert nrmse(data, model)[0] < 0.045
    # the search: it reaches the optimum nearest the truth or one that fits better (before
    # stage 2 ended each polish with Levenberg-Marquardt steps, vehicle_1's search stopped in
    # the gear coupling's valley at 0.054 for 0.050), and what it pins down on both vehicles
    assert result.objective < report.fit_objective(truth)
    assert result.objective <= 1.01 * value, (result.objective, value)
    for pinned in ("J_sum", "x1", "x12", "eps12", "d12"):
        found = result.theta[pinned] / true_theta[pinned] - 1
        assert abs(found) <= TARGETS[pinned], f"{pinned} {found:+.3f}"


@pytest.mark.parametrize("name", ["vehicle_1", "vehicle_2"])
def test_k_read_stroke_by_stroke_is_within_a_fraction_of_a_percent(name: str) -> None:
    """K of eq. (3) from the strokes of the identifying runs, each recording's slope weighted by
    its request's spread: +0.08 % and -0.06 % of the truth, where eq. (24)'s mean |G_ENG| (which
    the search holds) is off by -0.52 % and -0.87 %."""
    tests, _, folder = _vehicle(name)
    with (folder / "truth.toml").open("rb") as handle:
        true_k = tomllib.load(handle)["drivetrain"]["K"]
    selection = identification_runs(tests)
    slopes = [
        t.loop.engine_gain([(t.estimates[i].run.start_s, t.estimates[i].run.end_s) for i in runs])
        for t, runs in zip(selection.tests, selection.runs, strict=True)
    ]
    k = sum(s * w for s, w in slopes) / sum(w for _, w in slopes)
    assert k == pytest.approx(true_k, rel=0.003)
    eq24 = np.mean([e.engine_gain for e in selection.estimates()])
    assert abs(eq24 / true_k - 1) > 0.004


@pytest.mark.slow  # two searches and two polishes from the truth (40 s)
def test_a_tooth_timer_puts_vehicle_2s_nearest_optimum_on_its_truth() -> None:
    """With the speed sensor adding up tooth times (``[sensors] speed_average = "times"``)
    vehicle_2's truth fits far better than with eq. (9)'s average of speeds (eq. 17 0.069
    against 0.080), the optimum nearest it lies within 2.5 % of it on all ten parameters (eq. 9's
    up to 5.4-7.6 %) and fits at least as well as eq. (9)'s nearest optimum: these recordings'
    sensor is a tooth timer (docs/accuracy.md). Where the local polish from the truth ends moves
    with the machine's floating point (0.0638 against 0.0655 on one host, 0.0648 against 0.0650
    on another), so the two sensors are compared on the same machine, not against a figure.
    The search's own end is not asserted (at the default budget it ends in another basin)."""
    brief = SearchSettings(popsize=4, generations=1, polish_starts=1, scan_starts=1)
    at_truth, nearest = {}, {}
    for average in ("times", "speeds"):
        tests, truth, _ = _vehicle("vehicle_2", speed_average=average)
        report = run_identification(tests, reference_parameters(), settings=brief, profile_points=0)
        at_truth[average] = report.fit_objective(truth)
        nearest[average] = _nearest_the_truth(report, truth)
    assert at_truth["times"] < 0.9 * at_truth["speeds"], at_truth
    errors = {n: round(e, 4) for n, e in nearest["times"].errors.items()}
    assert max(abs(e) for e in errors.values()) < 0.025, errors
    assert nearest["times"].value <= 1.01 * nearest["speeds"].value
