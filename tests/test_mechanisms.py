"""The mechanism library (dtid.simulator.mechanisms) in the kernel: neutral values give the
paper's plant bit for bit, and each term does what its physics says, checked against closed
forms; the command line conceals them and names a wrong one clearly."""

from __future__ import annotations

import numpy as np
import pytest

from dtid.acquisition.plan import TestPlan
from dtid.cli import main as dtid
from dtid.errors import ConfigError
from dtid.simulator.controller import IdleController
from dtid.simulator.couplings import backlash_torque, second_stage_torque
from dtid.simulator.kernel import _torques
from dtid.simulator.mechanisms import (
    BY_NAME,
    EXTRA_INDEX,
    KERNEL_WIDTH,
    MECHANISMS,
    NEUTRAL,
    Effects,
    behind_imitation,
    kernel_parameters,
    parse_effect,
)
from dtid.simulator.parameters import INDEX, NAMES
from dtid.simulator.simulate import SimulationOptions, simulate

IDLE = TestPlan(amplitudes_nm=(0.01,), validation_nm=0.0, duration_s=4.0, settle_s=4.0)
"""Almost no excitation: the plant idles at its set-point."""


def run(reference, plan=IDLE, closed_loop=True, **effects: float):
    controller = IdleController(closed_loop=closed_loop)
    options = SimulationOptions.clean(effects=Effects(effects), controller=controller)
    return simulate(reference, plan, options, seed=2)


def test_every_parameter_has_one_slot_and_a_neutral_value_inside_its_bounds():
    names = [p.name for m in MECHANISMS for p in m.parameters]
    assert len(names) == len(set(names)) == KERNEL_WIDTH - len(NAMES)
    assert sorted(EXTRA_INDEX.values()) == list(range(len(NAMES), KERNEL_WIDTH))
    for mechanism in MECHANISMS:
        assert mechanism.physics.endswith(".")
        for p in mechanism.parameters:
            assert p.lower <= p.neutral <= p.upper, p
            assert p.lower <= p.typical[0] < p.typical[1] <= p.upper, p
    assert {m.name for m in MECHANISMS} == {
        "progressive_spring",
        "asymmetric_play",
        "friction_hysteresis",
        "quadratic_damping",
        "clutch_two_stage",
        "gearbox_drag",
        "accessory_mode",
        "torque_lag",
        "torque_sensor_gain",
        "cylinder_imbalance",
    }


def test_neutral_mechanisms_are_the_papers_plant_bit_for_bit(reference):
    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=10.0)
    plain = simulate(reference, plan, SimulationOptions(), seed=3)
    neutral = {p.name: p.neutral for m in MECHANISMS for p in m.parameters}
    given = simulate(reference, plan, SimulationOptions(effects=Effects(neutral)), seed=3)
    np.testing.assert_array_equal(plain.speed_rpm, given.speed_rpm)
    np.testing.assert_array_equal(plain.mean_torque_nm, given.mean_torque_nm)
    np.testing.assert_array_equal(kernel_parameters(reference.as_array())[12:], NEUTRAL)


def test_torque_sensor_gain_scales_the_measurement_and_nothing_else(reference):
    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=10.0)
    plain, scaled = run(reference, plan), run(reference, plan, g_T=1.1)
    np.testing.assert_array_equal(plain.speed_rpm, scaled.speed_rpm)
    np.testing.assert_allclose(scaled.mean_torque_nm, 1.1 * plain.mean_torque_nm, rtol=1e-12)


def test_cylinder_imbalance_gives_the_first_cylinder_its_share(reference):
    share = 0.2
    result = run(reference, closed_loop=False, share=share)  # no loop reacting to the half order
    late = result.torque_t > 3.0
    torque, cylinder = result.mean_torque_nm[late], result.cylinder[late]
    first = torque[cylinder == 0].mean()
    others = torque[cylinder != 0].mean()
    assert first / others == pytest.approx((1 + share) / (1 - share / 3), rel=0.01)
    even = run(reference, closed_loop=False)
    assert torque.mean() == pytest.approx(even.mean_torque_nm[even.torque_t > 3.0].mean(), rel=0.01)


