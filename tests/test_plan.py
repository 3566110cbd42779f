"""``dtid plan``: the predicted precision holds on recordings it did not see, the search finds
the shortest test, and the plan file runs (daemon configuration, ``dtid simulate --plan``)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from json_schemas import validate

from dtid import read_recording
from dtid.acquisition.config import load_config
from dtid.acquisition.plan import TestPlan, in_rounds, plan_from_file
from dtid.cli import main
from dtid.cli.commands.plan import recorded_identification
from dtid.errors import AnalysisError, ConfigError
from dtid.identification.frf.runs import find_runs
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.planning.design import (
    DEFAULT_TARGETS_PERCENT,
    DURATIONS_S,
    PRECISION_NAMES,
    SIGMAS,
    Design,
    predict,
    predict_worst,
    recommend,
    recommend_confirmed,
    recorded_correlation,
    recorded_spread,
    wider_than_targets,
)
from dtid.identification.planning.design import information as run_information
from dtid.identification.planning.document import plan_document
from dtid.identification.planning.information import (
    RESOLUTION_HZ,
    PlanInformation,
    measure_information,
)
from dtid.identification.planning.spread import DRIVETRAIN, MAX_SPREAD, spread_priors
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.objective import Objective
from dtid.identification.search.parameterization import (
    THETA_NAMES,
    Parameterization,
    theta_from_parameters,
)
from dtid.identification.search.sensitivity import jacobian, linearised_step
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.simulate import simulate


@pytest.fixture(scope="module")
def information() -> PlanInformation:
    """The reference vehicle's information at 2 (validation), 5 and 10 N*m from 60 s chirps."""
    return measure_information(reference_parameters(), (2.0, 5.0, 10.0), seeds=6)


def linearised_errors(design: Design, seeds: range) -> np.ndarray:
    """Eq. (17)'s linearised estimator applied to fresh recordings of ``design`` at the
    reference: (seeds, 13) relative errors, ordered as PRECISION_NAMES.

    Independent of the prediction's own machinery: new noise seeds, the design's own chirps (not
    the 60 s ones scaled), each seed's residual and its own eq. (17) weights, the errors mapped
    to J1-J3 exactly rather than to first order."""
    prior = reference_parameters()
    plan = design.test_plan()
    theta = theta_from_parameters(prior)
    values = np.array([theta[n] for n in THETA_NAMES])
    par = Parameterization.around(prior, prior.T_loss, prior.K)
    unit = par.unit(values[None])[0]
    span = par.upper - par.lower
    errors, jacobians = [], {}  # by the runs' bins (a seed's idle speed may move one)
    for seed in seeds:
        test = MeasuredTest.from_data(
            "fresh", from_simulation(simulate(prior, plan, seed=7000 + seed)), RESOLUTION_HZ
        )
        runs = [i for i, e in enumerate(test.estimates) if e.run.amplitude_nm > 3]
        drv = [test.estimates[i].drv_db for i in runs]
        objective = Objective(par, [test.model_test(runs)], [drv]).replacing(seed=50 + seed)
        sizes = tuple(len(d) for d in drv)
        if sizes not in jacobians:
            jacobians[sizes] = jacobian(objective, unit)[0]
        residual = objective.residuals(unit[None])[0]
        delta = linearised_step(jacobians[sizes], residual, sizes) * span
        estimate = values + delta
        j_sum, x1, x12 = estimate[:3]
        inertias = np.array([j_sum * x1 * x12, j_sum * (1 - x1) * x12, j_sum * (1 - x12)])
        true = np.array([prior.J1, prior.J2, prior.J3])
        errors.append(np.concatenate([inertias / true - 1, delta / values]))
    return np.array(errors)


def test_the_prediction_holds_on_fresh_recordings_of_a_longer_narrower_chirp(
    information: PlanInformation,
) -> None:
    """Predicted from 60 s chirps over 1-15 Hz, checked on new 120 s chirps over 2-12 Hz: the
    sweep spends 2.8 times as long per hertz, which the prediction carries by scaling each
    bin's variance, not by simulating it. Twelve fresh recordings leave about +-20 % on each
    measured scatter, so the median ratio over the parameters is held to within 25 % and each
    one to a factor 2 (the issue asks 1.5 of the searches' scatter; docs/planning.md)."""
    design = Design((5.0, 10.0), (1, 1), 120.0, 2.0, 12.0)
    predicted = np.array([predict(information, design)[n] for n in PRECISION_NAMES])
    errors = linearised_errors(design, range(12))
    measured = np.sqrt(np.mean(errors**2, axis=0))
    ratio = measured / predicted
    assert 0.75 < np.median(ratio) < 1.33, dict(zip(PRECISION_NAMES, ratio.round(2), strict=True))
    assert np.all((ratio > 0.5) & (ratio < 2.0)), dict(
        zip(PRECISION_NAMES, ratio.round(2), strict=True)
    )


