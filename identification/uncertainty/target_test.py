"""Does a parameter's 95 % interval lie within a target? The likelihood-ratio test at its ends.

A campaign (:mod:`dtid.acquisition.campaign`) stops when every target is met, and a target is
met only where the recorded runs' 95 % interval confirms it
(:mod:`dtid.identification.planning.confirmation`). A whole profile answers that, and more than
that: it walks the parameter's box (five grid points, the bisection of both threshold
crossings, the neighbours' solutions offered to every point), each point a re-optimisation of
eq. (17) over every run recorded. Its cost grows with the campaign's runs: after the campaign
trial's second round (13 runs, truth 5; 2026-11-29) the worker's profiles took 44 minutes on a
2-core host, and a third round's would have passed the daemon's wait for the plan
(``[test] replan_wait_s``, an hour).

The question asked is narrower: is the interval within +-target of the estimate? For a
connected interval that is the likelihood-ratio test of the two values at the target's ends:
the interval lies within them exactly when both are rejected. So each targeted parameter is
re-optimised at those two values only (:func:`dtid.identification.uncertainty.profile.profile_at`
with that grid and no bisection: the same re-optimisation, statistic, Monte Carlo margin and
neighbours' smoothing as a profile), two points where a profile evaluates about thirteen.

Where an end is not rejected the target is not confirmed, and the next round is sized by how far
the interval reaches (:attr:`~dtid.identification.planning.confirmation.IntervalCheck.\
planning_target_percent`). So on such a side the test reaches further, each point twice as far
from the optimum as the last, up to :data:`EXPAND` times (eight times the target) or the bound,
until one is rejected; the crossing is read between the last two points as a profile reads it
(linear in the statistic's root). An extrapolation from the ends
alone (the statistic assumed quadratic beyond them) was tried first and read the gear play's
interval after the campaign trial's round 1 (truth 5) at 77 % where its profile said 17 %: a
statistic of a fraction of the threshold, less its Monte Carlo margin, is mostly noise, and the
free play's profile is far from quadratic; the next round planned on it took 26 minutes where the
profile's took 9. Beyond eight times the target the side is open (no factor to plan by). What the
test does not see: a second valley beyond a rejected end (a disjoint interval), which a whole
profile's grid sees only where a grid point falls into it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtid.identification.search.objective import Objective
from dtid.identification.uncertainty.profile import Profile, profile_at
from dtid.identification.uncertainty.statistic import THRESHOLD
from dtid.jsonfile import finite

EXPAND = 3
"""Doublings of an end's distance from the optimum on a side where it is not rejected: the
interval is followed to eight times the target."""


@dataclass(frozen=True)
class TargetTest:
    """The likelihood-ratio test of a parameter at the two ends of its target.

    Attributes
    ----------
    name
        Setup-4 parameter name.
    estimate
        The search's optimum, SI units.
    ends
        The values tested, SI units: the estimate less and plus the target's half-width, each
        clipped to the search's bounds (None: the estimate is at that bound, nothing to test).
    bounds
        The search's bounds, SI units.
    profile
        The profile the test read (the optimum, the ends and the points beyond an end not
        rejected): statistic, margin, and whether a point fitted better than the optimum
        (:attr:`~dtid.identification.uncertainty.profile.Profile.beats_estimate`).
    """

    name: str
    estimate: float
    ends: tuple[float | None, float | None]
    bounds: tuple[float, float]
    profile: Profile

    def _at(self, end: float | None) -> tuple[float, float]:
        """The statistic and its margin at an end (NaN where it was not tested)."""
        if end is None:
            return float("nan"), float("nan")
        i = int(np.argmin(np.abs(self.profile.values - end)))
        return float(self.profile.statistic[i]), float(self.profile.margin[i])

    @property
    def rejected(self) -> tuple[bool, bool]:
        """Whether each end is rejected at 95 % (its statistic above the threshold and the
        Monte Carlo margin)."""
        ends = (self._at(end) for end in self.ends)
        return tuple(bool(stat > THRESHOLD + margin) for stat, margin in ends)  # type: ignore[return-value]

    @property
    def confirmed(self) -> bool:
        """Whether both ends are rejected: the 95 % interval lies within the target."""
        return all(self.rejected)

    @property
    def interval(self) -> tuple[float | None, float | None]:
        """The 95 % interval, SI units: each side's crossing, read as a profile reads it, where
        the test found one (between the optimum and a rejected end, or beyond an end not
        rejected within :data:`EXPAND` doublings); None where it did not."""
        return self.profile.interval

    def as_dict(self) -> dict[str, object]:
        """The identification JSON's ``target_tests`` entry."""
        lower, upper = self.interval
        return {
            "estimate": self.estimate,
            "ends": list(self.ends),
            "rejected": list(self.rejected),
            "confirmed": self.confirmed,
            "interval": {"lower": lower, "upper": upper},
            "bounds": list(self.bounds),
            "values": self.profile.values.tolist(),
            "statistic": finite(self.profile.statistic),
            "margin": finite(self.profile.margin),
        }


def target_test(
    objective: Objective,
    measured_db: Sequence[np.ndarray],
    name: str,
    optimum_unit: np.ndarray,
    half_width: float,
    seed: int = 0,
    search_objective: Objective | None = None,
) -> TargetTest:
    """Test a parameter at the estimate less and plus ``half_width``.

    Parameters
    ----------
    objective, measured_db, name, optimum_unit, seed, search_objective
        As :func:`dtid.identification.uncertainty.profile.profile`.
    half_width
        The target's half-width, SI units of the parameter (positive).

    Raises
    ------
    ValueError
        If ``half_width`` is not positive.
    """
    if not half_width > 0.0:
        raise ValueError(f"the target's half-width of {name} must be positive, got {half_width}")
    par = objective.parameterization
    k = list(par.free).index(name)
    lowest, highest = par.bounds_of(name)
    span = highest - lowest
    estimate = lowest + float(optimum_unit[k]) * span
    ends = tuple(
        None if np.isclose(estimate, bound) else float(np.clip(value, lowest, highest))
        for value, bound in ((estimate - half_width, lowest), (estimate + half_width, highest))
    )
    grid = np.array([(end - lowest) / span for end in ends if end is not None])
    prof = profile_at(
        objective,
        measured_db,
        name,
        optimum_unit,
        grid,
        seed=seed,
        refine=0,
        search_objective=search_objective,
        expand=EXPAND,
    )
    return TargetTest(name, estimate, ends, (lowest, highest), prof)  # type: ignore[arg-type]
