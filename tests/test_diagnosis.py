"""The diagnosis's mismatch map (dtid.identification.diagnosis): calibrated on the model's own
scatter, it declares a right model adequate, locates a wrong one where the physics says it must
miss, and its hints recover the value the data came from; its statistics against closed forms
and independent estimates."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from dtid.acquisition.plan import TestPlan
from dtid.cli import main as dtid
from dtid.identification.diagnosis.bin_statistics import (
    TREND_DEGREE,
    bin_autocorrelation,
    family_p_value,
    neighbour_correlation,
    trend_test,
)
from dtid.identification.diagnosis.diagnose import amplitude_trend, diagnose, diagnose_document
from dtid.identification.diagnosis.hints import EffectiveValue
from dtid.identification.diagnosis.mismatch import (
    EDGE_Z,
    ROUGH_SCALE,
    TREND_LAGS,
    TREND_WINDOW,
    MismatchMap,
    NoiseFigures,
    RunResidual,
    find_bands,
    mismatch_map,
    model_scatter,
    scatter_scale,
    smoothed,
    trend_db,
)
from dtid.identification.model.cylinder_spread import (
    odd_place,
    one_cylinder,
    single_share,
    stroke_factors,
)
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import identification_runs, validation_runs
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.runs import engine_gain
from dtid.simulator.linear import three_mass_modes
from dtid.simulator.mechanisms import Effects, kernel_parameters
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, simulate
from dtid.simulator.vehicle_data import VehicleData
from tests.json_schemas import validate


@pytest.fixture(scope="module")
def selections(reference_data):
    """The reference test's identifying (5, 10 N*m) and validating (2 N*m) runs."""
    tests = [MeasuredTest.from_data("reference", reference_data, 0.25, VehicleData())]
    return [("fit", identification_runs(tests)), ("validation", validation_runs(tests))]


@pytest.fixture(scope="module")
def at_truth(selections, reference):
    return mismatch_map(reference, selections)


def test_the_model_at_the_truth_explains_the_recording(at_truth):
    assert at_truth.adequate, [band.as_dict() for band in at_truth.bands]
    assert at_truth.global_p_value > at_truth.family_error
    # the scatter is calibrated: z has about unit spread where the model is right
    z = np.concatenate([r.z for r in at_truth.residuals])
    assert 0.7 < np.sqrt(np.nanmean(z**2)) < 1.4
    assert {r.role for r in at_truth.residuals} == {"fit", "validation"}
    # both FRFs of every run: the recording carries the ECU's torque request
    assert sorted((r.amplitude_nm, r.frf) for r in at_truth.residuals) == [
        (a, frf) for a in (2.0, 5.0, 10.0) for frf in ("drv", "eng")
    ]
    assert at_truth.engine is not None
    assert at_truth.engine.threshold_z > 0 and at_truth.engine.scatter_scale >= 1


def test_a_wrong_dmf_stiffness_is_located_at_the_dmf_mode_and_the_hint_finds_the_truth(
    selections, reference
):
    wrong = reference.replace(c12=1.3 * reference.c12)
    baseline = {"parameters": {}, "nrmse": {}, "objective": 0.0}
    diagnosis = diagnose(wrong, selections, baseline, mechanisms=())  # locate only
    assert not diagnosis.adequate
    # the model's DMF is too stiff: every strong band lies where the DMF shapes the response,
    # from its anti-resonance (4.5-5 Hz on these runs) over its resonance (6.5-7 Hz) to the
    # flank above, none on the inertia line below 3 Hz
    assert three_mass_modes(wrong)[0] > three_mass_modes(reference)[0]
    low = 3.0
    first = diagnosis.mismatch.bands[0]
    assert first.p_value < 1e-6
    bins = [band for band in diagnosis.mismatch.bands if band.kind == "bins"]
    strong = [band for band in bins if band.p_value < 1e-4]
    assert strong and all(low < band.peak_hz < 12.5 for band in strong), strong
    assert {band.amplitude_nm for band in diagnosis.mismatch.bands} >= {5.0, 10.0}
    # each identifying run on its own asks for the stiffness the data were made with
    for hint in diagnosis.hints:
        if hint.name == "c12" and hint.role == "fit":
            assert hint.effective == pytest.approx(reference.c12, rel=0.08), hint
            assert hint.nrmse_effective < hint.nrmse_identified
    assert "c12" in diagnosis.sentence()
    assert "the identifying runs agree on one value: the model's is off" in diagnosis.sentence()


TAU_M = 0.03
"""Lag of the engine in the torque-lag test, s (the low end of the mechanism's typical range)."""


@pytest.fixture(scope="module")
def lagging(reference):
    """A recording of the reference vehicle whose engine lags by :data:`TAU_M`, its runs; with
    eq. (9)'s speed sensor, as the lag's figures were measured (with a tooth timer the lag's
    T/T_ecu fit reads it about 5 % long: docs/model-assumptions.md)."""
    lagging = SimulationOptions(effects=Effects({"tau_m": TAU_M}), speed_average="speeds")
    plan = TestPlan(amplitudes_nm=(2.0, 5.0, 10.0), validation_nm=0.0, duration_s=40.0)
    data = from_simulation(simulate(reference, plan, lagging, seed=3))
    tests = [MeasuredTest.from_data("lagging", data, 0.25, VehicleData(speed_average="speeds"))]
    chosen = [("fit", identification_runs(tests)), ("validation", validation_runs(tests))]
    return data, chosen


def test_a_torque_lag_is_located_in_g_eng_where_the_analytic_lag_puts_it(reference, lagging):
    """An engine that delivers its request with a lag (``torque_lag``): each stroke's torque moves
    towards K T_ecu by 1 - a, a = exp(-T/tau), T the stroke period, so the delivered torque is
    the request through L(z) = (1 - a) / (1 - a z^-1), z = exp(j 2 pi f T). The sensor sees what
    is delivered: |G_DRV| (speed per measured torque) keeps the drivetrain, |G_ENG| (measured per
    requested torque) falls by |L|. The map compares |G_ENG| in shape (its level is K's): the
    true drivetrain without the lag is located in |G_ENG| at 10 N*m, above the model at the
    bottom of the band and below it at the top, its residual following 20 log10 |L| (a closed
    form) less one level; with the lag in the model, no |G_ENG| band is left."""
    data, chosen = lagging
    without = mismatch_map(reference, chosen)
    engine_bands = [band for band in without.bands if band.frf == "eng"]
    at_10 = [band for band in engine_bands if round(band.amplitude_nm) == 10]
    assert any(b.excess_db > 2.0 and b.peak_hz < 4.0 for b in at_10), engine_bands
    assert any(b.excess_db < -2.0 and b.peak_hz > 10.0 for b in at_10), engine_bands
    assert without.engine is not None
    for residual in (r for r in without.residuals if r.frf == "eng"):
        stroke_s = 30.0 / data.speed.value.mean()  # pi of crank angle at the mean speed
        a = np.exp(-stroke_s / TAU_M)
        z = np.exp(2j * np.pi * residual.frequency_hz * stroke_s)
        lag_db = 20 * np.log10(np.abs((1 - a) / (1 - a / z)))
        assert lag_db[-1] < -5.0  # the lag is no small effect at the top of the band
        # the residual is the lag less the one level the map moved the model by
        misfit = residual.residual_db - lag_db + without.engine.level_db
        # measured 0.15, 0.35 and 0.79 dB RMS at 10, 5 and 2 N*m: about a third of the scatter
        limit = 0.6 * np.sqrt(np.mean(residual.scatter_db**2))
        assert np.sqrt(np.mean(misfit**2)) < limit, (residual.label, misfit.round(2))
    lagged = kernel_parameters(reference.as_array(), Effects({"tau_m": TAU_M}))
    with_lag = mismatch_map(lagged, chosen)
    assert not [band for band in with_lag.bands if band.frf == "eng"], with_lag.bands
    assert with_lag.engine is not None and abs(with_lag.engine.level_db) < 0.1