def test_repeats_and_duration_trade_as_the_scaling_says(information: PlanInformation) -> None:
    """Twice the runs gives exactly 1/sqrt(2); twice the duration nearly so (the longer sweep
    loses less band to its edges, so a little better)."""
    one = predict(information, Design((5.0, 10.0), (1, 1), 60.0, 1.0, 15.0))
    two = predict(information, Design((5.0, 10.0), (2, 2), 60.0, 1.0, 15.0))
    long = predict(information, Design((5.0, 10.0), (1, 1), 120.0, 1.0, 15.0))
    for name in PRECISION_NAMES:
        assert two[name] == pytest.approx(one[name] / np.sqrt(2), rel=1e-9)
        assert 0.6 * one[name] < long[name] <= 1.01 * one[name] / np.sqrt(2)


def test_the_search_finds_the_shortest_test(information: PlanInformation) -> None:
    """Targets every design meets give the shortest design there is; the default targets a
    design that meets them, and none shorter among the same amplitudes' designs does."""
    loose = recommend(information, dict.fromkeys(PRECISION_NAMES, 1000.0), 10.0)
    assert loose.design.repeats == (1, 1)
    assert loose.design.duration_s == min(DURATIONS_S)
    assert loose.design.test_time_s == 3 + 3 * (min(DURATIONS_S) + 3)

    found = recommend(information, DEFAULT_TARGETS_PERCENT, 10.0, max_time_s=3600)
    assert not found.unmet
    assert found.design.amplitudes_nm == (5.0, 10.0)
    for name, target in DEFAULT_TARGETS_PERCENT.items():
        assert 100 * SIGMAS * found.precision[name] <= target * 1.001
    shorter = Design(
        found.design.amplitudes_nm,
        tuple(max(1, n - 1) for n in found.design.repeats),
        found.design.duration_s,
        found.design.f1_hz,
        found.design.f2_hz,
    )
    if shorter != found.design:
        worse = predict(information, shorter)
        assert any(100 * SIGMAS * worse[n] > t for n, t in DEFAULT_TARGETS_PERCENT.items())


def test_an_unreachable_target_is_said_with_what_would_reach_it(
    information: PlanInformation,
) -> None:
    found = recommend(information, DEFAULT_TARGETS_PERCENT, 10.0, max_time_s=300)
    assert found.design.test_time_s <= 300
    assert found.unmet
    friction = next(u for u in found.unmet if u.name == "Tc12")
    assert friction.predicted_percent > 20
    assert "min of chirps at 5 and 10 N*m" in friction.reason
    with pytest.raises(ConfigError, match="fewer than two amplitudes"):
        recommend(information, DEFAULT_TARGETS_PERCENT, 6.0)
    with pytest.raises(ConfigError, match="no test fits"):
        recommend(information, DEFAULT_TARGETS_PERCENT, 10.0, max_time_s=60)


def test_the_vehicles_around_a_prior_cover_its_spread() -> None:
    """Each drivetrain parameter of the drawn vehicles lies within +-spread of the prior's, one
    vehicle in each of the range's equal strata (a Latin hypercube); the operating point stays
    the prior's; the draw repeats."""
    prior = reference_parameters()
    drawn = spread_priors(prior, 0.4, 8)
    assert drawn == spread_priors(prior, 0.4, 8)
    assert spread_priors(prior, 0.0, 8) == [] and spread_priors(prior, 0.4, 0) == []
    for name in DRIVETRAIN:
        ratio = np.array([getattr(p, name) / getattr(prior, name) for p in drawn])
        assert np.all((ratio >= 0.6) & (ratio <= 1.4)), name
        strata = np.floor((ratio - 0.6) / 0.1).astype(int)
        assert sorted(strata) == list(range(8)), name
    assert {(p.T_loss, p.K) for p in drawn} == {(prior.T_loss, prior.K)}
    with pytest.raises(ValueError, match="spread"):
        spread_priors(prior, 1.0)
    only_friction = spread_priors(prior, {"Tc12": 0.9}, 4)
    assert len({p.Tc12 for p in only_friction}) == 4
    assert {p.replace(Tc12=prior.Tc12) for p in only_friction} == {prior}


