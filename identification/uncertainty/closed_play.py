"""A gear play the search found closed: is there an open play that fits better?

A closed gear play (eps23 at 0, the physical end of its box) with a high gear damping imitates
what an open play does to the gear mode's amplitude dependence, and the search's stage 2 reaches
that basin more easily than the open play's, whose gear block differs from it in every parameter
(and the DMF's block a little). Measured on drivetrains drawn around vehicle_1 of
../shared/independent (2026-12-07, ``benchmarks/identification_trial.py --truth 1 --sweep 0.5 20
--around ../shared/independent/vehicle_1/truth.toml``): the search ended at eq. (17) 0.0889
with the play closed, c23 +48 % and d23 +258 %, where the optimum nearest the truth (play open,
eps23 -4 %) fits at 0.0731; a profile of c23 found the open play's basin, one of eps23 did not
(its points stay near the closed basin's stiff coupling, 0.0855 at best).

So before a closed gear play is reported, the gear coupling's stiffness is held at
:data:`STIFFNESS_FACTORS` times the found value and everything else re-optimised as a profile's
point is (:func:`dtid.identification.uncertainty.profile.profile_at`, no bisection): two points
where a profile evaluates about thirteen, 5.6-7.0 s on two 60 s runs (docs/speed.md). A point
that fits significantly better than the search's optimum (``beats_estimate``) restarts the search
there, as a profile's would (:func:`dtid.identification.pipeline.identify_runs`). On that
truth: 0.0756 at half the stiffness (play open, c23 -26 % of the truth).

Where the profiles run (the default) the profile of c23 does this and more, so the check runs only
without it. A search that ends with the play open is untouched.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dtid.identification.search.objective import Objective
from dtid.identification.search.parameterization import EDGE_TOLERANCE, THETA_NAMES
from dtid.identification.uncertainty.profile import Profile, profile_at

STIFFNESS_FACTORS = (0.5, 1.5)
"""The gear coupling's stiffness is held at these multiples of the closed-play optimum's: the
open play's basin lay at 0.51 times it on the measured truth (module notes)."""


def play_closed(objective: Objective, optimum_unit: np.ndarray) -> bool:
    """Whether the search's optimum (normalised free values) closed a free gear play: eps23 within
    :data:`EDGE_TOLERANCE` of its box's width from a lower bound of 0, with c23 free too."""
    par = objective.parameterization
    if not {"c23", "eps23"} <= set(par.free):
        return False
    lower, upper = par.bounds_of("eps23")
    eps23 = _value(objective, optimum_unit, "eps23")
    return lower == 0.0 and eps23 <= EDGE_TOLERANCE * (upper - lower)


def _value(objective: Objective, unit: np.ndarray, name: str) -> float:
    """A setup-4 value (SI) of normalised free values."""
    return float(objective.parameterization.theta(unit[None])[0][THETA_NAMES.index(name)])


def closed_play_check(
    objective: Objective,
    measured_db: Sequence[np.ndarray],
    optimum_unit: np.ndarray,
    seed: int = 0,
    search_objective: Objective | None = None,
) -> Profile | None:
    """The gear coupling's stiffness re-optimised at :data:`STIFFNESS_FACTORS` times the optimum's,
    where the optimum closed the gear play (:func:`play_closed`); None otherwise.

    Parameters
    ----------
    objective, measured_db, optimum_unit, seed, search_objective
        As :func:`dtid.identification.uncertainty.profile.profile`.

    Returns
    -------
    Profile or None
        The two points' profile of ``c23``: its ``beats_estimate`` says whether an open play
        fitted significantly better, ``minimum_unit`` where.
    """
    if not play_closed(objective, optimum_unit):
        return None
    par = objective.parameterization
    lower, upper = par.bounds_of("c23")
    c23 = _value(objective, optimum_unit, "c23")
    grid = np.clip((c23 * np.array(STIFFNESS_FACTORS) - lower) / (upper - lower), 0.0, 1.0)
    return profile_at(
        objective,
        measured_db,
        "c23",
        optimum_unit,
        np.unique(grid),
        seed=seed,
        refine=0,
        search_objective=search_objective,
    )