def test_a_torque_lag_is_named_fitted_and_bounded_on_g_eng(reference, lagging, selections):
    """The lag the map located is named: fitted on |G_ENG| (which |G_DRV| cannot, absorbing it),
    significant, the held-out run's |G_ENG| closer, its profile interval holding the value the
    recording was made with. The model diagnosed has the true drivetrain and eq. (24)'s K, which
    the lag lowers (|G_ENG|'s mean); the lag's fit on |G_ENG| restores K, and the drivetrain
    refitted with both stays near the truth. On the recording without a lag the model is adequate
    and the lag is not called indistinguishable: |G_ENG| would see one."""
    _, chosen = lagging
    fit = chosen[0][1]
    kept = fit.tests[0]
    identifying = dataclasses.replace(kept, estimates=tuple(kept.estimates[i] for i in fit.runs[0]))
    identified = reference.replace(K=engine_gain([identifying]))
    assert identified.K < 0.8 * reference.K  # measured 0.60 for the true 0.9
    baseline = {"parameters": {}, "nrmse": {}, "objective": 0.0}
    diagnosis = diagnose(identified, chosen, baseline, mechanisms=["torque_lag"], profile_points=5)
    assert diagnosis.mechanisms == ("torque_lag",), diagnosis.sentence()
    (named,) = diagnosis.accepted
    assert named.drivetrain().K == pytest.approx(reference.K, rel=0.02)
    assert named.frf == "eng" and named.p_value < 1e-6 and named.validation_gain > 0.2
    # measured 0.0305 s, interval 0.0291-0.0315 s
    assert named.parameters()["tau_m"] == pytest.approx(TAU_M, rel=0.05)
    interval = diagnosis.intervals["tau_m"]
    assert interval["verdict"] == "practical" and interval["lower"] < TAU_M < interval["upper"]
    drivetrain = named.drivetrain()
    # within issue 15's 5 %: the refit ends in the DMF's valley where its path takes it (with
    # the speed sensor's noise in the map's draws, c12 +3.4 %, the friction +59 %; without,
    # +0.9 % and +8 %: the same lag and K); the inertias within 0.5 %, K +0.6 %
    for name in ("J1", "J2", "J3", "c12", "c23"):
        assert getattr(drivetrain, name) == pytest.approx(getattr(reference, name), rel=0.05)
    assert diagnosis.after is not None and diagnosis.after.adequate, diagnosis.after.bands
    assert "torque_lag explains it" in diagnosis.sentence()

    quiet = diagnose(reference, selections, baseline, mechanisms=["torque_lag"])
    assert quiet.adequate and not quiet.candidates
    assert [(s.mechanism, s.frf) for s in quiet.screened] == [("torque_lag", "eng")]
    assert "torque_lag" not in quiet.indistinguishable


SHARE = -0.12
"""The concealed imbalance: the first cylinder of the firing order gives 12 % less."""


@pytest.fixture(scope="module")
def imbalanced(reference):
    """A recording of the reference vehicle with a cylinder imbalance, the simulation (its
    strokes' cylinders) and its runs."""
    options = SimulationOptions(effects=Effects({"share": SHARE}))
    plan = TestPlan(amplitudes_nm=(2.0, 5.0, 10.0), validation_nm=0.0, duration_s=40.0)
    result = simulate(reference, plan, options, seed=3)
    tests = [MeasuredTest.from_data("imbalanced", from_simulation(result), 0.25, VehicleData())]
    return result, [("fit", identification_runs(tests)), ("validation", validation_runs(tests))]


def test_the_strokes_places_follow_the_firing_order_and_the_share_is_its_least_squares():
    """Closed forms of :mod:`dtid.identification.model.cylinder_spread`: strokes numbered with
    gaps (lost reports) keep their places; the factors of a one-cylinder pattern are that
    pattern; its share is the least-squares one."""
    rng = np.random.default_rng(0)
    number = np.sort(rng.choice(4000, 3000, replace=False))  # a quarter of the reports lost
    pattern = np.array([1.0, 1.0, 1.0 + 0.09, 1.0]) * (1 - 0.03)  # place 2 odd, mean 1
    request = 20.0 + 10.0 * np.sin(0.013 * number)  # the chirp and the loop move the request
    factors = stroke_factors(number, 0.9 * pattern[number % 4] * request, request)[0]
    np.testing.assert_allclose(factors, pattern / pattern.mean(), rtol=1e-12)
    assert odd_place(factors) == 2
    share = single_share(factors, 2)
    fitted = np.sum((factors - one_cylinder(share, 2)) ** 2)
    for trial in (share - 1e-3, share + 1e-3):  # least squares: any other share misses more
        assert np.sum((factors - one_cylinder(trial, 2)) ** 2) > fitted
    np.testing.assert_allclose(one_cylinder(0.09, 1), [0.97, 1.09, 0.97, 0.97])


def test_a_cylinder_imbalance_is_read_from_the_strokes_and_modelled_on_its_own_stroke(
    reference, imbalanced, selections
):
    """The strokes show the imbalance whatever the map says: its share, significant, predicts the
    held-out run's strokes; the model puts it on the stroke the recording shows (the
    simulator's first cylinder) and then explains the recordings, while the same share on
    another stroke makes a line of its own in |G_ENG|. A recording without one is adequate."""
    result, chosen = imbalanced
    fit = chosen[0][1]
    loop = fit.tests[0].loop
    # the odd place is the simulator's cylinder 0 (its reports matched by time)
    reported = np.isin(result.torque_t, loop.stroke_t)
    odd = loop.stroke_number[np.isin(loop.stroke_t, result.torque_t[result.cylinder == 0])]
    assert reported.sum() > 0.99 * len(loop.stroke_t)
    assert set(odd % 4) == {loop.odd_stroke}
    baseline = {"parameters": {}, "nrmse": {"fit": {}, "validation": {}}, "objective": 0.0}
    diagnosis = diagnose(
        reference, chosen, baseline, mechanisms=["cylinder_imbalance"], profile_points=3
    )
    assert not diagnosis.adequate and diagnosis.mechanisms == ("cylinder_imbalance",)
    (named,) = diagnosis.accepted
    assert named.frf == "strokes" and named.p_value < 1e-10 and named.validation_gain > 0.9
    assert named.parameters()["share"] == pytest.approx(SHARE, rel=0.03)
    interval = diagnosis.intervals["share"]
    assert interval["lower"] < SHARE < interval["upper"]
    assert diagnosis.after is not None and diagnosis.after.adequate, diagnosis.after.bands
    assert "cylinder_imbalance explains it" in diagnosis.sentence()
    validate(diagnosis.as_dict(), "diagnosis")
    on_another = [
        (
            role,
            dataclasses.replace(
                selection,
                tests=tuple(
                    dataclasses.replace(
                        t, loop=dataclasses.replace(t.loop, odd_stroke=(t.loop.odd_stroke + 2) % 4)
                    )
                    for t in selection.tests
                ),
            ),
        )
        for role, selection in chosen
    ]
    wrong = mismatch_map(named.row, on_another)
    assert any(band.frf == "eng" for band in wrong.bands), wrong.bands

    quiet = diagnose(reference, selections, baseline, mechanisms=["cylinder_imbalance"])
    assert quiet.adequate and not quiet.candidates
    assert quiet.cylinders is not None and quiet.cylinders.p_value > 0.01
    assert "cylinder_imbalance" not in quiet.indistinguishable