def test_a_follow_up_spreads_each_parameter_by_what_the_first_test_left_open(
    information: PlanInformation,
) -> None:
    """After the paper's test, each parameter's half-width is twice its predicted precision,
    capped where a parameter would reach zero (at 90 %); after one short chirp the friction's
    is capped. (The paper's test leaves the friction near the cap: +-119 % on one host, +-87 %
    on another, the Coulomb term's finite differences following the floating point.)"""
    paper = [
        Design((5.0,), (1,), 60.0, 1.0, 15.0, validation_nm=0.0),
        Design((10.0,), (1,), 60.0, 1.0, 15.0, validation_nm=0.0),
    ]
    widths = recorded_spread(information, paper)
    precision = predict(information, None, paper)
    assert set(widths) == set(DRIVETRAIN)
    for name in DRIVETRAIN:
        assert widths[name] == pytest.approx(min(SIGMAS * precision[name], MAX_SPREAD)), name
    for name in ("J1", "c12", "eps12"):
        assert widths[name] == pytest.approx(SIGMAS * precision[name])
    short = [Design((5.0,), (1,), 30.0, 1.0, 15.0, validation_nm=0.0)]
    assert recorded_spread(information, short)["Tc12"] == MAX_SPREAD
    assert recorded_spread(information, []) == {}


def test_vehicles_drawn_along_a_correlation_vary_as_it_says() -> None:
    """With the identity the correlated draw is the independent one; with d12 and the friction
    correlated -0.9 their offsets follow (64 vehicles: sample correlation within 0.1, each
    offset's variance a third of its half-width squared within 25 %), the others stay
    uncorrelated, and a matrix that is not a correlation is refused."""
    prior = reference_parameters()
    independent, identity = (
        np.array([p.as_array() for p in spread_priors(prior, 0.4, 8, correlation)])
        for correlation in (None, np.eye(len(DRIVETRAIN)))
    )
    assert identity == pytest.approx(independent, rel=1e-12)
    correlation = np.eye(len(DRIVETRAIN))
    i, j = DRIVETRAIN.index("d12"), DRIVETRAIN.index("Tc12")
    correlation[i, j] = correlation[j, i] = -0.9
    drawn = spread_priors(prior, 0.3, 64, correlation)
    offsets = np.array([[getattr(p, n) / getattr(prior, n) - 1 for n in DRIVETRAIN] for p in drawn])
    sample = np.corrcoef(offsets.T)
    assert sample[i, j] == pytest.approx(-0.9, abs=0.1)
    assert np.all(np.abs(np.delete(sample[i], [i, j])) < 0.4)
    assert offsets.var(axis=0) == pytest.approx(np.full(len(DRIVETRAIN), 0.3**2 / 3), rel=0.25)
    with pytest.raises(ValueError, match="correlation"):
        spread_priors(prior, 0.3, 4, 2.0 * correlation)


def test_the_errors_a_first_test_leaves_are_correlated_as_the_physics_says(
    information: PlanInformation,
) -> None:
    """After the paper's test the predicted errors of the DMF's viscous damping and its friction
    are anticorrelated (both damp the DMF's resonance: the test tells their sum better than
    either); and the inertias' correlations, carried from setup 4 by their gradient, give
    J1 + J2 + J3 the variance of J_sum itself."""
    paper = [
        Design((5.0,), (1,), 60.0, 1.0, 15.0, validation_nm=0.0),
        Design((10.0,), (1,), 60.0, 1.0, 15.0, validation_nm=0.0),
    ]
    correlation = recorded_correlation(information, paper)
    assert recorded_correlation(information, []) is None
    assert correlation is not None and correlation.shape == (len(DRIVETRAIN),) * 2
    assert np.allclose(correlation, correlation.T) and np.allclose(np.diag(correlation), 1.0)
    assert np.all(np.linalg.eigvalsh(correlation) > -1e-9)
    assert correlation[DRIVETRAIN.index("d12"), DRIVETRAIN.index("Tc12")] < -0.5
    precision = predict(information, None, paper)
    prior = information.prior
    sd = np.array([precision[n] * getattr(prior, n) for n in ("J1", "J2", "J3")])
    inertias = [DRIVETRAIN.index(n) for n in ("J1", "J2", "J3")]
    variance = sd @ correlation[np.ix_(inertias, inertias)] @ sd
    j_sum = prior.J1 + prior.J2 + prior.J3
    assert np.sqrt(variance) == pytest.approx(precision["J_sum"] * j_sum, rel=1e-6)


def test_a_plan_for_several_vehicles_meets_the_hardest_ones_targets(
    information: PlanInformation,
) -> None:
    """A vehicle whose every residual is twice the prior's has exactly twice its predicted
    standard deviations (eq. 17's weights scale out of the sandwich), so a plan for the prior
    and that vehicle is the plan for that vehicle alone, and says how many of the two miss."""
    noisy = dataclasses.replace(
        information,
        levels=tuple(
            dataclasses.replace(level, sigma_db=2.0 * level.sigma_db)
            for level in information.levels
        ),
    )
    both = dataclasses.replace(information, around=(noisy,), spread=dict.fromkeys(DRIVETRAIN, 0.4))
    design = Design((5.0, 10.0), (2, 3), 60.0, 1.0, 15.0)
    alone = predict(information, design)
    assert predict_worst(both, design) == pytest.approx({n: 2 * v for n, v in alone.items()})
    found = recommend(both, DEFAULT_TARGETS_PERCENT, 10.0, max_time_s=3600)
    assert found.design == recommend(noisy, DEFAULT_TARGETS_PERCENT, 10.0, 3600).design
    assert found.per_vehicle[0] == pytest.approx(predict(information, found.design))
    short = recommend(both, DEFAULT_TARGETS_PERCENT, 10.0, max_time_s=300)
    friction = next(u for u in short.unmet if u.name == "Tc12")
    assert "the prior and 1 vehicles within +-40 %" in friction.reason
    assert friction.predicted_percent == pytest.approx(100 * SIGMAS * short.per_vehicle[1]["Tc12"])


