"""Speed of the identification's objective, eq. (17): the hot path of the search and profiles.

On the reference vehicle's default simulated recording (60 s chirps, 5 and 10 N*m identify,
each replayed from 3 s before it), times the objective as the search's stages call it: one
parameter set at a time (Nelder-Mead, the profiles' polish) and a population at once
(differential evolution), on 1, 2 and 4 model realizations. Each figure is split into the
simulator (:func:`dtid.simulator.simulate.replay_batch`) and the rest (cross-spectra, |G_DRV|,
NRMSE). Not a test: nothing is asserted.

    PYTHONPATH=. python benchmarks/bench_objective.py [--repeats 40]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dtid.identification.frf.closed_loop import DEFAULT_RESOLUTION_HZ
from dtid.identification.model import response as model_response
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.samples.testdata import from_simulation
from dtid.identification.search.objective import Objective
from dtid.identification.search.parameterization import (
    THETA_NAMES,
    Parameterization,
    theta_from_parameters,
)
from dtid.identification.search.runs import split_runs
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.simulate import simulate

POPULATION = 120
"""Parameter sets per batched call: the search's differential evolution population."""


def objective_of_reference() -> tuple[Objective, np.ndarray]:
    """Eq. (17) over the reference recording's 5 and 10 N*m runs, and the truth (normalised)."""
    reference = reference_parameters()
    data = from_simulation(simulate(reference, seed=100))
    measured = MeasuredTest.from_data("reference", data, DEFAULT_RESOLUTION_HZ)
    ident, _ = split_runs([measured])
    par = Parameterization.around(reference, measured.idle_torque_nm, reference.K)
    objective = Objective(
        par,
        [measured.model_test(ident[0])],
        [[measured.estimates[i].drv_db for i in ident[0]]],
    )
    theta = theta_from_parameters(reference)
    return objective, par.unit(np.array([[theta[n] for n in THETA_NAMES]]))[0]


def timed(objective: Objective, units: np.ndarray, repeats: int) -> tuple[float, float]:
    """Median wall time of one call, and of its simulator share, s."""
    simulator = model_response.replay_batch
    spent = [0.0]

    def counting(*args: object, **kwargs: object) -> object:
        start = time.perf_counter()
        try:
            return simulator(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - start

    model_response.replay_batch = counting
    try:
        objective(units[:1])  # compile and warm up
        calls, shares = [], []
        for _ in range(repeats):
            spent[0] = 0.0
            start = time.perf_counter()
            objective(units)
            calls.append(time.perf_counter() - start)
            shares.append(spent[0])
    finally:
        model_response.replay_batch = simulator
    return float(np.median(calls)), float(np.median(shares))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=40, help="calls per figure")
    args = parser.parse_args()
    objective, truth = objective_of_reference()
    rng = np.random.default_rng(0)
    population = np.clip(truth + 0.05 * rng.standard_normal((POPULATION, len(truth))), 0, 1)
    print("| call | realizations | wall per call | per parameter set | simulator share |")
    print("|---|---|---|---|---|")
    for realizations in (1, 2, 4):
        changed = objective.replacing(realizations=realizations)
        for label, units, repeats in (
            ("one set", truth[None], args.repeats),
            (f"{POPULATION} sets", population, max(3, args.repeats // 10)),
        ):
            wall, simulator = timed(changed, units, repeats)
            print(
                f"| {label} | {realizations} | {wall * 1e3:.1f} ms | "
                f"{wall / len(units) * 1e3:.2f} ms | {simulator / wall:.0%} |"
            )


if __name__ == "__main__":
    main()
