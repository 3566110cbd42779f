"""Name a cylinder imbalance from the strokes' own torques, and put it in the model.

One cylinder delivering a different torque (``cylinder_imbalance``) adds a line at the firing
cycle's frequency to the mean torque and the speed. The mismatch map sees it only through the
FRF estimate, where the chirp passes that frequency: how the line adds to |G_ENG| depends on its
phase at that moment, so a band comes and goes with the recording (blind trial: one |G_ENG|
band at 2 or 5 N*m on two of three imbalanced vehicles, none on the third), and a share fitted
on |G_ENG| has nothing to hold on to. The strokes show it directly: each stroke's measured mean
torque over the request it took, grouped by its place in the firing order
(:mod:`dtid.identification.model.cylinder_spread`). On recordings that carry the ECU's torque
request:

1. **Test.** Each identifying run's strokes in :data:`BLOCKS` blocks of consecutive strokes;
   each block's share (:func:`dtid.identification.model.cylinder_spread.single_share`) with the
   cylinder at the place the recording's strokes show departing most, where the model puts it
   (:attr:`dtid.identification.model.idle_loop.IdleLoop.odd_stroke`). Student's t
   of the blocks' mean share (a block spans a few seconds: the chirp's alias of the cycle
   frequency correlates the strokes within a block, hardly across), two-sided, Sidak over the
   places each recording chose among. Its likelihood-ratio statistic is t^2.
2. **Held out.** The held-out runs' factors against the pattern the share predicts, on the
   place the model puts it (their recording's odd stroke, :attr:`dtid.identification.model.
   idle_loop.IdleLoop.odd_stroke`): ``validation_gain`` = 1 - RMS(factors - pattern) /
   RMS(factors - 1). Accepted when p < :data:`dtid.identification.diagnosis.refit.ACCEPT_P`
   and that gain is positive.
3. **Model.** The share goes into the model on the recording's own odd stroke
   (:attr:`dtid.identification.model.idle_loop.IdleLoop.odd_stroke`): the model's line then
   has the vehicle's phase. The drivetrain is refitted on |G_DRV| with the share held (as a
   refit's baseline, :meth:`dtid.identification.diagnosis.refit.Refit.refit`), and the mismatch
   map of that model is drawn again (on the trial's two vehicles with a band, the band goes;
   with the share on another stroke, the model made a band of its own). The other mechanisms
   are then tried on top of that model.

The test does not depend on the map: an imbalance too small to show in any FRF is still named
when the strokes show it, and an engine whose strokes show none is adequate whatever the map
says of the rest. Without the request on the bus the model is driven by the measured strokes,
which hold the cylinders' spread already: nothing to test or add.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from dtid.identification.diagnosis.bin_statistics import sidak
from dtid.identification.diagnosis.candidates import Candidate, Screened
from dtid.identification.diagnosis.refit import (
    ACCEPT_P,
    Extra,
    Refit,
    with_mechanism,
)
from dtid.identification.model.cylinder_spread import (
    one_cylinder,
    single_share,
    stroke_factors,
)
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import RunSelection
from dtid.jsonfile import json_number
from dtid.simulator.angle_grid import N_CYL
from dtid.simulator.mechanisms import BY_NAME

MECHANISM = BY_NAME["cylinder_imbalance"]
BLOCKS = 20
"""Blocks of consecutive strokes per identifying run (about 3 s each in a 60 s chirp)."""


@dataclass(frozen=True)
class StrokeTest:
    """What the strokes say of the cylinders.

    Attributes
    ----------
    share
        The one-cylinder share that fits the identifying runs' strokes, 1.
    standard_error
        Its standard error over the blocks, 1.
    p_value
        Two-sided, family-wise over the places chosen among (Sidak).
    places
        Per recording (by name), the place in the firing order of the odd cylinder.
    factors
        Per recording, each place's torque factor over its identifying strokes (mean 1).
    validation_gain
        The held-out runs' fall of RMS departure (step 2 of the module notes; NaN without
        held-out runs).
    """

    share: float
    standard_error: float
    p_value: float
    places: dict[str, int]
    factors: dict[str, list[float]]
    validation_gain: float

    @property
    def statistic(self) -> float:
        """The likelihood-ratio statistic, t^2."""
        return (self.share / self.standard_error) ** 2 if self.standard_error > 0 else 0.0

    @property
    def significant(self) -> bool:
        """Whether the cylinders differ (p < ACCEPT_P)."""
        return self.p_value < ACCEPT_P

    @property
    def accepted(self) -> bool:
        """Significant, and the held-out strokes closer to the pattern than to equal cylinders."""
        return self.significant and (np.isnan(self.validation_gain) or self.validation_gain > 0)

    def as_dict(self) -> dict[str, object]:
        """The diagnosis JSON's ``cylinders``."""
        return {
            "share": self.share,
            "standard_error": self.standard_error,
            "p_value": self.p_value,
            "places": self.places,
            "factors": self.factors,
            "validation_gain": json_number(self.validation_gain),  # null: no held-out run
            "significant": self.significant,
        }


