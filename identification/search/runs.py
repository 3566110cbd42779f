"""Which runs identify: the amplitude levels among the runs, the identification and validation
runs of each recording (the two largest amplitudes identify), and the engine gain K of eq. (24)
that the search holds."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence

import numpy as np

from dtid.errors import AnalysisError
from dtid.identification.model.test_setup import MeasuredTest

logger = logging.getLogger(__name__)


def engine_gain(tests: Sequence[MeasuredTest]) -> float:
    """Eq. (24): K as the mean of |G_ENG| over every run that has it.

    Each recording's K read stroke by stroke is reported beside it
    (:func:`dtid.identification.model.idle_loop.stroke_gain`, the identification JSON's
    ``idle_loop.engine_gain``): closer to the truth, but the search holds it only where eq.
    (24)'s is far from it (:func:`dtid.identification.gain_choice.held_gain` says why)."""
    gains = [e.engine_gain for t in tests for e in t.estimates if np.isfinite(e.engine_gain)]
    if not gains:
        raise AnalysisError(
            "no recording carries a torque request T_ecu the identification can use (none is "
            "mapped, or it was left out: the warnings above say why), so K (eq. 24) cannot be "
            "measured; map the ECU's total torque request or fix K with --fix K=VALUE"
        )
    return float(np.mean(gains))


AMPLITUDE_MATCH = 0.05
"""Runs whose amplitudes differ by at most this fraction are at one amplitude (the peak of a
sampled, quantised request varies a little from recording to recording)."""


def amplitude_levels(amplitudes: Iterable[float]) -> list[float]:
    """The distinct amplitudes among runs, ascending, N*m: runs within :data:`AMPLITUDE_MATCH`
    of a level's smallest are one level, given as their mean."""
    levels: list[list[float]] = []
    for amplitude in sorted(amplitudes):
        if levels and amplitude <= (1 + AMPLITUDE_MATCH) * levels[-1][0]:
            levels[-1].append(amplitude)
        else:
            levels.append([amplitude])
    return [float(np.mean(level)) for level in levels]


def _at_level(amplitude: float, chosen: Sequence[float]) -> bool:
    """Whether a run's amplitude, N*m, is within :data:`AMPLITUDE_MATCH` of a chosen level."""
    return any(abs(amplitude - a) <= AMPLITUDE_MATCH * a for a in chosen)


def runs_at(test: MeasuredTest, levels: Sequence[float]) -> list[int]:
    """Indices of a recording's runs at any of the given amplitude levels, N*m."""
    return [i for i, e in enumerate(test.estimates) if _at_level(e.run.amplitude_nm, levels)]


def split_runs(
    tests: Sequence[MeasuredTest], identify_amplitudes: Sequence[float] | None = None
) -> tuple[list[list[int]], list[list[int]]]:
    """Indices of the identification and validation runs of each recording.

    By default the two largest amplitudes identify and the others validate (the paper: 5 and
    10 N*m identify, 2 N*m validates); amplitudes are levels (:func:`amplitude_levels`), so two
    recordings whose 10 N*m peaks read 9.998 and 10.000 N*m still identify from 5 and 10. A run
    without an FRF (:attr:`dtid.identification.model.test_setup.MeasuredTest.unusable`) counts in
    the choice of the amplitudes: at an identifying amplitude it is an error, else it is left out
    with a warning.

    Raises
    ------
    AnalysisError
        If no run identifies, or a run that should cannot give an FRF.
    """
    runs = [e.run for t in tests for e in t.estimates] + [r for t in tests for r, _ in t.unusable]
    levels = amplitude_levels(run.amplitude_nm for run in runs)
    chosen = list(identify_amplitudes) if identify_amplitudes else levels[-2:]
    ident, valid = [], []
    for test in tests:
        for run, reason in test.unusable:
            if _at_level(run.amplitude_nm, chosen):
                raise AnalysisError(
                    f"{test.name}: the {run.amplitude_nm:g} N*m run identifies but cannot give "
                    f"an FRF: {reason}"
                )
            logger.warning(
                "%s: the %g N*m run at %.1f s is left out of the validation: %s",
                test.name,
                run.amplitude_nm,
                run.start_s,
                reason,
            )
        picks = runs_at(test, chosen)
        ident.append(picks)
        valid.append([i for i in range(len(test.estimates)) if i not in picks])
    if not any(ident):
        raise AnalysisError(
            f"no chirp run has an amplitude among {', '.join(f'{a:g}' for a in chosen)} N*m"
        )
    return ident, valid