def effective(amplitude: float, value: float, role: str = "fit", edge: bool = False):
    return EffectiveValue(
        "c12", f"r @ {amplitude:g}", role, amplitude, 300.0, value, 0.1, 0.05, edge
    )


def test_amplitude_trend_reads_the_runs_effective_values():
    assert amplitude_trend([effective(5, 330), effective(10, 360)]) == "rising with the amplitude"
    assert amplitude_trend([effective(10, 300), effective(5, 360)]) == "falling with the amplitude"
    agree = amplitude_trend(
        [effective(5, 352), effective(10, 345), effective(2, 250, "validation")]
    )
    assert agree == "the identifying runs agree on one value: the model's is off"
    # a second stage engaged at both identifying amplitudes shows only in the smaller held-out
    # run (a two-stage clutch: trial case 6 asked for c23 275 and 278 at 5 and 10 N*m, 171 or
    # less at 2 N*m, against 274 identified)
    stage = amplitude_trend(
        [effective(5, 306), effective(10, 309), effective(2, 187.5, "validation", edge=True)]
    )
    assert stage.startswith(
        "the identifying runs agree with the model's value, the held-out run at 2 N*m asks for "
        "38% less at least: c12 grows with the amplitude beyond the identifying runs' reach, as "
        "progressive_spring engaged"
    ), stage
    softer_above = amplitude_trend(  # softer at a larger amplitude: no second stage does that
        [effective(5, 306), effective(10, 309), effective(20, 240, "validation")]
    )
    assert softer_above == (
        "the identifying runs agree with the model's value, the held-out run at 20 N*m asks for "
        "20% less"
    )
    assert amplitude_trend([effective(5, 306), effective(10, 309)]) == (
        "the identifying runs agree with the model's value"
    )
    assert amplitude_trend([effective(5, 330)]) == ""  # one identifying run says nothing
    assert amplitude_trend([effective(5, 330), effective(10, 480, edge=True)]) == ""


def test_without_a_torque_request_the_diagnosis_says_why_it_cannot(reference_data, reference):
    from dtid.errors import AnalysisError

    data = dataclasses.replace(reference_data, torque_request=None)
    tests = [MeasuredTest.from_data("no request", data, 0.25, VehicleData())]
    with pytest.raises(AnalysisError, match="torque_request role"):
        mismatch_map(reference, [("fit", identification_runs(tests))])


def test_the_smoothed_scatter_keeps_the_rise_where_the_chirp_excites_less():
    """Constant noise over an excitation that falls to a quarter in the sweep's top bin: the
    smoothed variance is noise / S_zz in every bin, four times higher in that one (a plain
    average over five bins would have given 2.5 there)."""
    excitation = np.ones(12)
    excitation[-1] = 0.25
    variance = 0.01 / excitation
    assert smoothed(variance, excitation) == pytest.approx(variance, rel=1e-12)
    variance[4] = np.nan  # a bin without draws: its neighbours' average stands in for it
    assert smoothed(variance, excitation)[2:7] == pytest.approx(np.full(5, 0.01), rel=1e-12)


def test_a_recording_far_rougher_than_the_models_draws_is_said_to_be():
    """White residuals of unit scatter against draws of 1/300 and of 1: the scale is the ratio
    of their roughness (the medians of neighbour differences of independent normal bins, so 300
    and 1 within the medians' sampling error over 4 x 60 bins), and only the first |G_ENG| is
    named as rougher than the draws (vehicle 34's 1047 before its fix, docs/diagnosis.md)."""
    rng = np.random.default_rng(3)
    residuals = [rng.standard_normal(60) for _ in range(4)]
    scales = [
        scatter_scale(residuals, [spread * rng.standard_normal((16, 60)) for _ in range(4)])
        for spread in (1 / 300, 1.0)
    ]
    assert scales[0] == pytest.approx(300, rel=0.15)
    assert scales[1] == pytest.approx(1, abs=0.15)
    figures = [NoiseFigures(scale, 0.3, 100.0, 60.0, 4.8) for scale in scales]
    noisy = MismatchMap((), (), figures[1], 200.0, 1.0, engine=figures[0])
    assert [m.split(" residuals")[0] for m in noisy.noise_warnings()] == ["the recordings' |G_ENG|"]
    assert MismatchMap((), (), figures[1], 200.0, 1.0, engine=figures[1]).noise_warnings() == []
    assert scales[0] > ROUGH_SCALE > scales[1]


def test_the_model_draws_scatter_as_recordings_do_at_the_top_of_the_sweep(
    reference: DrivetrainParameters,
) -> None:
    """The reference vehicle at 5 and 10 N*m, seeds 1-16, the model at the truth: over the top
    six bins of each run (12.98-14.48 Hz, where the speed's response is smallest and the sweep
    ends) the recordings' scatter over the seeds is 0.75-1.3 times the one the map's draws
    give on |G_DRV|, and on |G_ENG| no more than they give (measured: |G_DRV| 0.86-0.91,
    |G_ENG| 0.66-0.68). Without the speed sensor's noise in the draws the |G_DRV| scattered
    1.39 (5 N*m) and 1.17 (10 N*m) times what they gave; with a plain average over
    neighbouring bins (not by the excitation) the top bin's scatter came out at 0.54-0.92 of
    the recordings'. The draws overstate |G_ENG|'s scatter because the model replays each
    recording's own combustion variation and a draw's sensor reports its drawn rest too
    (:class:`dtid.identification.model.response.ModelTest`'s ``recording_noise``); before the
    replay both FRFs scattered 0.81-1.11 times the draws."""
    plan = TestPlan(amplitudes_nm=(5.0, 10.0), validation_nm=0.0)
    measured, drawn = {}, {}
    for seed in range(1, 17):
        data = from_simulation(simulate(reference, plan, SimulationOptions(), seed=seed))
        selection = identification_runs([MeasuredTest.from_data("r", data, 0.25, VehicleData())])
        for run in model_scatter(reference, "fit", selection, 16):
            key = (run.estimate.run.amplitude_nm, run.frf)
            measured.setdefault(key, []).append(run.residual_db[-6:])
            drawn.setdefault(key, []).append(run.scatter_db[-6:] ** 2)
    assert len(measured) == 4
    for key, residuals in measured.items():
        ratio = np.sqrt(np.mean(np.var(residuals, axis=0, ddof=1)) / np.mean(drawn[key]))
        assert (0.75 if key[1] == "drv" else 0.5) < ratio < (1.3 if key[1] == "drv" else 1.0), (
            key,
            ratio,
        )


def test_neighbour_correlation_of_an_ar1_sequence():
    rng = np.random.default_rng(3)
    rho, n = 0.5, 4000
    noise = rng.standard_normal((8, n))
    series = np.empty_like(noise)
    series[:, 0] = noise[:, 0]
    for i in range(1, n):
        series[:, i] = rho * series[:, i - 1] + np.sqrt(1 - rho**2) * noise[:, i]
    assert neighbour_correlation([series]) == pytest.approx(rho, abs=0.02)
    assert neighbour_correlation([rng.standard_normal((8, n))]) == pytest.approx(0.0, abs=0.02)