def test_gearbox_drag_preloads_the_clutch_by_drag_over_stiffness(reference):
    """At idle the drag d3 * w3 passes through the clutch: its twist is that over c23, beyond
    half the gear play (the backlash rests on its stop)."""
    d3 = 0.02
    result = run(reference, d3=d3)
    late = result.speed_t > 6.0
    w3 = result.speed_rpm[late].mean() * np.pi / 30
    expected = reference.eps23 / 2 + d3 * w3 / reference.c23
    assert result.delta23_rad[late].mean() == pytest.approx(expected, rel=0.02)
    free = run(reference)
    assert abs(free.delta23_rad[free.speed_t > 6.0].mean()) < 0.2 * expected


def test_second_stage_adds_its_stiffness_beyond_the_knee():
    assert second_stage_torque(0.005, 600.0, 0.008) == 0.0
    assert second_stage_torque(0.010, 600.0, 0.008) == pytest.approx(600.0 * 0.002)
    assert second_stage_torque(-0.010, 600.0, 0.008) == pytest.approx(-600.0 * 0.002)
    assert second_stage_torque(0.5, 0.0, 0.008) == 0.0


def dmf_torque(
    delta12: float,
    rate12: float = 0.0,
    *,
    c12: float = 300.0,
    half12: float = 0.01,
    asym12: float = 0.0,
    c12_2: float = 0.0,
    knee12: float = 0.0,
    d12_2: float = 0.0,
) -> float:
    """The DMF torque of the kernel's force law, N*m: J2's smooth torque with the gear coupling
    and the belt absent and no viscous damping."""
    dmf = (c12, 0.0, half12, asym12 * half12, c12_2, knee12, d12_2)
    rest = (0.0,) * 8  # c23, d23, half23, c23_2, knee23, d3, c14, d14
    return _torques(0.0, delta12, 0.0, 0.0, 0.0, rate12, 0.0, 0.0, 0.0, (*dmf, *rest))[1]


def test_asymmetric_play_moves_the_stops_and_keeps_the_total_width():
    """asym12 = 0.5 with eps12/2 = 0.01 rad: the drive stop at 0.015 rad, the coast stop at
    -0.005 rad (widths 0.01 (1 +- 0.5)); beyond each the arc spring's c12 times the overshoot."""
    assert dmf_torque(0.0149, asym12=0.5) == 0.0
    assert dmf_torque(0.020, asym12=0.5) == pytest.approx(300.0 * 0.005)
    assert dmf_torque(-0.0049, asym12=0.5) == 0.0
    assert dmf_torque(-0.010, asym12=0.5) == pytest.approx(-300.0 * 0.005)
    assert dmf_torque(-0.010, asym12=-0.5) == 0.0  # mirrored: the coast side is the wide one
    assert dmf_torque(0.020, asym12=0.0) == pytest.approx(300.0 * 0.010)


def test_progressive_spring_adds_its_stage_beyond_play_and_knee_on_both_sides():
    """Play 0.01 rad each side, knee 0.008 rad beyond it: at 0.03 rad the first stage carries
    c12 * 0.02 and the second c12_2 * 0.012; inside the knee the second stage is absent."""
    stage = {"c12_2": 600.0, "knee12": 0.008}
    assert dmf_torque(0.03, **stage) == pytest.approx(300.0 * 0.02 + 600.0 * 0.012)
    assert dmf_torque(-0.03, **stage) == pytest.approx(-(300.0 * 0.02 + 600.0 * 0.012))
    assert dmf_torque(0.017, **stage) == pytest.approx(300.0 * 0.007)
    with_asym = dmf_torque(0.035, asym12=0.5, **stage)  # the stage counts from the moved stop
    assert with_asym == pytest.approx(300.0 * 0.02 + 600.0 * 0.012)