def test_repeats_run_in_rounds() -> None:
    assert in_rounds([10.0, 5.0], [3, 2]) == (5.0, 10.0, 5.0, 10.0, 10.0)
    assert in_rounds([5.0, 10.0], 2) == (5.0, 10.0, 5.0, 10.0)
    for bad in ([1, 2, 3], 0, [1.5, 1]):
        with pytest.raises(ConfigError, match="repeats"):
            in_rounds([5.0, 10.0], bad)  # type: ignore[arg-type]


def _plan_file(tmp_path: Path) -> Path:
    path = tmp_path / "plan.json"
    plan = {
        "amplitudes_nm": [3.0, 10.0],
        "repeats": [2, 1],
        "duration_s": 30.0,
        "f1_hz": 2.0,
        "f2_hz": 12.0,
        "validation_nm": 2.0,
        "setpoint_rpm": 1000.0,
        "sweep": "linear",
    }
    path.write_text(json.dumps({"plan": plan}))
    return path


def test_the_daemon_configuration_runs_a_plan_file(tmp_path: Path) -> None:
    _plan_file(tmp_path)
    config = tmp_path / "dtid.toml"
    config.write_text('[test]\nplan = "plan.json"\nrequest_period_s = 0.01\n')
    test = load_config(config).test
    assert test.amplitudes_nm == (3.0, 10.0, 3.0)
    assert (test.duration_s, test.f1_hz, test.f2_hz, test.validation_nm) == (30, 2, 12, 2)
    assert test.levels == (3.0, 10.0, 3.0, 2.0)

    config.write_text("[test]\namplitudes_nm = [5, 10]\nrepeats = [1, 2]\n")
    assert load_config(config).test.amplitudes_nm == (5.0, 10.0, 10.0)
    config.write_text('[test]\nplan = "plan.json"\nduration_s = 60\n')
    with pytest.raises(ConfigError, match="'duration_s' and plan are both given"):
        load_config(config)
    config.write_text('[test]\nplan = "missing.json"\n')
    with pytest.raises(ConfigError, match="cannot read the plan file"):
        load_config(config)
    (tmp_path / "bad.json").write_text('{"plan": {"amplitudes_nm": [5]}}')
    with pytest.raises(ConfigError, match="has no 'repeats'"):
        plan_from_file(tmp_path / "bad.json")
    document = json.loads((tmp_path / "plan.json").read_text())
    for key, value, message in (  # hand-edited: a traceback's words, or silently linear
        ("f2_hz", None, "its plan's f2_hz is None, not a number"),
        ("sweep", "log", "its plan's sweep is 'log'; the test sweeps linearly"),
    ):
        edited = {"plan": {**document["plan"], key: value}}
        (tmp_path / "bad.json").write_text(json.dumps(edited))
        with pytest.raises(ConfigError, match=message):
            plan_from_file(tmp_path / "bad.json")
    recorded = {"schema": "dtid-recording-metadata/1", "plan": document["plan"]}
    (tmp_path / "bad.json").write_text(json.dumps(recorded))  # a recording's sidecar
    with pytest.raises(ConfigError, match="is a recording's metadata"):
        plan_from_file(tmp_path / "bad.json")