def test_the_trend_test_is_chi_square_on_correlated_bins_and_finds_a_slope_no_bin_shows():
    """On AR(1) noise over 48 bins (lag-one correlation 0.45, as the map measures on its draws),
    with the correlation measured from other draws, T^2 rejects at a nominal 5 % in 5 % of
    sequences (chi-square with four degrees of freedom); a slope of 2.4 scatters over the band,
    each bin within its threshold, is found at p < 1e-4, and the trend returned is the slope."""
    rng = np.random.default_rng(11)
    rho, n, count = 0.45, 48, 4000

    def ar1(rows: int) -> np.ndarray:
        noise = rng.standard_normal((rows, n))
        out = np.empty_like(noise)
        out[:, 0] = noise[:, 0]
        for i in range(1, n):
            out[:, i] = rho * out[:, i - 1] + np.sqrt(1 - rho**2) * noise[:, i]
        return out

    f = np.linspace(1.5, 14.5, n)
    acf = bin_autocorrelation([ar1(400)], TREND_LAGS)
    assert acf[1] == pytest.approx(rho, abs=0.03)
    values = [trend_test(z, f, acf) for z in ar1(count)]
    assert {dof for _, dof, _ in values} == {TREND_DEGREE + 1}
    rejected = np.mean([stats.chi2.sf(t2, dof) < 0.05 for t2, dof, _ in values])
    assert rejected == pytest.approx(0.05, abs=0.012)
    slope = np.linspace(-2.4, 2.4, n)
    t2, dof, trend = trend_test(slope, f, acf)
    assert stats.chi2.sf(t2, dof) < 1e-4
    np.testing.assert_allclose(trend, slope, atol=1e-12)