def test_a_second_stage_acts_as_a_stiffer_spring_behind_a_wider_play_beyond_its_knee(reference):
    """One DMF spring of 900 N*m/rad behind a half-play of 0.01 + 600 * 0.008 / 900 rad is,
    beyond the knee and on both sides, the two-stage spring ``behind_imitation`` finds behind
    it for a stage of 600 from a knee of 0.008 rad: c12 300 behind a half-play of 0.01 rad;
    inside the knee it is not. The clutch's second stage likewise with its backlash on a stop.
    Behind a spring softer than the stage there is no first stage."""
    mechanism = BY_NAME["progressive_spring"]
    half = 0.01 + 600.0 * 0.008 / 900.0
    single = kernel_parameters(reference.replace(c12=900.0, eps12=2 * half).as_array())
    two = behind_imitation(mechanism, single, 600.0, 0.008)
    assert two is not None
    assert two[INDEX["c12"]] == pytest.approx(300.0)
    assert two[INDEX["eps12"]] == pytest.approx(0.02)
    assert (two[EXTRA_INDEX["c12_2"]], two[EXTRA_INDEX["knee12"]]) == (600.0, 0.008)
    stage = {"c12_2": 600.0, "knee12": 0.008}
    for delta in (0.025, -0.04):
        assert dmf_torque(delta, half12=half, c12=900.0) == pytest.approx(
            dmf_torque(delta, **stage)
        )
    assert dmf_torque(0.015, half12=half, c12=900.0) != pytest.approx(dmf_torque(0.015, **stage))
    assert behind_imitation(mechanism, single, 1000.0, 0.008) is None

    clutch = BY_NAME["clutch_two_stage"]
    half23 = 0.006 + 200.0 * 0.004 / 280.0
    single = kernel_parameters(reference.replace(c23=280.0, eps23=2 * half23).as_array())
    two = behind_imitation(clutch, single, 200.0, 0.004)
    assert two is not None
    assert (two[INDEX["c23"]], two[INDEX["eps23"]]) == pytest.approx((80.0, 0.012))
    for delta in (0.02, -0.03):  # the backlash on its stop, delta's side
        staged = backlash_torque(
            delta, 0.0, np.copysign(0.006, delta), 80.0, 0.0, 0.006, 200.0, 0.004
        )
        one = backlash_torque(delta, 0.0, np.copysign(half23, delta), 280.0, 0.0, half23)
        assert one == pytest.approx(staged)


def test_quadratic_damping_adds_the_square_of_the_relative_speed_against_it():
    """d12_2 * w12 * |w12| at 4 rad/s with d12_2 = 1.5: 24 N*m, opposing the motion."""
    assert dmf_torque(0.0, 4.0, d12_2=1.5) == pytest.approx(24.0)
    assert dmf_torque(0.0, -4.0, d12_2=1.5) == pytest.approx(-24.0)
    assert dmf_torque(0.0, 4.0) == 0.0


def test_friction_hysteresis_is_the_plain_friction_short_of_its_angle_and_the_sum_beyond(
    reference,
):
    """A friction ring that never engages (phi12_f beyond the test's largest deflection, 0.054
    rad) leaves the plant bit for bit; one engaged at every deflection (phi12_f = 0) is a DMF
    friction of Tc12 + Tc12_2 (but at delta12 = 0 exactly, where it is not beyond: within 1 %
    of the ring's effect); in between, the later the ring engages the less it changes."""
    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=6.0)
    plain = run(reference, plan)

    def change(result) -> float:  # over the samples both have (a run ends on a speed sample)
        n = min(len(result.speed_rpm), len(plain.speed_rpm))
        return float(np.sqrt(np.mean((result.speed_rpm[:n] - plain.speed_rpm[:n]) ** 2)))

    assert np.abs(plain.delta12_rad).max() < 0.1
    never = run(reference, plan, Tc12_2=3.0, phi12_f=0.1)
    np.testing.assert_array_equal(never.speed_rpm, plain.speed_rpm)
    always = run(reference, plan, Tc12_2=3.0, phi12_f=0.0)
    summed = run(reference.replace(Tc12=reference.Tc12 + 3.0), plan)
    n = min(len(always.speed_rpm), len(summed.speed_rpm))
    assert np.sqrt(np.mean((always.speed_rpm[:n] - summed.speed_rpm[:n]) ** 2)) < 0.01 * change(
        always
    )
    later = [change(run(reference, plan, Tc12_2=3.0, phi12_f=f)) for f in (0.01, 0.02, 0.04)]
    assert change(always) > later[0] > later[1] > later[2] > 0.0


