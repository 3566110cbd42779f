"""Section IV-A: what the frequency response says analytically about stiffness and free play.

An undamped spring c with a symmetric free play of total width eps, loaded by a sinusoidal torque
of amplitude A, deflects by A/c plus half the play on each side (eq. 20, Fig. 4). The linearised
stiffness a resonance shows is therefore

    c_lin = A / (A/c + eps/2)                                   (eq. 21)

(the paper writes eq. 21 with the play counted once; with eps the *total* width, as in eq. 7,
half of it adds to each side's amplitude). One amplitude leaves a one-parameter family of
(c, eps) pairs (eq. 22); two amplitudes fix both (eq. 23).

:func:`inseparable` applies that to an identification: which stiffnesses and free plays its
excitation cannot split, whatever their profiles show.
"""

from __future__ import annotations

from collections.abc import Iterable

from dtid.errors import AnalysisError

SPRING_AND_PLAY: tuple[tuple[str, str], ...] = (("c12", "eps12"), ("c23", "eps23"))
"""Each coupling's stiffness and free play (setup-4 names): the pairs eq. (22) ties together."""


def linearized_stiffness(c: float, eps: float, amplitude: float) -> float:
    """Eq. (21): stiffness seen at a torque amplitude, N*m/rad.

    Parameters
    ----------
    c
        Spring stiffness, N*m/rad.
    eps
        Total free-play width, rad.
    amplitude
        Torque amplitude across the spring, N*m.
    """
    return amplitude / (amplitude / c + eps / 2)


def free_play_for(c_lin: float, c: float, amplitude: float) -> float:
    """Eq. (22): the total free play that makes stiffness c look like c_lin at an amplitude, rad."""
    return 2 * (1 / c_lin - 1 / c) * amplitude


def stiffness_and_play(
    amplitude_1: float, c_lin_1: float, amplitude_2: float, c_lin_2: float
) -> tuple[float, float]:
    """Eq. (23): spring stiffness and total free play from two amplitudes.

    Parameters
    ----------
    amplitude_1, amplitude_2
        Torque amplitudes across the spring, N*m (different).
    c_lin_1, c_lin_2
        Linearised stiffnesses seen at them, N*m/rad.

    Returns
    -------
    tuple of float
        (c, N*m/rad; eps, rad).

    Raises
    ------
    AnalysisError
        If the amplitudes are equal or the stiffnesses do not grow with the amplitude as free
        play makes them (then the data cannot separate c from eps).
    """
    denominator = amplitude_1 * c_lin_2 - amplitude_2 * c_lin_1
    if amplitude_1 == amplitude_2 or denominator == 0:
        raise AnalysisError("stiffness and free play need two different amplitudes (eq. 23)")
    c = c_lin_1 * c_lin_2 * (amplitude_1 - amplitude_2) / denominator
    if not c > 0 or (c_lin_1 - c_lin_2) * (amplitude_1 - amplitude_2) < 0:
        raise AnalysisError(
            f"stiffnesses {c_lin_1:.4g} and {c_lin_2:.4g} N*m/rad at {amplitude_1:g} and "
            f"{amplitude_2:g} N*m do not soften towards the small amplitude as free play does"
        )
    return c, free_play_for(c_lin_1, c, amplitude_1)


def inseparable(free: Iterable[str], amplitude_levels: int) -> dict[str, str]:
    """The stiffnesses and free plays an excitation cannot split (eq. 22), with the reason.

    With fewer than two excitation amplitudes, a coupling whose stiffness and free play are both
    free is structurally non-identifiable in the paper's sense: for one sinusoid every (c*, eps*)
    of eq. (22) gives the same linearised stiffness. A chirp does narrow the family a little
    (the spring's deflection grows through the resonance, so one run sees more than one
    deflection amplitude), but only through the exact shape of the model's dead zone across the
    resonance: a progressive or multi-stage arc spring, which the model replaces by one
    stiffness, would move that answer. With one of the two fixed, the other is separable.

    Parameters
    ----------
    free
        Names of the free parameters (setup-4 names).
    amplitude_levels
        Number of distinct excitation amplitudes among the identification runs.

    Returns
    -------
    dict of str to str
        For each parameter that cannot be separated, why and what to do.
    """
    free = set(free)
    if amplitude_levels >= 2:
        return {}
    reasons = {}
    for spring, play in SPRING_AND_PLAY:
        if spring in free and play in free:
            reason = (
                f"{spring} and {play}: one excitation amplitude cannot split a stiffness from its "
                "free play (eq. 22); any interval rests on the model's dead-zone shape alone. "
                "Identify from two amplitudes (eq. 23) or fix one of the two."
            )
            reasons[spring] = reasons[play] = reason
    return reasons
