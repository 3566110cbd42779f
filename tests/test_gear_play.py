"""The gear play's check (identification/uncertainty/gear_play.py): a search that closed the gear
play is tested against an open one, one that left it open against a wider and a narrower one,
and restarted where one fits better."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from dtid.identification.search.identify import SearchSettings
from dtid.identification.search.parameterization import (
    THETA_NAMES,
    Parameterization,
    passenger_car_bounds,
    theta_from_parameters,
)
from dtid.identification.uncertainty import gear_play
from dtid.simulator.parameters import DrivetrainParameters, reference_parameters

VEHICLE_1 = DrivetrainParameters(
    J1=0.16,
    J2=0.07,
    J3=0.012,
    c12=250.0,
    c23=40.0,
    d12=1.0,
    d23=0.05,
    Tc12=1.5,
    eps12=0.052,
    eps23=0.035,
    T_loss=15.0,
    K=1.0,
)
"""The drivetrain of ../shared/independent/vehicle_1 (its truth.toml), written out so that the
test runs without those files: the centre of ``benchmarks/identification_trial.py --around``."""
CLOSED = {
    "J_sum": 0.2663,
    "x1": 0.6353,
    "x12": 0.9549,
    "c12": 339.2,
    "c23": 50.24,
    "d12": 0.9735,
    "d23": 0.2256,
    "Tc12": 1.072,
    "eps12": 0.05521,
    "eps23": 0.0,
}
"""Where the default search ended on truth 1 drawn around vehicle_1 (2026-12-07, before the
check): the gear play closed, eq. (17) 0.0889."""


def _unit(par: Parameterization, theta: dict[str, float]) -> np.ndarray:
    return par.unit(np.array([[theta[n] for n in THETA_NAMES]]))[0]


@pytest.fixture
def grids(monkeypatch: pytest.MonkeyPatch) -> list[np.ndarray]:
    """The (parameter, values in SI units) :func:`gear_play.gear_play_check` hands the profile,
    which is not run."""
    seen: list[tuple[str, np.ndarray]] = []

    def profile_at(objective, measured_db, name, optimum_unit, grid, **kwargs):
        assert kwargs["refine"] == 0
        lower, upper = objective.parameterization.bounds_of(name)
        seen.append((name, lower + grid * (upper - lower)))
        return "profile"

    monkeypatch.setattr(gear_play, "profile_at", profile_at)
    return seen


def test_the_check_holds_the_stiffness_of_a_closed_play_and_an_open_play_itself(
    grids: list[tuple[str, np.ndarray]],
) -> None:
    """Where the gear play ended at 0 the check holds c23 at half and 1.5 times its value, where
    it ended open the play at 2/3 and 1.5 times; a held play or c23 leaves it out, and a play at
    the lower end of a box that cannot close counts as open. (Beside the data test below, which
    can fail on what the check finds.)"""
    prior = reference_parameters()
    par = Parameterization.around(prior, 15.0, 1.0, bounds=passenger_car_bounds(prior))

    def check(par: Parameterization, theta: dict[str, float]) -> object:
        objective = SimpleNamespace(parameterization=par)
        return gear_play.gear_play_check(objective, [], _unit(par, theta))

    assert check(par, CLOSED) == "profile"
    assert grids[-1][0] == "c23" and grids[-1][1] == pytest.approx([25.12, 75.36])
    assert check(par, {**CLOSED, "eps23": 0.012}) == "profile"
    assert grids[-1][0] == "eps23" and grids[-1][1] == pytest.approx([0.008, 0.018])
    for held in ("eps23", "c23"):
        assert check(Parameterization.around(prior, 15.0, 1.0, fixed={held: 0.0}), CLOSED) is None
    narrow = Parameterization.around(prior, 15.0, 1.0, bounds={"eps23": (0.005, 0.05)})
    assert check(narrow, {**CLOSED, "eps23": 0.005}) == "profile"
    assert grids[-1][0] == "eps23" and grids[-1][1] == pytest.approx([0.005, 0.0075])
    assert len(grids) == 3


def test_a_search_that_closed_the_gear_play_is_restarted_in_the_open_plays_basin(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Truth 1 drawn around vehicle_1 (its own idle loop, engine and noise; 60 s chirps to 20
    Hz): the default search closed the gear play there (c23 +48 %, d23 +258 %, eq. 17 0.0889)
    where the optimum nearest the truth, play open, fits at 0.0731. The search held at that
    point, the check finds the open play at half the stiffness and the search's last stages go
    on from there (0.0737 on 2026-12-07: c23 -25 %, d23 -39 %, eps23 -28 %)."""
    from benchmarks.identification_trial import trial_recording
    from dtid.identification import pipeline
    from dtid.identification.search.identify import identify_from

    truth, _, measured = trial_recording(1, (0.5, 20.0), VEHICLE_1)
    no_budget = SearchSettings(polish_evaluations=1, final_evaluations=1, newton_iterations=0)

    def search_that_closed_the_play(tests, par, ident, valid, *args, **kwargs):
        return identify_from(tests, par, ident, valid, CLOSED, no_budget)

    monkeypatch.setattr(pipeline, "identify", search_that_closed_the_play)
    selection = pipeline.identification_runs([measured], None, 0.25)  # 5 and 10 N*m
    report = pipeline.identify_runs(selection, reference_parameters(), profile_points=0)
    restart = report.restart
    assert restart is not None and restart.found_by == "closed gear play"
    assert restart.parameter == "c23" and restart.search_theta["eps23"] == 0.0
    assert restart.objective_restart < 0.9 * restart.objective_search
    found, true = report.parameters, theta_from_parameters(truth)
    errors = {n: found[n] / true[n] - 1 for n in ("c23", "d23", "eps23")}
    assert abs(errors["c23"]) < 0.35 and abs(errors["d23"]) < 0.6 and abs(errors["eps23"]) < 0.4
    assert "c23 held at 0.5 and 1.5 times the closed gear play's value fitted better" in (
        restart.message(True)
    )
    assert report.as_dict()["search_restart"]["found_by"] == "closed gear play"
    from dtid.cli.commands.identify import print_report

    print_report(report.as_dict(), {})
    printed = capsys.readouterr().out
    assert "restarted where c23 held at 0.5 and 1.5 times the closed gear play's value" in printed