def test_a_trend_bands_excess_is_the_residuals_running_mean_never_beyond_it():
    """A mode the model lacks (-9 dB, then +7 dB), the band's last bins noisy: the trend band's
    excess is the residual's inverse-variance running mean over a quarter of the band, within
    the residual's range (the cubic of the test, read back bin by bin, is not)."""
    n = 120
    f = np.linspace(2.5, 13.5, n)
    measured = np.where((f > 10.0) & (f < 11.7), -9.0, 0.0) + np.where(f >= 11.7, 7.0, 0.0)
    scatter = np.full(n, 0.5)
    scatter[-6:] = 9.0
    z = measured / scatter
    residual = RunResidual("r", "fit", "drv", 5.0, f, measured, np.zeros(n), scatter, z, z)
    excess = trend_db(residual)
    # within the range to rounding (numpy 2.4's sums put a mean of 7.0s at 7.000000000000001)
    assert np.nanmin(excess) >= -9.0 - 1e-9 and np.nanmax(excess) <= 7.0 + 1e-9
    width = round(TREND_WINDOW * n)
    i = 60  # a window of equal weights: the plain mean of its bins
    window = slice(i - width // 2, i - width // 2 + width)
    assert excess[i] == pytest.approx(np.mean(measured[window]), abs=1e-12)
    i = n - 1  # the noisy last bins weigh (0.5 / 9)^2 as much
    weight = scatter[i - width // 2 :] ** -2.0
    expected = np.sum(weight * measured[i - width // 2 :]) / np.sum(weight)
    assert excess[i] == pytest.approx(expected, abs=1e-12)
    assert np.max(np.abs(trend_test(z, f, np.array([1.0]))[2] * scatter)) > 9.0


def test_family_p_value_is_sidaks_with_students_t():
    for z, m, dof in ((3.0, 50.0, 30.0), (4.5, 200.0, 1e6), (1.0, 1.0, 10.0)):
        single = 2 * stats.t.sf(z, dof)
        assert family_p_value(z, m, dof) == pytest.approx(1 - (1 - single) ** m, rel=1e-9)
    # at the threshold the family-wise error is the one asked for
    m, dof = 60.0, 40.0
    threshold = stats.t.isf((1 - 0.99 ** (1 / m)) / 2, dof)
    assert family_p_value(threshold, m, dof) == pytest.approx(0.01, rel=1e-6)


def test_bands_gather_same_signed_neighbours_around_a_significant_bin():
    f = np.arange(10.0)
    z = np.array([0.0, 2.5, 6.0, 3.0, -2.5, -2.2, 0.0, -5.0, 1.0, 2.1])
    residual = RunResidual(
        "r", "fit", "drv", 5.0, f, z * 0.1, np.zeros(10), np.full(10, 0.1), z, np.ones(10)
    )
    bands = find_bands(residual, threshold=4.0, effective=10.0, dof=100.0)
    assert [(b.f_lo_hz, b.f_hi_hz, b.peak_hz) for b in bands] == [(1, 3, 2), (7, 7, 7)]
    assert bands[0].excess_db == pytest.approx(0.6) and bands[1].excess_db == pytest.approx(-0.5)
    assert all(abs(z[int(b.f_lo_hz)]) >= EDGE_Z for b in bands)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("diagnose") / "test.blf"
    command = ["simulate", str(path), "--amplitudes", "5", "10", "2", "--duration", "20"]
    assert dtid([*command, "--seed", "4"]) == 0
    return path


def identification_document(recording: Path, reference, **changes: float) -> dict:
    """An identification JSON as `dtid identify` writes it, at the truth (changed)."""
    from dtid.workflow import measured_tests

    test = measured_tests([recording])[0]
    values = reference.replace(**changes).as_dict()
    return {
        "parameters": {k: v for k, v in values.items() if k != "T_loss"},
        "T_loss": values["T_loss"],
        "combustion_variation": {test.name: test.combustion_variation},
        "nrmse": {"fit": {}, "validation": {}},
        "objective": 0.0,
    }


def test_diagnose_command_writes_the_documented_json(recording, reference, tmp_path, capsys):
    document = identification_document(recording, reference, c12=1.3 * reference.c12)
    identification = tmp_path / "id.json"
    identification.write_text(json.dumps(document))
    out = tmp_path / "diagnosis.json"
    command = ["diagnose", str(recording), "--identification", str(identification)]
    command += ["--mechanisms"]  # none: locate only (the refits are tested below)
    assert dtid([*command, "--json", str(out), "--plot", str(tmp_path / "map.png")]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("The identified model misses these recordings")
    result = json.loads(out.read_text())
    validate(result, "diagnosis")
    assert result["adequate"] is False and result["mismatch"]
    assert result["verdict"]["unexplained"] == result["mismatch"]
    assert result["candidates"] == [] and result["verdict"]["mechanisms"] == []
    assert (tmp_path / "map.png").stat().st_size > 10_000


def test_diagnose_refuses_a_file_that_is_no_identification(recording, tmp_path, capsys):
    wrong = tmp_path / "wrong.json"
    wrong.write_text('{"not": "an identification"}')
    assert dtid(["diagnose", str(recording), "--identification", str(wrong)]) == 2
    assert "not an identification JSON" in capsys.readouterr().err
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"parameters": {"J1": 0.1}, "T_loss": 10.0}))
    assert dtid(["diagnose", str(recording), "--identification", str(other)]) == 2
    assert "lacks" in capsys.readouterr().err


def test_a_document_for_other_recordings_is_refused(recording, reference):
    from dtid.errors import ConfigError
    from dtid.workflow import measured_tests

    document = identification_document(recording, reference)
    document["combustion_variation"] = {"elsewhere.blf": 0.02}
    with pytest.raises(ConfigError, match="other recordings"):
        diagnose_document(measured_tests([recording]), document)


def test_a_right_model_is_adequate_and_the_screen_names_what_it_cannot_see(selections, reference):
    """At the truth nothing is named; the mechanisms no data of this test can show are listed
    as indistinguishable: an asymmetric DMF play (no mean torque loads the DMF in neutral, so
    the asymmetry only shifts the play's centre) and a uniform torque-sensor gain (it scales
    |G_DRV| as the inertias do), each with what the drivetrain would make of it. The listing is
    the screen's, checked by the refit of each listed mechanism whose starts could explain
    something: none significant."""
    baseline = {"parameters": {}, "nrmse": {"fit": {}, "validation": {}}, "objective": 0.0}
    diagnosis = diagnose(reference, selections, baseline)
    assert diagnosis.adequate and not diagnosis.accepted
    refitted = {c.mechanisms[-1] for c in diagnosis.candidates}
    assert refitted <= set(diagnosis.indistinguishable)
    assert all(c.p_value >= 0.01 for c in diagnosis.candidates)
    assert {"asymmetric_play", "torque_sensor_gain"} <= set(diagnosis.indistinguishable)
    assert "cannot tell" in diagnosis.sentence() and "torque_sensor_gain" in diagnosis.sentence()
    # a check significant on the identifying runs whose held-out run does not follow (the blind
    # trial's case 22, a two-stage clutch): adequate, the mechanism neither named nor listed
    from dtid.identification.diagnosis.candidates import Candidate

    row = kernel_parameters(reference.as_array())
    scores = {"fit": {"r @ 5 N*m": 0.05}, "validation": {"r @ 2 N*m": 0.2}}
    refused = Candidate.tested(("clutch_two_stage",), row, scores, 24.0, 0.002, 2, -0.13, False)
    told = dataclasses.replace(diagnosis, candidates=(refused,))
    assert told.adequate and "clutch_two_stage" not in told.indistinguishable
    assert "clutch_two_stage fits the identifying runs significantly better" in told.sentence()
    assert "held-out NRMSE +13 %" in told.sentence()
    visible = {s.mechanism for s in diagnosis.screened if s.detectable(diagnosis.mismatch)}
    assert {"progressive_spring", "accessory_mode", "gearbox_drag"} <= visible
    # what each would cost if present: a sensor reading g_T = 1.15 times the torque lowers
    # |G_DRV| by that factor, which the drivetrain imitates exactly by scaling: every inertia
    # and stiffness 15 % larger (the modes and the mass ratios stay) and, as the same torque
    # then turns it 1/1.15 as far, every free play 13 % smaller (measured: J_sum +14.9 %, c12
    # +14.6, c23 +15.2, eps12 -13.2, eps23 -12.1; the flat friction and d12 trade instead)
    absorbed = {entry.mechanism: entry for entry in diagnosis.absorbed}
    assert set(absorbed) == set(diagnosis.indistinguishable)
    gain = absorbed["torque_sensor_gain"]
    assert gain.parameters == {"g_T": 1.15}
    for name in ("J_sum", "c12", "c23"):
        assert gain.shift[name] == pytest.approx(0.15, abs=0.015), name
    for name in ("eps12", "eps23"):
        assert gain.shift[name] == pytest.approx(1 / 1.15 - 1, abs=0.02), name
    assert abs(gain.shift["x1"]) < 0.01 and abs(gain.shift["x12"]) < 0.01
    # an asymmetric play only moves the play's centre: nothing for the drivetrain to imitate
    assert max(map(abs, absorbed["asymmetric_play"].shift.values())) < 0.02
    validate(diagnosis.as_dict(), "diagnosis")


def concealed(folder: Path, effect: str, duration: float = 20.0) -> Path:
    """The reference vehicle's test (5, 10, 2 N*m, seed 5) with a mechanism concealed by
    ``dtid simulate --effect``, written to ``folder``."""
    path = folder / "run.blf"
    command = ["simulate", str(path), "--amplitudes", "5", "10", "2"]
    command += ["--duration", f"{duration:g}", "--seed", "5", "--effect", effect]
    assert dtid(command) == 0
    return path


def test_a_concealed_asymmetric_play_is_listed_as_indistinguishable(tmp_path, reference):
    """The undetectable case, concealed: a DMF play 60 % wider in drive than in coast, in
    neutral, where no mean torque loads the DMF. Diagnosed at the truth's drivetrain the map
    finds nothing, nothing is named (a listed mechanism's refit, where one runs, is
    insignificant), and the asymmetry is listed among what these data can neither detect nor
    exclude, with the drivetrain unmoved by it."""
    from dtid.workflow import measured_tests

    path = concealed(tmp_path, "asymmetric_play:asym12=0.6")
    document = identification_document(path, reference)
    diagnosis = diagnose_document(measured_tests([path]), document)
    assert diagnosis.adequate and not diagnosis.accepted
    assert "asymmetric_play" in diagnosis.indistinguishable
    assert all(c.p_value >= 0.01 for c in diagnosis.candidates)
    assert "asymmetric_play" in diagnosis.sentence()
    absorbed = {entry.mechanism: entry for entry in diagnosis.absorbed}
    assert max(map(abs, absorbed["asymmetric_play"].shift.values())) < 0.02


@pytest.fixture(scope="module")
def dragged(tmp_path_factory) -> Path:
    """A recording with a gearbox drag concealed: 2 N*m against the housing at idle."""
    return concealed(tmp_path_factory.mktemp("concealed"), "gearbox_drag:d3=0.02")


@pytest.mark.slow
def test_a_concealed_gearbox_drag_is_named_refitted_and_improves_the_held_out_run(
    dragged, reference, tmp_path
):
    """The model without the drag (the truth's drivetrain) misses the recording; the drag is
    refitted from it and accepted, its coefficient within 25 %, the held-out 2 N*m run fits
    better, and its profile interval holds the truth. (The whole library on this recording:
    docs/diagnosis.md.)"""
    from dtid.workflow import measured_tests

    tests = measured_tests([dragged])
    document = identification_document(dragged, reference)
    diagnosis = diagnose_document(tests, document, mechanisms=("gearbox_drag",), profile_points=3)
    assert not diagnosis.adequate
    drag = diagnosis.accepted[0]
    assert drag.mechanisms == ("gearbox_drag",), diagnosis.sentence()
    assert drag.parameters()["d3"] == pytest.approx(0.02, rel=0.25)
    assert drag.p_value < 1e-6 and drag.validation_gain > 0.3
    assert "gearbox_drag" in diagnosis.sentence()
    assert not diagnosis.hints  # explained: no hint needed
    result = diagnosis.as_dict()
    validate(result, "diagnosis")
    assert result["verdict"]["mechanisms"][0] == "gearbox_drag"
    assert result["verdict"]["parameters"]["d3"] == pytest.approx(0.02, rel=0.25)
    assert [c["mechanism"] for c in result["candidates"]] == ["gearbox_drag"]
    # the profile interval of the last accepted model's drag holds the truth
    interval = result["verdict"]["intervals"]["d3"]
    assert interval["lower"] is not None and interval["lower"] <= 0.02, interval
    assert interval["upper"] is None or interval["upper"] >= 0.02, interval
    from dtid.identification.diagnosis.figure import plot_mismatch

    assert plot_mismatch(diagnosis, tmp_path / "drag.png").stat().st_size > 10_000


@pytest.fixture(scope="module")
def belted(tmp_path_factory) -> Path:
    """A recording with a belt-driven accessory concealed: 0.03 kg*m^2 on the crank through a
    130 N*m/rad belt (its mode near 10.5 Hz, inside the chirps' band)."""
    return concealed(tmp_path_factory.mktemp("concealed"), "accessory_mode:J4=0.03")


@pytest.mark.slow
def test_a_concealed_accessory_mode_is_found_at_its_own_resonance(belted, reference):
    """The mode family: the model without the accessory (the truth's drivetrain) misses an
    antiresonance-resonance pair near 10-12 Hz; among the mechanisms that stiffen, damp or add
    a mode, the accessory is named, its inertia, belt stiffness and damping within 10 % of the
    truth, and the held-out 2 N*m run fits better. (It needs the screen's magnitudes across the
    typical range: at its ends, 0.015 and 0.04, the mode is at 14.8 and 9.1 Hz, the screen's
    gain was 0 and the refit, gated to its start, left J4 at 0.)"""
    from dtid.workflow import measured_tests

    tests = measured_tests([belted])
    document = identification_document(belted, reference)
    library = ("progressive_spring", "clutch_two_stage", "quadratic_damping", "accessory_mode")
    diagnosis = diagnose_document(tests, document, mechanisms=library)
    assert not diagnosis.adequate
    located = [band for band in diagnosis.mismatch.bands if band.kind == "bins"]
    assert any(9.5 <= band.peak_hz <= 12.5 for band in located), located
    trends = [band for band in diagnosis.mismatch.bands if band.kind == "trend"]
    assert all(abs(band.excess_db) < 13.0 for band in trends), trends  # within the residual
    accessory = diagnosis.accepted[0]
    assert accessory.mechanisms == ("accessory_mode",), diagnosis.sentence()
    values = accessory.parameters()
    assert values["J4"] == pytest.approx(0.03, rel=0.1)
    assert values["c14"] == pytest.approx(130.0, rel=0.1)
    assert values["d14"] == pytest.approx(0.125, rel=0.1)
    assert accessory.p_value < 1e-6 and accessory.validation_gain > 0.3
    assert diagnosis.as_dict()["verdict"]["mechanisms"] == ["accessory_mode"]


BELTED_TRUTH = DrivetrainParameters(
    J1=0.149, J2=0.0709, J3=0.0262, c12=351.0, c23=100.0, d12=1.04, d23=0.332, Tc12=0.22,
    eps12=0.0209, eps23=0.0089, T_loss=14.05, K=0.918,
)  # fmt: skip
"""The blind trial's case 26 (rounded): its accessory's mode lies among the DMF's."""
BENT = BELTED_TRUTH.replace(
    J1=0.1735, J2=0.1106, J3=0.0083, c12=251.0, c23=17.3, d12=0.524, d23=0.0718, eps12=0.0,
    eps23=0.0129,
)  # fmt: skip
"""What the identification made of case 26 (eq. 17 0.44): the DMF's play closed, the gear
coupling four times too soft."""


def accessory_against(
    truth: DrivetrainParameters, bent: DrivetrainParameters, effect: Effects, duration_s: float
):
    """The paper's test (5, 10, 2 N*m chirps of ``duration_s``, seed 5) of ``truth`` with the
    accessory ``effect`` concealed, diagnosed with the accessory alone against ``bent`` (the
    basin an identification ended in): the accepted candidate, asserted to be the accessory."""
    plan = TestPlan(amplitudes_nm=(5.0, 10.0, 2.0), validation_nm=0.0, duration_s=duration_s)
    result = simulate(truth, plan, SimulationOptions(effects=effect), seed=5)
    tests = [MeasuredTest.from_data("belted", from_simulation(result), 0.25, VehicleData())]
    chosen = [("fit", identification_runs(tests)), ("validation", validation_runs(tests))]
    baseline = {"parameters": {}, "nrmse": {}, "objective": 0.0}
    diagnosis = diagnose(bent, chosen, baseline, mechanisms=["accessory_mode"])
    assert not diagnosis.adequate and diagnosis.accepted, diagnosis.sentence()
    assert diagnosis.accepted[0].mechanisms == ("accessory_mode",), diagnosis.sentence()
    return diagnosis.accepted[0]


@pytest.mark.slow
def test_an_accessory_mode_the_identification_bent_everything_around_is_found_identifying_again():
    """A 16 dB accessory mode (0.0386 kg*m^2 through 108 N*m/rad, 9.4 Hz) diagnosed against the
    basin the identification ended in: no refit from there explains it (before the
    re-identification the accessory's refit left J4 at 0 and nothing was named); identified
    again with the accessory in the model, the search finds it within 10 % and the held-out run
    fits better (the accessory's inertia within 25 %, its mode within 2 %)."""
    effect = Effects({"J4": 0.0386, "c14": 108.0, "d14": 0.176})
    accessory = accessory_against(BELTED_TRUTH, BENT, effect, duration_s=20.0)
    values = accessory.parameters()
    assert values["J4"] == pytest.approx(0.0386, rel=0.25)  # the issue's target
    # 20 s chirps trade J4 against c14 (-12 % both here); the accessory's own frequency holds
    assert np.sqrt(values["c14"] / values["J4"]) == pytest.approx(np.sqrt(108.0 / 0.0386), rel=0.02)
    assert accessory.p_value < 1e-6 and accessory.validation_gain > 0.3
    assert accessory.drivetrain().J1 == pytest.approx(BELTED_TRUTH.J1, rel=0.1)


ACCESSORY_TRUTH = DrivetrainParameters(
    J1=0.158, J2=0.085, J3=0.0270, c12=263.5, c23=87.8, d12=0.617, d23=0.390, Tc12=0.385,
    eps12=0.0127, eps23=0.0149, T_loss=11.48, K=0.989,
)  # fmt: skip
"""The blind trial's case 16 (rounded): a 7 dB accessory mode (13.4 Hz on a fixed
crank), above the DMF's."""
ACCESSORY_BENT = ACCESSORY_TRUTH.replace(
    J1=0.1872, J2=0.0424, J3=0.0658, c12=450.7, c23=185.8, d12=0.186, d23=0.756, Tc12=2.24,
    eps12=0.0089, eps23=0.0163,
)  # fmt: skip
"""What the identification made of case 16 (eq. 17 0.38): c12 +71 %, c23 +112 %, J2 halved."""


@pytest.mark.slow
def test_an_accessory_its_refit_names_gets_the_drivetrain_identified_again_around_it():
    """The accessory's refit from the basin the identification bent around it passes its test
    (before this, it was accepted there: J4 -21 %, J2 -64 %, c12 +194 %, held-out NRMSE -30 %);
    the accepted candidate is identified again with its mechanism and that model replaces the
    refit: the accessory within 10 %, the drivetrain's inertias and stiffnesses within 15 %
    (measured within 7.4 %), the held-out 2 N*m run's NRMSE more than halved (-70 %). 60 s
    chirps: on 20 or 40 s ones the refit already finds that basin."""
    effect = Effects({"J4": 0.0218, "c14": 155.0, "d14": 0.18})
    accessory = accessory_against(ACCESSORY_TRUTH, ACCESSORY_BENT, effect, duration_s=60.0)
    values = accessory.parameters()
    assert values["J4"] == pytest.approx(0.0218, rel=0.1)
    assert values["c14"] == pytest.approx(155.0, rel=0.1)
    drivetrain = accessory.drivetrain()
    for name in ("J1", "J2", "J3", "c12", "c23"):
        truth = getattr(ACCESSORY_TRUTH, name)
        assert getattr(drivetrain, name) == pytest.approx(truth, rel=0.15), name
    assert accessory.p_value < 1e-6 and accessory.validation_gain > 0.5


@pytest.mark.slow
def test_a_refit_the_held_out_run_does_not_follow_is_identified_again():
    """The blind trial's case 23 (`benchmarks/diagnosis_trial.py`: a random vehicle with its own
    idle loop, engine and noise; a 2.3 dB friction ring, Tc12_2 1.64 N*m beyond 0.0181 rad),
    simulated, identified and diagnosed as the trial does. The identification ends with the gear
    coupling off (c23 -36 %, eps23 +121 %); from there the ring's refit is significant (p 2e-6,
    Tc12_2 1.50) but the held-out 2 N*m run fits worse (NRMSE 0.078 -> 0.084, where the truth
    fits at 0.069), so before this version nothing was named (the two most visible candidates,
    an accessory and a second spring stage, were identified again instead). Identified again
    with the ring, it is named within 25 % and the held-out run fits better. Where the search
    ends follows the host's arithmetic (docs/accuracy.md), so this checks the product on one
    vehicle it did not make, not a rate."""
    from benchmarks.diagnosis_trial import run_case

    row = run_case(23, clean=0.25)  # the trial's default share of clean cases
    assert row["concealed"] == "friction_hysteresis"
    assert row["named"] == "friction_hysteresis", row
    assert abs(row["main_error"]) < 0.25
    assert row["validation_after"] < row["validation_before"]


@pytest.mark.slow
def test_a_mechanism_the_map_does_not_locate_is_named_by_its_refit():
    """The blind trial's case 3 (a random vehicle with its own idle loop, engine and noise; a
    quadratic DMF damping, d12_2 1.51 N*m*s^2/rad^2), simulated, identified and diagnosed as
    the trial does. The identification bends the DMF around it (c12 -55 %, d12 +141 %) and the
    map finds no band (global p 0.017), so before this version the verdict was "adequate", the
    damping listed as indistinguishable. Fitted in the truth's basin it explains the identifying
    runs at p = 1e-8 (`benchmarks/diagnosis_ceiling.py`): the map's omnibus test misses what
    the mechanism's directed one sees. The listed mechanisms are now checked by their refits,
    and this one is named within 25 % with the held-out run closer. Where the search ends
    follows the host's arithmetic (docs/accuracy.md): one vehicle, not a rate."""
    from benchmarks.diagnosis_trial import run_case

    row = run_case(3, clean=0.25)  # the trial's default share of clean cases
    assert row["concealed"] == "quadratic_damping"
    assert row["bands"] == 0 and row["named"] == "quadratic_damping", row
    assert not row["adequate"]
    assert abs(row["main_error"]) < 0.25
    assert row["validation_after"] < row["validation_before"]


@pytest.mark.slow
def test_a_second_stage_the_identification_made_one_stiff_spring_is_named():
    """The blind trial's case 27 (a random vehicle with its own idle loop, engine and noise; a
    progressive DMF spring, c12_2 348 N*m/rad from a knee at 0.0109 rad), simulated,
    identified and diagnosed as the trial does. The identification returns one stiff spring
    behind a wider play (c12 +163 %, eps12 +68 %); the map finds one band. Of the spring's
    polished starts, the one with the first stage at 110 N*m/rad fitted best by a hair (eq. 17
    0.0935 against 0.0946) and ended at a likelihood ratio of 12.5 (p 0.15), so before this
    version nothing was named; the runner-up, refined too, ends at 35 (p 1e-4) with the
    held-out run closer. Where the search ends follows the host's arithmetic
    (docs/accuracy.md): one vehicle, not a rate; the second stage's split from the first is
    what the 5 and 10 N*m runs determine least (its main parameter's error is in the trial's
    results)."""
    from benchmarks.diagnosis_trial import run_case

    row = run_case(27, clean=0.25)  # the trial's default share of clean cases
    assert row["concealed"] == "progressive_spring"
    assert row["named"] == "progressive_spring", row
    assert not row["adequate"]
    assert row["validation_after"] < row["validation_before"]


@pytest.fixture(scope="module")
def ringed(tmp_path_factory) -> Path:
    """A recording with a DMF friction ring concealed: 4.2 N*m more friction beyond 0.017 rad
    (off the screen's grid of magnitudes), 40 s chirps."""
    effect = "friction_hysteresis:Tc12_2=4.2,phi12_f=0.017"
    return concealed(tmp_path_factory.mktemp("concealed"), effect, duration=40.0)


@pytest.mark.slow
def test_a_concealed_friction_ring_is_named_against_the_damping_it_resembles(ringed, reference):
    """The friction family: the model without the ring (the truth's drivetrain) misses the
    10 N*m run near the DMF mode; against a quadratic damping (the other way the DMF's losses
    grow with the swing) and a progressive spring, the ring is named, its level and engagement
    angle within 25 % (measured: 4.79 N*m and 0.0180 rad here, 4.84 and 0.0186 on seed 6), and
    the held-out 2 N*m run fits better. (On 20 s chirps a ring of 3.5 N*m was named on one
    seed and on another absorbed by the base friction, Tc12 0.3 -> 1.67 N*m.)"""
    from dtid.workflow import measured_tests

    tests = measured_tests([ringed])
    document = identification_document(ringed, reference)
    library = ("friction_hysteresis", "quadratic_damping", "progressive_spring")
    diagnosis = diagnose_document(tests, document, mechanisms=library)
    assert not diagnosis.adequate
    assert diagnosis.mechanisms == ("friction_hysteresis",), diagnosis.sentence()
    ring = diagnosis.accepted[0]
    values = ring.parameters()
    assert values["Tc12_2"] == pytest.approx(4.2, rel=0.25)
    assert values["phi12_f"] == pytest.approx(0.017, rel=0.25)
    assert ring.p_value < 0.01 and ring.validation_gain > 0.1


@pytest.mark.slow
def test_a_second_stage_hidden_behind_a_stiffer_spring_is_listed_with_what_it_hides(reference):
    """A DMF spring of 250 N*m/rad with a second stage of 500 from a knee of 0.004 rad, the
    deflections of a 2, 5 and 10 N*m test past the knee, against the single spring it imitates
    there (750 N*m/rad behind a play 2 * 500 * 0.004 / 750 rad wider; blind trial cases 15, 19
    and 20 were identified so, c12 +173 to +233 %): the model explains the recordings, and the
    progressive spring is listed among what these data cannot tell from the drivetrain
    (before 2026-12-06 the screen, local, found a stage added on top of the stiff spring
    plainly visible and excluded it), with the softer first stage and narrower play behind the
    identified spring for a typical stage."""
    first, second, knee = 250.0, 500.0, 0.004
    truth = reference.replace(c12=first)
    plan = TestPlan(amplitudes_nm=(5.0, 10.0, 2.0), validation_nm=0.0, duration_s=20.0)
    options = SimulationOptions(effects=Effects({"c12_2": second, "knee12": knee}))
    data = from_simulation(simulate(truth, plan, options, seed=5))
    tests = [MeasuredTest.from_data("staged", data, 0.25, VehicleData())]
    runs = [("fit", identification_runs(tests)), ("validation", validation_runs(tests))]
    wider = truth.eps12 + 2 * second * knee / (first + second)
    single = truth.replace(c12=first + second, eps12=wider)
    baseline = {"parameters": {}, "nrmse": {"fit": {}, "validation": {}}, "objective": 0.0}
    diagnosis = diagnose(single, runs, baseline)
    assert diagnosis.adequate, diagnosis.sentence()
    assert "progressive_spring" in diagnosis.indistinguishable
    entry = next(a for a in diagnosis.absorbed if a.mechanism == "progressive_spring")
    stage, stage_knee = entry.parameters["c12_2"], entry.parameters["knee12"]
    behind = first + second - stage  # the first stage behind the identified spring
    assert entry.shift["c12"] == pytest.approx((first + second) / behind - 1)
    narrower = wider - 2 * stage * stage_knee / (first + second)
    assert entry.shift["eps12"] == pytest.approx(wider / narrower - 1)
    assert abs(entry.shift["J_sum"]) < 1e-12 and abs(entry.shift["c23"]) < 1e-12


@pytest.fixture(scope="module")
def clutched(tmp_path_factory) -> Path:
    """A recording with a two-stage clutch damper concealed: 200 N*m/rad more beyond 0.004 rad
    of twist (past the 0.012 rad play), 40 s chirps."""
    effect = "clutch_two_stage:c23_2=200,knee23=0.004"
    return concealed(tmp_path_factory.mktemp("concealed"), effect, duration=40.0)


@pytest.mark.slow
def test_a_clutch_stage_that_a_drivetrain_in_another_basin_fits_as_well_is_not_named(
    clutched, reference
):
    """The springs family, where it cannot be named: a drivetrain elsewhere in the gear
    coupling's valley fits as well as the stage. Nothing is named, and the verdict reports that
    drivetrain, which the map finds adequate, instead of an unexplained mismatch.

    Which drivetrain depends on the searches' path: on the host and packages before
    2026-11-29 the clutch's refit found the stage where it is (within 10 %) and beat the
    drivetrain refitted alone, and the drivetrain re-polished from the candidate's optimum with
    the stage off traded J3 for c23 (c23 80 -> 100 N*m/rad, J3 0.040 -> 0.018 kg*m^2); on
    today's (numpy 2.4.6, scipy 1.17.1) the drivetrain refitted alone stiffens the clutch (c23
    80 -> 277 N*m/rad) and explains the recordings, and the clutch's refit ends at c23_2 20
    (docs/diagnosis.md). Since J_sum's start value was corrected (2026-11-30) both at once: the
    stage at c23_2 210 (+5 %) with its knee at 0.0036 (-10.1 %: the knee's tolerance is 15 %,
    the stiffness's 10 %), and the drivetrain refitted alone at c23 174, J3 0.0295. Since the
    model replays the recording's own combustion variation (2026-11-30) the drivetrain refitted
    alone lies nearer the truth along the valley: J3 0.0342 (-14.5 %). With the tooth-timer
    reference (2026-12-01) the other basin no longer fits as well and the stage is named, where
    it is: the third outcome of the same path dependence, asserted as such."""
    from dtid.workflow import measured_tests

    tests = measured_tests([clutched])
    document = identification_document(clutched, reference)
    library = ("clutch_two_stage", "progressive_spring", "quadratic_damping")
    diagnosis = diagnose_document(tests, document, mechanisms=library)
    assert not diagnosis.adequate
    if diagnosis.accepted:
        named = diagnosis.accepted[0]
        assert named.mechanisms == ("clutch_two_stage",), diagnosis.sentence()
        assert named.parameters()["c23_2"] == pytest.approx(200, rel=0.1), named.parameters()
        assert named.parameters()["knee23"] == pytest.approx(0.004, rel=0.15), named.parameters()
        assert named.p_value < 0.01 and named.validation_gain > 0
        assert "clutch_two_stage" in diagnosis.sentence()
        return
    clutch = next(c for c in diagnosis.candidates if c.mechanisms == ("clutch_two_stage",))
    refitted = diagnosis.refitted
    assert refitted is not None and refitted.found.adequate, diagnosis.sentence()
    found_stage = clutch.parameters()["c23_2"] == pytest.approx(200, rel=0.1)
    if found_stage:  # the stage where it is, and a drivetrain that trades J3 for c23 as good
        assert clutch.parameters()["knee23"] == pytest.approx(0.004, rel=0.15)
        assert refitted.parameters.J3 < 0.9 * reference.J3  # the valley, not the truth
    else:  # the drivetrain took the stage into a stiffer clutch
        assert refitted.parameters.c23 > 1.5 * reference.c23, diagnosis.sentence()
    assert "explains the recordings" in diagnosis.sentence()


@pytest.mark.slow
def test_a_drivetrain_short_of_its_best_fit_is_refitted_not_explained_by_physics(
    recording, reference
):
    """A clean recording diagnosed against an identification whose DMF stiffness is 30 % off:
    the map misses it, no mechanism is accepted, and the drivetrain refitted alone (the
    candidates' own baseline) explains the recordings with c12 back within 5 % of the truth;
    the verdict says so instead of calling the mismatch unexplained."""
    from dtid.workflow import measured_tests

    document = identification_document(recording, reference, c12=1.3 * reference.c12)
    library = ("gearbox_drag", "quadratic_damping")
    diagnosis = diagnose_document(measured_tests([recording]), document, mechanisms=library)
    assert not diagnosis.adequate and not diagnosis.accepted
    refitted = diagnosis.refitted
    assert refitted is not None and refitted.found.adequate
    assert refitted.parameters.c12 == pytest.approx(reference.c12, rel=0.05)
    assert "c12" in refitted.changes()
    assert "ended short of the best fit" in diagnosis.sentence(), diagnosis.sentence()
    result = diagnosis.as_dict()
    validate(result, "diagnosis")
    assert result["verdict"]["drivetrain_refit"]["adequate"] is True


def test_a_better_drivetrain_found_beside_a_mechanism_is_not_credited_to_it(selections, reference):
    """A search that missed (the DMF play 30 % off) against a candidate whose mechanism does
    nothing (a gearbox drag of 1e-6 N*m*s/rad) but whose drivetrain is the truth: the plain test
    credits the mechanism with the better drivetrain (p < 0.01, the held-out run improves);
    re-polished from the candidate's own drivetrain with the drag off, the model before it fits
    as well, and the candidate is refused."""
    from dtid.identification.diagnosis.refit import Refit
    from dtid.simulator.mechanisms import EXTRA_INDEX, kernel_parameters

    missed = reference.replace(eps12=1.3 * reference.eps12)
    refit = Refit(missed, selections[0][1], selections[1][1], prior=reference)
    row = kernel_parameters(reference.as_array())
    row[EXTRA_INDEX["d3"]] = 1e-6
    plain = refit.test(("gearbox_drag",), row, kernel_parameters(missed.as_array()), k=1)
    assert plain.accepted and plain.p_value < 1e-6
    guarded = refit.against_own_null(plain, (), tried=1)
    assert not guarded.accepted
    assert guarded.statistic < plain.statistic and guarded.p_value > 0.01


def test_a_parameter_identified_at_zero_has_no_relative_shift(selections, reference):
    """A friction identified at its bound 0 leaves the absorbed mechanism's relative shifts
    without it (the blind trial's case 3 divided by it), the others as usual."""
    from dtid.identification.diagnosis.refit import Refit
    from dtid.simulator.mechanisms import BY_NAME, kernel_parameters

    frictionless = reference.replace(Tc12=0.0)
    refit = Refit(frictionless, dict(selections)["fit"])
    entry = refit.absorbed(
        BY_NAME["torque_sensor_gain"], kernel_parameters(frictionless.as_array())
    )
    assert "Tc12" not in entry.shift
    assert entry.shift["J_sum"] == pytest.approx(0.15, abs=0.015)


def test_a_candidate_without_a_held_out_run_is_written_as_strict_json() -> None:
    """A diagnosis of recordings whose validation run was refused has no held-out figure: the
    JSON carries null there (its schema allows it), not a NaN strict JSON refuses."""
    from dtid.identification.diagnosis.candidates import Candidate
    from dtid.identification.diagnosis.imbalance import StrokeTest
    from dtid.simulator.parameters import reference_parameters

    row = kernel_parameters(reference_parameters().as_array())
    scores = {"fit": {"a.blf @ 10 N*m": 0.1}}
    candidate = Candidate.tested(("torque_lag",), row, scores, 80.0, 1e-9, 1, np.nan, True, "eng")
    strokes = StrokeTest(0.02, 0.01, 0.3, {"a.blf": 2}, {"a.blf": [1.0] * 4}, np.nan)
    for entry in (candidate.as_dict(), strokes.as_dict()):
        assert entry["validation_gain"] is None
        json.dumps(entry, allow_nan=False)
