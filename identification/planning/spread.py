"""Vehicles a prior stands for: a plan that must hold on each of them, not on the prior alone.

A prior is a guess (the reference vehicle for a car nobody has measured yet), and the
information a test gives about the friction and the free plays depends on their own values: a
friction half the prior's needs about four times the test (docs/planning.md, check 2). Planned
at the prior alone, a test can promise a precision that the vehicle then misses without
warning. So ``dtid plan`` also measures the information at vehicles drawn around the prior,
every drivetrain parameter within +-``spread`` of its value (a Latin hypercube: each
parameter's range is covered evenly however few vehicles are drawn), and the search asks the
targets of every one of them (a minimax design).

The draws are fixed by :data:`DRAW_SEED`: a plan is repeatable.
"""

from __future__ import annotations

from scipy.stats import qmc

from dtid.simulator.parameters import NAMES, DrivetrainParameters

DEFAULT_SPREAD_PERCENT = 40.0
"""Default half-width of a guessed prior's vehicles, % of each drivetrain parameter: a
passenger car's drivetrain within +-40 % of the reference's (the span of the identification
trial's random vehicles)."""
DEFAULT_VEHICLES = 8
"""Vehicles drawn around the prior by default (the prior itself comes on top): the worst of
eight independent draws exceeds about 89 % of the population's precisions on average."""
DRAW_SEED = 20261127
"""Seed of the Latin hypercube."""
DRIVETRAIN = tuple(name for name in NAMES if name not in ("T_loss", "K"))
"""The parameters drawn: inertias, stiffnesses, dampings, friction and free plays (the loss
torque and the engine gain are the operating point's, measured on the vehicle)."""


def spread_priors(
    prior: DrivetrainParameters, spread: float, count: int = DEFAULT_VEHICLES
) -> list[DrivetrainParameters]:
    """Drivetrains around a prior, each parameter uniformly within +-``spread`` of its value.

    Parameters
    ----------
    prior
        The centre.
    spread
        Relative half-width, 1 (0.4 for +-40 %); below 1.
    count
        Vehicles to draw.

    Returns
    -------
    list of DrivetrainParameters
        ``count`` drivetrains from a Latin hypercube seeded with :data:`DRAW_SEED`; their loss
        torque and engine gain are the prior's.

    Raises
    ------
    ValueError
        If ``spread`` is not in [0, 1) or ``count`` is negative.
    """
    if not 0.0 <= spread < 1.0:
        raise ValueError(f"the spread must be in [0, 1), not {spread}")
    if count < 0:
        raise ValueError(f"the number of vehicles must be >= 0, not {count}")
    if count == 0 or spread == 0.0:
        return []
    unit = qmc.LatinHypercube(d=len(DRIVETRAIN), seed=DRAW_SEED).random(count)
    factors = 1.0 - spread + 2.0 * spread * unit
    return [
        prior.replace(
            **{
                name: float(getattr(prior, name) * f)
                for name, f in zip(DRIVETRAIN, row, strict=True)
            }
        )
        for row in factors
    ]