def test_torque_lag_filters_the_delivered_torque_stroke_by_stroke(reference):
    """Open loop, clean: each stroke's torque moves from the last towards the prompt engine's by
    1 - exp(-stroke time / tau_m), which the same recurrence on the prompt run reproduces."""
    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=4.0, f1_hz=1.0)
    tau = 0.08
    lagged = run(reference, plan, closed_loop=False, tau_m=tau)
    prompt = run(reference, plan, closed_loop=False)
    n = min(len(lagged.torque_t), len(prompt.torque_t))
    stroke_s = np.diff(lagged.torque_t[:n], prepend=0.0)
    expected = np.empty(n)
    state = reference.T_loss
    for i in range(n):
        state += (prompt.mean_torque_nm[i] - state) * (1 - np.exp(-stroke_s[i] / tau))
        expected[i] = state
    late = lagged.torque_t[:n] > 1.0
    error = lagged.mean_torque_nm[:n][late] - expected[late]
    swing = np.ptp(prompt.mean_torque_nm[:n][late])
    assert np.sqrt(np.mean(error**2)) < 0.03 * swing
    assert np.sqrt(np.mean((lagged.mean_torque_nm[:n] - prompt.mean_torque_nm[:n])[late] ** 2)) > (
        0.1 * swing
    )


def test_accessory_mode_adds_a_mode_and_is_stable(reference):
    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=10.0)
    plain, belt = run(reference, plan), run(reference, plan, J4=0.03, c14=120.0, d14=0.1)
    assert np.isfinite(belt.speed_rpm).all()
    assert np.sqrt(np.mean((belt.speed_rpm - plain.speed_rpm[: len(belt.speed_rpm)]) ** 2)) > 0.5


def test_a_belt_stiffer_than_its_limit_moves_the_accessory_with_the_crank(reference):
    """An accessory whose belt mode lies above BELT_RIGID_HZ is the crank's inertia plus its
    own, bit for bit, and needs no more substeps than the plant without it (a refit passing
    J4 -> 0 at a finite belt stiffness asked for thousands); one just below the limit keeps
    its mode."""
    from dtid.simulator.couplings import BELT_RIGID_HZ, belt_is_rigid
    from dtid.simulator.simulate import substeps

    plan = TestPlan(amplitudes_nm=(10.0,), validation_nm=0.0, duration_s=4.0)
    c14 = 130.0
    limit = (2 * np.pi * BELT_RIGID_HZ) ** 2
    rigid_j4 = 0.9 * c14 / (limit - c14 / reference.J1)  # mode 5 % above the limit
    assert belt_is_rigid(reference.J1, rigid_j4, c14)
    assert not belt_is_rigid(reference.J1, 1.3 * rigid_j4, c14)
    belt = run(reference, plan, J4=rigid_j4, c14=c14, d14=0.125)
    lumped = run(reference.replace(J1=reference.J1 + rigid_j4), plan)
    np.testing.assert_array_equal(belt.speed_rpm, lumped.speed_rpm)
    controller = IdleController()
    plain = kernel_parameters(reference.as_array())
    row = plain.copy()
    row[[EXTRA_INDEX["J4"], EXTRA_INDEX["c14"]]] = 1e-6, c14
    assert substeps(row, controller) == substeps(plain, controller)
    flexible = run(reference, plan, J4=1.3 * rigid_j4, c14=c14, d14=0.125)
    assert np.isfinite(flexible.speed_rpm).all()


def test_effect_options_parse_and_refuse_clearly():
    assert parse_effect("gearbox_drag:d3=0.01") == {"d3": 0.01}
    values = parse_effect("progressive_spring")
    assert values["c12_2"] == 600.0 and values["knee12"] > 0
    for text, message in (
        ("rattle", "unknown mechanism"),
        ("gearbox_drag:c12=3", "is not k=v"),
        ("gearbox_drag:d3=x", "not a number"),
        ("gearbox_drag:d3=0.01,d3=0.02", "gives d3 twice"),  # the last one was taken
    ):
        with pytest.raises(ConfigError, match=message):
            parse_effect(text)
    with pytest.raises(ConfigError, match="outside"):
        Effects({"d3": 5.0})


def test_simulate_conceals_an_effect_and_refuses_an_unknown_one(tmp_path, capsys):
    path = tmp_path / "concealed.blf"
    command = ["simulate", str(path), "--duration", "5", "--amplitudes", "5"]
    assert dtid([*command, "--effect", "gearbox_drag:d3=0.01"]) == 0
    assert path.stat().st_size > 0
    assert dtid([*command, "--force", "--effect", "rattle"]) == 2
    assert "unknown mechanism 'rattle'" in capsys.readouterr().err
    twice = ["--effect", "gearbox_drag:d3=0.01", "--effect", "gearbox_drag:d3=0.02"]
    assert dtid([*command, "--force", *twice]) == 2
    assert "--effect gearbox_drag is given more than once" in capsys.readouterr().err
