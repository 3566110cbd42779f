"""The cylinders' torque spread, read from the strokes' own mean torques.

A cylinder-pressure system reports each working stroke's mean torque; the strokes of one
cylinder recur every :data:`dtid.simulator.angle_grid.N_CYL` strokes. An engine whose cylinders
deliver unequal torques (``cylinder_imbalance``: one at 1 + share times the mean, the others at
1 - share / 3) shows it in the strokes' ratio of measured to requested torque, T_m / (K T_ecu),
grouped by the stroke's place in the firing order: the test chirp and the idle controller move
request and torque together, so the ratio holds little but the cylinders' factors, the
combustion variation and the sensor's noise (on the trial's vehicles each factor came out
within 0.1-0.2 % from a minute of strokes).

Strokes are numbered on the recording's crank-event grid (two events per stroke), so a lost
frame leaves a gap, not a shift of the numbering. Which cylinder a number belongs to is not
needed: the numbering modulo N_CYL is the firing order's place, the same for the model that
repeats the recording stroke by stroke (:meth:`dtid.identification.model.idle_loop.IdleLoop.
cylinder_offset`).
"""

from __future__ import annotations

import numpy as np

from dtid.simulator.angle_grid import N_CYL


def stroke_factors(
    number: np.ndarray, torque_nm: np.ndarray, request_nm: np.ndarray, blocks: int = 1
) -> np.ndarray:
    """Each place in the firing order's torque factor, per block of consecutive strokes.

    Parameters
    ----------
    number
        Each stroke's number on the recording's crank-event grid (its place in the firing order
        is ``number % N_CYL``).
    torque_nm
        Each stroke's measured mean torque, N*m.
    request_nm
        The request each stroke took, times K, N*m (any common factor cancels).
    blocks
        Blocks of consecutive strokes (equal counts) to estimate in separately.

    Returns
    -------
    numpy.ndarray
        (blocks, N_CYL): per block, each place's summed torque over its summed request,
        normalised to a mean of 1 over the places (NaN where a block lacks a place).
    """
    out = np.full((blocks, N_CYL), np.nan)
    for row, chosen in enumerate(np.array_split(np.arange(len(number)), blocks)):
        place = number[chosen] % N_CYL
        torque = np.bincount(place, torque_nm[chosen], N_CYL)
        request = np.bincount(place, request_nm[chosen], N_CYL)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.bincount(place, minlength=N_CYL) > 0, torque / request, np.nan)
        out[row] = ratio / np.mean(ratio)
    return out


def odd_place(factors: np.ndarray) -> int:
    """The place in the firing order whose factor departs most from the others' mean: where a
    one-cylinder imbalance acts (``factors``: (N_CYL,))."""
    others = (np.sum(factors) - factors) / (N_CYL - 1)
    return int(np.argmax(np.abs(factors - others)))


def one_cylinder(share: float, place: int) -> np.ndarray:
    """The factors (N_CYL,) of a ``cylinder_imbalance``: 1 + share at ``place``, 1 - share /
    (N_CYL - 1) elsewhere (mean 1)."""
    pattern = np.full(N_CYL, 1.0 - share / (N_CYL - 1))
    pattern[place] = 1.0 + share
    return pattern


def single_share(factors: np.ndarray, place: int) -> float:
    """The ``cylinder_imbalance`` share that fits ``factors`` (N_CYL,) best (least squares) with
    its cylinder at ``place``: the pattern :func:`one_cylinder`, whose departure there from the
    others' mean is s N_CYL / (N_CYL - 1)."""
    others = (np.sum(factors) - factors[place]) / (N_CYL - 1)
    return float((factors[place] - others) * (N_CYL - 1) / N_CYL)