def _strokes(test: MeasuredTest, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A run's strokes: numbers, measured torques and requests taken."""
    loop, run = test.loop, test.estimates[index].run
    inside = (loop.stroke_t >= run.start_s) & (loop.stroke_t <= run.end_s)
    return loop.stroke_number[inside], loop.stroke_torque_nm[inside], loop.stroke_request_nm[inside]


def _by_request(selection: RunSelection | None) -> bool:
    return selection is not None and all(t.loop.by_request for t in selection.tests)


def stroke_test(fit: RunSelection, validation: RunSelection | None) -> StrokeTest | None:
    """Steps 1 and 2 of the module notes; None when a recording lacks the ECU's request."""
    if not _by_request(fit):
        return None
    shares: list[np.ndarray] = []
    places: dict[str, int] = {}
    factors: dict[str, list[float]] = {}
    for test, runs in zip(fit.tests, fit.runs, strict=True):
        strokes = [_strokes(test, i) for i in runs]
        pooled = stroke_factors(*(np.concatenate(parts) for parts in zip(*strokes, strict=True)))
        place = test.loop.odd_stroke  # where the model puts it
        places[test.name], factors[test.name] = place, [float(f) for f in pooled[0]]
        for number, torque, request in strokes:
            blocks = stroke_factors(number, torque, request, BLOCKS)
            shares.append(np.array([single_share(b, place) for b in blocks]))
    values = np.concatenate(shares)
    values = values[np.isfinite(values)]
    if len(values) < 3:
        return None
    share = float(np.mean(values))
    error = float(np.std(values, ddof=1) / np.sqrt(len(values)))
    single = float(2 * stats.t.sf(abs(share) / error, len(values) - 1)) if error > 0 else 1.0
    p_value = sidak(single, N_CYL ** len(places))
    return StrokeTest(share, error, p_value, places, factors, _held_out(validation, share))


def _held_out(validation: RunSelection | None, share: float) -> float:
    """Step 2: the held-out runs' fall of RMS departure from the pattern the share predicts, on
    the place the model puts it (its recording's odd stroke)."""
    if not _by_request(validation):
        return float("nan")
    assert validation is not None
    pattern_miss, equal_miss = [], []
    for test, runs in zip(validation.tests, validation.runs, strict=True):
        for i in runs:
            factors = stroke_factors(*_strokes(test, i))[0]
            if not np.isfinite(factors).all():
                continue
            pattern_miss.append(factors - one_cylinder(share, test.loop.odd_stroke))
            equal_miss.append(factors - 1.0)
    if not equal_miss:
        return float("nan")
    equal = float(np.sqrt(np.mean(np.square(equal_miss))))
    return 1.0 - float(np.sqrt(np.mean(np.square(pattern_miss)))) / equal if equal > 0 else 0.0


def screen_strokes(test: StrokeTest) -> Screened:
    """The screen's entry: the top of the typical range in standard errors (what the strokes
    would show of it), against the t a p of ACCEPT_P needs; the share of the places' spread the
    fitted share explains."""
    top = MECHANISM.main.typical[1]
    visible = top / max(test.standard_error, 1e-12)
    explained = []
    for name, factors in test.factors.items():
        f = np.asarray(factors)
        miss = f - one_cylinder(test.share, test.places[name])
        spread = float(np.sum((f - 1.0) ** 2))
        explained.append(1.0 - float(np.sum(miss**2)) / spread if spread > 0 else 0.0)
    needed = float(stats.norm.isf(0.5 * (1.0 - (1.0 - ACCEPT_P) ** (1.0 / N_CYL))))
    return Screened(
        MECHANISM.name,
        float(visible),
        max(0.0, float(np.mean(explained))),
        test.share,
        frf="strokes",
        threshold=needed,
    )


def imbalance_candidate(refit: Refit, test: StrokeTest) -> Candidate:
    """Step 3's model, tested by steps 1 and 2: the model the refits extend with the share, and
    when accepted its drivetrain refitted on |G_DRV| with the share held (the identification
    bent it around the line: blind trial case 2 held the identified drivetrain with the share
    added at a held-out NRMSE of 0.122 where 0.091 without)."""
    row = with_mechanism(refit.start_row(), MECHANISM, test.share)
    if test.accepted:
        row, _ = refit.refit(Extra(refit.base, row, ()))
    return Candidate.tested(
        (*refit.held, MECHANISM.name),
        row,
        refit.run_nrmse(row),
        test.statistic,
        test.p_value,
        len(MECHANISM.parameters),
        test.validation_gain,
        test.accepted,
        frf="strokes",
    )


def imbalance_interval(test: StrokeTest) -> dict[str, object]:
    """95 % interval of the share from the blocks' standard error (their count is large: the
    normal quantile); both ends bounded, so ``practical`` in the intervals' terms."""
    half = float(stats.norm.isf(0.025)) * test.standard_error
    low, high = test.share - half, test.share + half
    return {MECHANISM.main.name: {"lower": low, "upper": high, "verdict": "practical"}}