def test_dtid_simulate_records_the_planned_test(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The plan's runs, and a note where the simulated vehicle idles elsewhere than the plan's
    prediction assumed (`dtid plan --setpoint 700` simulated at 1000 rpm without a word)."""
    recording, plan = tmp_path / "planned.blf", _plan_file(tmp_path)
    assert main(["simulate", str(recording), "--plan", str(plan)]) == 0
    assert "was planned for" not in capsys.readouterr().out  # at its 1000 rpm
    runs = find_runs(read_recording(recording).test_data().test_torque)
    assert [round(r.amplitude_nm) for r in runs] == [3, 10, 3, 2]
    assert all(abs(r.duration_s - 30.0) < 0.2 for r in runs)
    assert main(["simulate", str(tmp_path / "x.blf"), "--plan", "p.json", "--f1", "2"]) == 2
    document = json.loads(plan.read_text())
    document["plan"]["setpoint_rpm"] = 700.0
    plan.write_text(json.dumps(document))
    assert main(["simulate", str(recording), "--force", "--plan", str(plan)]) == 0
    printed = capsys.readouterr().out
    assert "planned for a vehicle idling at 700 rpm; this one idles at 1000 rpm" in printed
    assert "--setpoint 700 simulates the vehicle it was planned for" in printed


def test_dtid_plan_writes_its_contract(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "plan.json"
    args = ["plan", "--seeds", "3", "--max-amplitude", "10", "--max-time", "400"]
    args += ["--spread-vehicles", "2"]  # and the reference prior's default spread
    assert main([*args, "--json", str(out), "--plot", str(tmp_path / "plan.png")]) == 0
    document = json.loads(out.read_text())
    validate(document, "plan")
    spread = document["spread"]
    assert (spread["percent"], spread["vehicles"], spread["correlated"]) == (40.0, 2, False)
    assert set(spread["percent_by_parameter"].values()) == {40.0}
    for name, value in document["predicted_precision"].items():
        assert value >= spread["predicted_precision_at_prior"][name]
    assert not document["meets_targets"]
    assert {u["name"] for u in document["unmet"]} >= {"Tc12"}
    assert document["test_time_s"] <= 400
    assert document["paper"]["test_time_s"] == 192.0
    printed = capsys.readouterr().out
    assert "does NOT meet every target" in printed and "unmet Tc12" in printed
    assert (tmp_path / "plan.png").stat().st_size > 20_000
    assert isinstance(plan_from_file(out), TestPlan)  # the daemon and simulate read it
    assert main(["plan", "--target", "c12=abc"]) == 2
    assert main(["plan", "--spread", "100"]) == 2
    assert main(["plan", "--spread", "recorded"]) == 2  # needs --after's recordings
    assert "error:" in capsys.readouterr().err


def test_a_bad_request_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from dtid.identification.planning import design

    def simulated(*args: object, **kwargs: object) -> None:
        raise AssertionError("simulated before the request was checked")

    monkeypatch.setattr(design, "measure_information", simulated)
    assert main(["plan", "--max-amplitude", "2"]) == 2  # refused before any simulation
    assert "2 N*m: the validation chirp's amplitude" in capsys.readouterr().err
    assert main(["plan", "--max-amplitude", "15", "--validation", "12"]) == 2
    assert "2 N*m: below the validation chirp's" in capsys.readouterr().err
    assert main(["plan", "--max-time", "60"]) == 2  # the shortest test lasts longer
    assert "no test fits in --max-time 60 s" in capsys.readouterr().err
    assert main(["plan", "--target", "stiffness=5"]) == 2
    assert "NAME one of J1" in capsys.readouterr().err
    (tmp_path / "other.json").write_text('{"runs": []}')
    assert main(["plan", "--prior", str(tmp_path / "other.json")]) == 2
    assert "--prior" in capsys.readouterr().err
    assert main(["plan", "--after", str(tmp_path / "missing.blf")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_a_prior_identified_on_its_boxs_edge_is_planned_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from dtid.cli.commands.plan import read_prior

    reference = reference_parameters()
    document = {"parameters": reference.as_dict(), "T_loss": reference.T_loss, "at_bounds": {}}
    path = tmp_path / "id.json"
    path.write_text(json.dumps(document))
    assert read_prior(path) == reference and "search box" not in caplog.text
    document["at_bounds"] = {"c23": {"side": "upper", "lower": 0.0, "upper": 300.0}}
    path.write_text(json.dumps(document))
    assert read_prior(path) == reference
    assert "c23 (upper) ended on an edge of the identification's search box" in caplog.text


def test_a_follow_up_counts_the_recorded_runs_in(information: PlanInformation) -> None:
    """After the paper's test the follow-up needs less than a test from scratch; after a test
    that met the targets, none."""
    paper = [
        Design((5.0,), (1,), 60.0, 1.0, 15.0, validation_nm=0.0),
        Design((10.0,), (1,), 60.0, 1.0, 15.0, validation_nm=0.0),
    ]
    scratch = recommend(information, DEFAULT_TARGETS_PERCENT, 10.0, max_time_s=3600)
    after = recommend(
        information, DEFAULT_TARGETS_PERCENT, 10.0, 3600, validation_nm=0.0, recorded=paper
    )
    assert after.design is not None and not after.unmet
    chirps = sum(after.design.repeats) * after.design.duration_s
    assert chirps < sum(scratch.design.repeats) * scratch.design.duration_s
    together = predict(information, after.design, paper)
    assert together == pytest.approx(after.precision)
    assert all(together[n] < predict(information, None, paper)[n] for n in PRECISION_NAMES)
    done = [Design((a,), (n,), 60.0, 1.0, 15.0, 0.0) for a, n in ((5.0, 40), (10.0, 40))]
    enough = recommend(information, DEFAULT_TARGETS_PERCENT, 10.0, recorded=done)
    assert enough.design is None and not enough.unmet


def _identification(intervals: dict[str, tuple[float, float]]) -> dict[str, object]:
    """An identification document at the reference: each parameter's profile interval the
    estimate +-1 % unless given, its grid the default box."""
    theta = theta_from_parameters(reference_parameters())
    ends = {n: intervals.get(n, (0.99 * v, 1.01 * v)) for n, v in theta.items()}
    return {
        "parameters": theta,
        "intervals": {n: {"lower": lo, "upper": hi} for n, (lo, hi) in ends.items()},
        "profiles": {n: {"values": [0.0, 0.5 * v, v, 2.0 * v]} for n, v in theta.items()},
    }


def test_dtid_plan_after_a_recording_plans_its_follow_up(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The paper's test recorded and identified, then `dtid plan --prior ID.json --after REC`:
    the follow-up counts the recording in, and the identification's profile intervals (here the
    friction's, +-40 %) confirm the targets; an identification of other recordings does not."""
    recording = tmp_path / "paper.blf"
    assert main(["simulate", str(recording), "--duration", "30"]) == 0
    identification = tmp_path / "id.json"
    friction = reference_parameters().Tc12
    made = _identification({"Tc12": (0.6 * friction, 1.4 * friction)})
    made["parameters"] = {**made["parameters"], **reference_parameters().as_dict()}
    made |= {"T_loss": 15.0, "combustion_variation": {str(recording): 0.03}}
    identification.write_text(json.dumps(made))
    out = tmp_path / "follow.json"
    args = ["plan", "--prior", str(identification), "--after", str(recording), "--seeds", "3"]
    args += ["--spread-vehicles", "2"]  # spread by what the recording leaves open (default)
    assert main([*args, "--max-amplitude", "10", "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    validate(document, "plan")
    widths = document["spread"]["percent_by_parameter"]
    # the friction left wide open (86 % of its value; the cap 90 % before the model replayed
    # the recording's own combustion variation), the inertias pinned
    assert 50 < widths["Tc12"] <= 100 * MAX_SPREAD and widths["J1"] < 10
    assert document["spread"]["correlated"]  # along the errors the recording leaves
    runs = document["recorded"]["runs"]
    assert sorted(round(r["amplitude_nm"]) for r in runs) == [5, 10]
    assert all(abs(r["duration_s"] - 30) < 0.5 for r in runs)
    assert document["plan"]["validation_nm"] == 0
    assert "validation amplitude" in document["information"]["excluded"]["2"]  # stays held out
    assert set(document["identify_nm"]) >= {5.0, 10.0}
    assert document["intervals"]["Tc12"]["half_width_percent"] == pytest.approx(40.0)
    assert not document["intervals"]["Tc12"]["confirms"] and not document["meets_targets"]
    assert "Tc12" in [u["name"] for u in document["unmet"]]
    printed = capsys.readouterr().out
    assert "identify the recordings of both tests together with --identify" in printed
    assert "unmet Tc12: its 95 % profile interval" in printed

    # a recording that only validated the identification may come along (the paper's layout
    # of ../shared/independent: one file per chirp), one it did not use may not
    validation = tmp_path / "paper-2nm.blf"
    made["nrmse"] = {"fit": {}, "validation": {f"{validation} @ 2 N*m": 0.1}}
    identification.write_text(json.dumps(made))
    given = argparse.Namespace(prior=identification, after=[recording, validation])
    assert recorded_identification(given) is not None
    assert "identified from other recordings" not in capsys.readouterr().out
    given = argparse.Namespace(prior=identification, after=[recording, tmp_path / "x.blf"])
    assert recorded_identification(given) is None
    assert "identified from other recordings" in capsys.readouterr().out
    made["combustion_variation"] = {str(tmp_path / "other.blf"): 0.03}
    identification.write_text(json.dumps(made))
    given = argparse.Namespace(prior=identification, after=[recording])
    assert recorded_identification(given) is None
    assert "identified from other recordings" in capsys.readouterr().out


def test_a_target_its_profile_interval_does_not_confirm_stays_unmet(
    information: PlanInformation,
) -> None:
    """The campaign trial's false stop (truth 5: the friction's interval -37/+30 % where the
    linearised prediction said 14 %): runs the prediction says meet every target are not enough
    where the friction's interval is wider than its 20 %; the follow-up is planned for the
    prediction scaled by what the interval showed it off by, and the JSON says why."""
    done = [Design((a,), (n,), 60.0, 1.0, 15.0, 0.0) for a, n in ((5.0, 40), (10.0, 40))]
    limits = {"max_amplitude_nm": 10.0, "max_time_s": 3600, "validation_nm": 0.0}
    tight = recommend_confirmed(
        information, DEFAULT_TARGETS_PERCENT, _identification({}), recorded=done, **limits
    )
    assert tight.design is None and tight.meets_targets and not tight.unconfirmed

    friction = reference_parameters().Tc12
    predicted = SIGMAS * 100 * predict_worst(information, None, done)["Tc12"]
    assert predicted < 20.0
    wide = _identification({"Tc12": (0.75 * friction, 1.22 * friction)})
    follow = recommend_confirmed(
        information, DEFAULT_TARGETS_PERCENT, wide, recorded=done, **limits
    )
    assert not follow.meets_targets
    assert [c.name for c in follow.unconfirmed] == ["Tc12"]
    check = follow.unconfirmed[0]
    assert check.half_width_percent == pytest.approx(25.0)
    assert check.predicted_percent == pytest.approx(predicted)
    assert follow.design is not None and not follow.unmet
    after = SIGMAS * 100 * follow.precision["Tc12"]
    assert after <= 20.0 * predicted / 25.0 * (1 + 1e-9)  # the prediction scaled by 25/p

    shown = {"max_amplitude_nm": 10.0, "max_time_s": 3600, "speed_window_rpm": 300.0}
    document = plan_document(information, follow, DEFAULT_TARGETS_PERCENT, shown)
    validate(document, "plan")
    assert not document["meets_targets"]
    (entry,) = document["unmet"]
    assert entry["name"] == "Tc12" and entry["target_percent"] == 20.0
    assert entry["predicted_percent"] == pytest.approx(25.0)
    assert "profile interval" in entry["reason"] and "does not reach" not in entry["reason"]
    assert document["intervals"]["Tc12"]["confirms"] is False
    assert document["intervals"]["c12"]["confirms"] is True

    # +-60 %: an hour of chirps more does not reach it (+-40 %, the campaign trial's truth 5,
    # sits on the hour's edge: 3,570 s on 2026-11-30, within it with the libraries of 2026-12-03)
    wider = _identification({"Tc12": (0.4 * friction, 1.6 * friction)})
    beyond = recommend_confirmed(
        information, DEFAULT_TARGETS_PERCENT, wider, recorded=done, **limits
    )
    assert [u.name for u in beyond.unmet] == ["Tc12"]
    (entry,) = plan_document(information, beyond, DEFAULT_TARGETS_PERCENT, shown)["unmet"]
    assert entry["predicted_percent"] == pytest.approx(60.0) and "does not reach" in entry["reason"]

    opened = _identification({"eps23": (0.99 * reference_parameters().eps23, None)})
    (check,) = recommend_confirmed(
        information, DEFAULT_TARGETS_PERCENT, opened, recorded=done, **limits
    ).unconfirmed
    assert check.name == "eps23" and not check.closed
    assert check.half_width_percent == pytest.approx(100.0)  # to the box's end, 2 x the value
    assert check.planning_target_percent == DEFAULT_TARGETS_PERCENT["eps23"]  # not scaled


def test_a_campaign_round_tests_each_target_at_its_half_width() -> None:
    """The worker's target tests in a campaign round: each target of the campaign (the rest at
    their defaults) as a half-width around the identified value, a value near 0 replaced by the
    one the plan is relative to (5 % of a passenger car's largest friction: 0.2 N*m); outside a
    campaign, none."""
    from dtid.identification.service.follow_up import campaign_widths

    assert campaign_widths(None) is None
    widths = campaign_widths({"targets": {"c12": 2.0}})
    assert widths is not None
    got = widths({"c12": 300.0, "Tc12": 0.0, "x1": 0.4})
    assert got == pytest.approx({"c12": 6.0, "Tc12": 0.2 * 0.2, "x1": 0.05 * 0.4})
    with pytest.raises(ConfigError, match="eps99"):
        campaign_widths({"targets": {"eps99": 5.0}})


def test_intervals_wider_than_the_targets_are_named_against_the_value_they_are_relative_to(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """An interval reaching past a target on either side, or open, is named with its ends in %
    of the value (of the planning floor where the value lies below it: a friction identified
    at 0 is planned relative to 0.2 N*m); one within it, or a name without a target, is not.
    `dtid identify` prints them with the follow-up command."""
    theta = {"c23": 40.0, "eps12": 0.05, "Tc12": 0.0, "d12": 1.0, "K": 0.9}
    intervals = {
        "c23": (36.0, 44.0),  # +-10 % for 5 %
        "eps12": (0.049, 0.051),  # +-2 % for 5 %
        "Tc12": (None, 0.1),  # open below; 0.1 N*m is 50 % of the floor 0.2 for 20 %
        "d12": (0.9, 1.1),  # +-10 % for 20 %
        "K": (0.0, 2.0),  # no target
    }
    wide = wider_than_targets(theta, intervals)
    assert list(wide) == ["c23", "Tc12"]
    assert wide["c23"] == pytest.approx((-10.0, 10.0))
    assert wide["Tc12"][0] is None and wide["Tc12"][1] == pytest.approx(50.0)
    assert wider_than_targets(theta, intervals, {"c23": 12.0, "Tc12": 60.0}) == {
        "Tc12": wide["Tc12"]
    }
    from dtid.cli.commands.identify import print_report

    document = {
        "parameters": theta,
        "intervals": {n: {"lower": lo, "upper": hi} for n, (lo, hi) in intervals.items()},
        "identifiable": {},
        "identifiability_notes": {},
        "nrmse": {},
        "combustion_variation": {},
        "idle_loop": {},
        "parameter_sets": 1,
        "seconds": 1.0,
    }
    print_report(document, {}, "dtid plan --prior id.json --after a.blf")
    out = capsys.readouterr().out
    assert (
        "default targets (95 % interval, % of the value): c23 -10/+10 (target 5), "
        "Tc12 open/+50 (target 20)\n" in out
    )
    assert "the follow-up test that reaches them: dtid plan --prior id.json --after a.blf" in out


def test_the_information_is_finite_at_a_prior_outside_its_own_plus_minus_100_percent_box() -> None:
    """A gearbox inertia 4 % of the total (x12 = 0.96, as vehicle_1 of ../shared/independent
    has 5 % and a vehicle drawn around it less): the prior's +-100 % box caps x12 at 0.95, its
    finite differences clipped to the box were 0/0, and `dtid plan --after` recommended the
    first design it tried. Measured in the identification's own box the information is finite,
    and x12's sensitivity is not zero."""
    prior = reference_parameters().replace(J3=0.01)
    assert (prior.J1 + prior.J2) / (prior.J1 + prior.J2 + prior.J3) == pytest.approx(0.96)
    plan = TestPlan(duration_s=30.0)
    info = measure_information(prior, (5.0, 10.0), reference=plan, seeds=2)
    x12 = THETA_NAMES.index("x12")
    for level in info.levels:
        assert np.isfinite(level.jacobian_db).all()
        assert np.abs(level.jacobian_db[:, x12]).max() > 0


def test_a_prediction_that_is_not_finite_is_never_recommended(
    information: PlanInformation,
) -> None:
    """Information with a NaN (a parameter set the simulator could not measure at a vehicle
    around the prior) once made `dtid plan` recommend the first design it tried; now such a
    vehicle makes no design recommendable, and the plan says why."""
    level = information.levels[1]
    broken = dataclasses.replace(level, jacobian_db=np.full_like(level.jacobian_db, np.nan))
    around = dataclasses.replace(
        information, levels=(information.levels[0], broken, *information.levels[2:])
    )
    with pytest.raises(AnalysisError, match="not finite"):
        recommend(dataclasses.replace(information, around=(around,)), DEFAULT_TARGETS_PERCENT, 10.0)


@pytest.fixture(scope="module")
def with_tiny_chirp() -> PlanInformation:
    """The reference's information at 0.3 N*m, too small a chirp to give an FRF, 5 and 10."""
    plan = TestPlan(duration_s=30.0)
    return measure_information(reference_parameters(), (0.3, 5.0, 10.0), reference=plan, seeds=1)


def test_an_amplitude_whose_chirp_gives_no_frf_is_left_out_with_the_reason(
    with_tiny_chirp: PlanInformation,
) -> None:
    """At a low idle a vehicle around the prior gave no FRF for the 2 N*m chirp (the measured
    torque's coherence 0.45), and `dtid plan` refused the whole prior. Such an amplitude is now
    measured as unusable, carries no information, and the search leaves it out, saying why;
    the amplitudes that do give an FRF are planned with."""
    info = with_tiny_chirp
    tiny, *usable = info.levels
    assert tiny.unusable and tiny.frequency_hz.size == 0
    assert all(not level.unusable and level.frequency_hz.size > 20 for level in usable)
    recommendation = recommend(info, {"J_sum": 5.0}, 10.0, validation_nm=0.0)
    assert recommendation.excluded[0.3].startswith("its chirp gave no FRF at the prior: ")
    assert recommendation.design is not None
    assert recommendation.design.amplitudes_nm == (5.0, 10.0)
    # a recorded run that such a vehicle would refuse tells nothing about it
    both = Design((0.3, 5.0), (1, 1), 30.0, 1.0, 15.0, validation_nm=0.0)
    alone = Design((5.0,), (1,), 30.0, 1.0, 15.0, validation_nm=0.0)
    assert np.array_equal(run_information(info, [both])[0], run_information(info, [alone])[0])


def test_a_validation_chirp_that_gives_no_frf_is_said(with_tiny_chirp: PlanInformation) -> None:
    """The validation chirp never identifies, but a plan whose validation chirp a vehicle
    would refuse leaves nothing to validate on: the plan says so."""
    recommendation = recommend(with_tiny_chirp, {"J_sum": 5.0}, 10.0, validation_nm=0.3)
    assert "may have nothing to validate on: the chirp run at" in recommendation.excluded[0.3]