VEHICLE_2 = DrivetrainParameters(
    J1=0.13,
    J2=0.1,
    J3=0.02,
    c12=320.0,
    c23=70.0,
    d12=1.2,
    d23=0.15,
    Tc12=0.6,
    eps12=0.035,
    eps23=0.02,
    T_loss=12.0,
    K=0.92,
)
"""The drivetrain of ../shared/independent/vehicle_2 (its truth.toml), written out as
:data:`VEHICLE_1` is."""
NARROW = {
    "J_sum": 0.2553,
    "x1": 0.4327,
    "x12": 0.9392,
    "c12": 240.4,
    "c23": 59.79,
    "d12": 0.9575,
    "d23": 0.1801,
    "Tc12": 0.374,
    "eps12": 0.04658,
    "eps23": 0.01808,
}
"""Where the default search ended on truth 12 drawn around vehicle_2 (2026-12-08, before the
check held an open play): the gear play open but 30 % narrow, eq. (17) 0.0506."""


def test_a_search_that_left_the_gear_play_narrow_is_restarted_where_it_fits_better(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Truth 12 drawn around vehicle_2: the default search ended with the gear play 30 % narrow
    (eq. 17 0.0506; on the same fresh draws of the model 0.0470 against 0.0432 at the optimum
    nearest the truth, eight standard errors). The search held at that point, the check finds a
    better fit with the play 1.5 times as wide and the search's last stages go on from there
    (2026-12-08: eps23 +5.7 %, d23 -14.4 %; the friction, which these runs pin to about 20 %,
    -35 % from this rounded start where the whole search ended at -9 %)."""
    from benchmarks.identification_trial import trial_recording
    from dtid.identification import pipeline
    from dtid.identification.search.identify import identify_from

    truth, _, measured = trial_recording(12, (0.5, 20.0), VEHICLE_2)
    no_budget = SearchSettings(polish_evaluations=1, final_evaluations=1, newton_iterations=0)

    def search_that_left_it_narrow(tests, par, ident, valid, *args, **kwargs):
        return identify_from(tests, par, ident, valid, NARROW, no_budget)

    monkeypatch.setattr(pipeline, "identify", search_that_left_it_narrow)
    selection = pipeline.identification_runs([measured], None, 0.25)
    report = pipeline.identify_runs(selection, reference_parameters(), profile_points=0)
    restart = report.restart
    assert restart is not None and restart.found_by == "open gear play"
    assert restart.parameter == "eps23" and restart.as_dict()["adopted"] is True
    assert restart.objective_restart < 0.95 * restart.objective_search
    found, true = report.parameters, theta_from_parameters(truth)
    errors = {n: found[n] / true[n] - 1 for n in ("eps23", "d23")}
    assert abs(errors["eps23"]) < 0.15 and abs(errors["d23"]) < 0.25
    assert "eps23 held at 0.667 and 1.5 times the open gear play's value fitted better" in (
        restart.message(True)
    )
