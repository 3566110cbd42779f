"""Vehicles a prior stands for: a plan that must hold on each of them, not on the prior alone.

A prior is a guess (the reference vehicle for a car nobody has measured yet), and the
information a test gives about the friction and the free plays depends on their own values: a
friction half the prior's needs about four times the test (docs/planning.md, check 2). Planned
at the prior alone, a test can promise a precision that the vehicle then misses without
warning. So ``dtid plan`` also measures the information at vehicles drawn around the prior,
every drivetrain parameter within +-``spread`` of its value (a Latin hypercube: each
parameter's range is covered evenly however few vehicles are drawn), and the search asks the
targets of every one of them (a minimax design). A follow-up test, planned at what a first test
identified, spreads each parameter by what the first test leaves open (:data:`RECORDED`), and
along the directions it leaves open: the errors a test leaves are correlated (the paper's test
at the reference: d12 with the friction -0.93, c12 with the DMF play +0.85, the mass ratio x12
with c23 -0.72), so vehicles drawn independently per parameter include many the first test
has already ruled out (a high d12 with a high friction) and too few along the valley it left.

The draws are fixed by :data:`DRAW_SEED`: a plan is repeatable.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
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
MAX_SPREAD = 0.9
"""Largest relative half-width a parameter is drawn within (it stays positive)."""
RECORDED = "recorded"
"""``spread`` that asks for each parameter's own:
:data:`~dtid.identification.planning.design.SIGMAS` times the relative precision
the runs recorded so far reach (a follow-up test: the vehicles those runs cannot tell from the
identified one), up to :data:`MAX_SPREAD`."""


def half_widths(spread: float | Mapping[str, float]) -> dict[str, float]:
    """Each drawn parameter's relative half-width: one for all, or by name (missing: 0).

    Raises
    ------
    ValueError
        If a half-width is not in [0, :data:`MAX_SPREAD`] or a name is not a drivetrain
        parameter.
    """
    if isinstance(spread, Mapping):
        unknown = set(spread) - set(DRIVETRAIN)
        if unknown:
            raise ValueError(f"no drivetrain parameter {sorted(unknown)[0]!r} to spread")
        widths = {name: float(spread.get(name, 0.0)) for name in DRIVETRAIN}
    else:
        widths = dict.fromkeys(DRIVETRAIN, float(spread))
    bad = [f"{n} {w:g}" for n, w in widths.items() if not 0.0 <= w <= MAX_SPREAD]
    if bad:
        raise ValueError(f"the spread must be in [0, {MAX_SPREAD:g}], not {bad[0]}")
    return widths


def describe(widths: Mapping[str, float]) -> str:
    """``+-40 %`` for one half-width, ``+-3-90 % by parameter`` for several."""
    values = sorted({round(100.0 * w, 1) for w in widths.values()})
    if len(values) == 1:
        return f"+-{values[0]:g} %"
    return f"+-{values[0]:g}-{values[-1]:g} % by parameter"


def spread_priors(
    prior: DrivetrainParameters,
    spread: float | Mapping[str, float],
    count: int = DEFAULT_VEHICLES,
    correlation: np.ndarray | None = None,
) -> list[DrivetrainParameters]:
    """Drivetrains around a prior, each parameter spread by its half-width about its value:
    uniformly within it and independently, or correlated as ``correlation`` says.

    With a correlation matrix R, each vehicle's relative offsets are the half-widths times
    R^(1/2) u, u a Latin hypercube point in [-1, 1]^d and R^(1/2) R's symmetric square root:
    every offset has the variance of the independent draw's (a third of its half-width
    squared) and the offsets correlate as R; R = I gives the independent draw. An offset may then
    exceed its half-width (up to the sum of its row of R^(1/2)) but is cut at
    :data:`MAX_SPREAD`.

    Parameters
    ----------
    prior
        The centre.
    spread
        Relative half-width, 1 (0.4 for +-40 %), for every drivetrain parameter or by name
        (:func:`half_widths`).
    count
        Vehicles to draw.
    correlation
        (d, d) correlation between the relative offsets of the :data:`DRIVETRAIN` parameters,
        in that order (symmetric, positive semi-definite, ones on the diagonal); None for
        independent draws.

    Returns
    -------
    list of DrivetrainParameters
        ``count`` drivetrains from a Latin hypercube seeded with :data:`DRAW_SEED`; their loss
        torque and engine gain are the prior's. Empty when every half-width is 0.

    Raises
    ------
    ValueError
        If a half-width is out of range (:func:`half_widths`), ``count`` is negative or
        ``correlation`` is not a correlation matrix of the drivetrain parameters.
    """
    widths = np.array(list(half_widths(spread).values()))
    if count < 0:
        raise ValueError(f"the number of vehicles must be >= 0, not {count}")
    if count == 0 or not widths.any():
        return []
    unit = 2.0 * qmc.LatinHypercube(d=len(DRIVETRAIN), seed=DRAW_SEED).random(count) - 1.0
    if correlation is not None:
        unit = unit @ square_root(correlation)  # symmetric: row @ R^(1/2) = (R^(1/2) u)^T
    factors = np.clip(1.0 + widths * unit, 1.0 - MAX_SPREAD, 1.0 + MAX_SPREAD)
    return [
        prior.replace(
            **{
                name: float(getattr(prior, name) * f)
                for name, f in zip(DRIVETRAIN, row, strict=True)
            }
        )
        for row in factors
    ]


def square_root(correlation: np.ndarray) -> np.ndarray:
    """The symmetric square root of a correlation matrix of the :data:`DRIVETRAIN` parameters
    (its eigenvalues' rounding below zero cut to zero).

    Raises
    ------
    ValueError
        If it is not a symmetric (d, d) matrix with ones on its diagonal.
    """
    matrix = np.asarray(correlation, dtype=float)
    size = len(DRIVETRAIN)
    if (
        matrix.shape != (size, size)
        or not np.allclose(matrix, matrix.T)
        or not np.allclose(np.diagonal(matrix), 1.0)
    ):
        raise ValueError(
            f"the correlation must be a symmetric {size} x {size} matrix with ones on its "
            f"diagonal, ordered as {', '.join(DRIVETRAIN)}"
        )
    values, vectors = np.linalg.eigh(matrix)
    return (vectors * np.sqrt(np.maximum(values, 0.0))) @ vectors.T
