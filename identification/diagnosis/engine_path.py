"""Name a mechanism of the engine path from |G_ENG|: screen, fit and test it there.

A mechanism on the engine path (:attr:`dtid.simulator.mechanisms.Mechanism.path` ``"engine"``:
a torque lag) sits between the ECU's torque request and the mean torque the sensor measures.
|G_DRV| (eq. 14) is speed per *measured* torque, so it hardly sees such a mechanism, and what it
sees the drivetrain parameters absorb (``tests/test_diagnosis.py``: a 30 ms lag leaves no
|G_DRV| band); |G_ENG| (eq. 15), measured per *requested* torque, shows it, and the drivetrain
parameters do not shape |G_ENG|. A refit on |G_DRV| (:mod:`dtid.identification.diagnosis.refit`)
can therefore neither find nor test it. Here, on the recordings that carry the ECU's request:

1. **Screen.** The mechanism's effect on the identifying runs' |G_ENG| at the top of its typical
   range, less the one level the map moves the model by (K's: |G_ENG| is compared in shape,
   :mod:`dtid.identification.diagnosis.mismatch`), in units of the map's scatter: ``visible_z``
   is its largest |z|.
2. **Fit.** Its main parameter minimises the identifying runs' squared standardised |G_ENG|
   residual with the level free, the drivetrain held as identified: a batched grid over its
   search bounds (:meth:`dtid.simulator.mechanisms.Mechanism.search_bounds`), then a finer
   grid around the best. The level at the best is K's correction: eq. (24) reads K as
   |G_ENG|'s mean, which a lag lowers (0.45-0.54 for a true 0.9 at 60 ms on the reference
   drivetrain), and a model given the lag with that K delivers half the torque. The library's
   engine-path mechanisms have one parameter; a further one would be held at the middle of its
   typical range (:func:`dtid.identification.diagnosis.refit.with_mechanism`).
3. **Test.** The intervals' likelihood-ratio statistic
   (:func:`dtid.identification.uncertainty.statistic.statistic`) on |G_ENG| with each model's
   level removed, against the model without the mechanism, on fresh realizations
   (:data:`dtid.identification.diagnosis.refit.TEST_SEED`); F reference of nested models with
   the level counted as fitted; Sidak over the engine-path mechanisms tried. Accepted when
   p < :data:`dtid.identification.diagnosis.refit.ACCEPT_P` **and** the held-out runs' |G_ENG|
   RMS z falls (their level taken from the identifying runs).
4. **The drivetrain again.** With an accepted mechanism held in the model, the drivetrain's ten
   free parameters are refitted on |G_DRV| as a |G_DRV| refit would (:meth:`dtid.
   identification.diagnosis.refit.Refit.refit`: from the identified values and the prior's
   starts, a short evolution, then the search's last stages): the missing physics may have
   bent the identification far from the truth. The drivetrain before and after, and the model
   the |G_DRV| refits then start from.

At most one engine-path mechanism is accepted (the library has one).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from dtid.identification.diagnosis.bin_statistics import sidak
from dtid.identification.diagnosis.candidates import Candidate, Screened
from dtid.identification.diagnosis.mismatch import MismatchMap, RunResidual, shape_level
from dtid.identification.diagnosis.refit import (
    ACCEPT_P,
    TEST_REALIZATIONS,
    TEST_SEED,
    Extra,
    Refit,
    with_mechanism,
)
from dtid.identification.pipeline import RunSelection
from dtid.identification.uncertainty.profile import interval_and_verdict
from dtid.identification.uncertainty.statistic import independent_bins, nested_p_value, statistic
from dtid.simulator.mechanisms import BY_NAME, EXTRA_INDEX, Mechanism
from dtid.simulator.parameters import NAMES

GAIN = NAMES.index("K")
"""Kernel column of K."""
GRID = 17
"""Main-parameter values of each of the fit's two grids."""
INTERVAL_GRID = 41
"""Main-parameter values of the profile interval's grid."""


def engine_mechanisms(found: MismatchMap, allowed: Sequence[str]) -> list[Mechanism]:
    """The allowed mechanisms this module decides: those of the engine path, when the map has
    the identifying runs' |G_ENG| (recordings without the ECU's torque request leave them to
    the |G_DRV| refits)."""
    if not any(r.role == "fit" and r.frf == "eng" for r in found.residuals):
        return []
    return [BY_NAME[name] for name in allowed if BY_NAME[name].path == "engine"]


class EngineRuns:
    """The |G_ENG| of a selection's runs: measured, the map's scatter, and the model's.

    Parameters
    ----------
    refit
        The runs and the identified model.
    found
        The identified model's map (its |G_ENG| scatter standardises).
    role
        ``fit`` or ``validation``.
    """

    def __init__(self, refit: Refit, found: MismatchMap, role: str) -> None:
        self.refit = refit
        self.selection: RunSelection | None = refit.fit if role == "fit" else refit.validation
        mapped: dict[str, list[RunResidual]] = {}
        for r in found.residuals:  # in the selection's order
            if r.role == role and r.frf == "eng":
                mapped.setdefault(r.label, []).append(r)
        self.residuals: list[RunResidual] = []
        self.present: list[bool] = []  # per run of the selection: does it have |G_ENG|
        if self.selection is not None:
            for test, runs in zip(self.selection.tests, self.selection.runs, strict=True):
                for i in runs:
                    label = test.run_label(i)
                    found_runs = mapped.get(label, [])
                    self.present.append(bool(found_runs))
                    if found_runs:
                        self.residuals.append(found_runs.pop(0))

    def __bool__(self) -> bool:
        return bool(self.residuals)

    def model(
        self, rows: np.ndarray, realizations: int | None = None, seed: int | None = None
    ) -> list[np.ndarray]:
        """The model's |G_ENG| (n, bins) per run that has one, dB."""
        curves = self.refit.curves(rows, self.selection, realizations, seed, frf="eng")
        return [c for c, present in zip(curves, self.present, strict=True) if present]

    def level(self, model: Sequence[np.ndarray]) -> np.ndarray:
        """Per row of ``model``, the level (dB) that moves its curves closest to the measured
        (:func:`dtid.identification.diagnosis.mismatch.shape_level`, as the map's)."""
        return shape_level(
            [r.measured_db - m for r, m in zip(self.residuals, model, strict=True)],
            [r.scatter_db for r in self.residuals],
        )

    def z(self, model: Sequence[np.ndarray], level: np.ndarray) -> np.ndarray:
        """(n, bins) standardised residual of each row, its curves moved by ``level``."""
        return np.hstack(
            [
                (r.measured_db - m - level[:, None]) / r.scatter_db
                for r, m in zip(self.residuals, model, strict=True)
            ]
        )

    def cost(self, rows: np.ndarray) -> np.ndarray:
        """Squared standardised residual of each row, level free (NaN: the model did not idle)."""
        model = self.model(rows)
        z = self.z(model, self.level(model))
        return np.where(np.isfinite(z).all(axis=1), np.sum(np.nan_to_num(z) ** 2, axis=1), np.nan)


def screen_engine(refit: Refit, found: MismatchMap, mechanism: Mechanism) -> Screened:
    """Step 1 (module notes) at the identified model; the gain is the fit's (step 2)."""
    fit = EngineRuns(refit, found, "fit")
    neutral = refit.start_row()
    top = with_mechanism(neutral, mechanism, mechanism.main.typical[1])
    model = fit.model(np.vstack([neutral, top]))
    effect = fit.z(model, fit.level(model))  # each moved by its own level
    visible = float(np.nanmax(np.abs(effect[0] - effect[1])))
    value, gain = fit_engine(fit, neutral, mechanism)
    return Screened(mechanism.name, visible, gain, value, frf="eng")


def fit_engine(fit: EngineRuns, row: np.ndarray, mechanism: Mechanism) -> tuple[float, float]:
    """Step 2: the main parameter's value that fits the identifying runs' |G_ENG| best, SI units,
    and the share of the squared standardised residual it removes (0..1)."""
    lower, upper = mechanism.search_bounds()[0]
    values = np.linspace(lower, upper, GRID)
    step = values[1] - values[0]
    baseline = float(fit.cost(row[None])[0])
    for _ in range(2):
        costs = fit.cost(np.vstack([with_mechanism(row, mechanism, v) for v in values]))
        best = float(values[int(np.nanargmin(costs))])
        values = np.clip(np.linspace(best - step, best + step, GRID), lower, upper)
        step = values[1] - values[0]
    best_cost = float(np.nanmin(costs))
    gain = max(0.0, 1.0 - best_cost / baseline) if baseline > 0 else 0.0
    return best, gain


def engine_candidate(
    refit: Refit, found: MismatchMap, mechanism: Mechanism, value: float, tried: int
) -> Candidate:
    """Steps 3 and 4 (module notes) for the mechanism at the fitted ``value``."""
    fit, held = EngineRuns(refit, found, "fit"), EngineRuns(refit, found, "validation")
    before = refit.start_row()
    row = with_mechanism(before, mechanism, value)
    row[GAIN] *= 10.0 ** (float(fit.level(fit.model(row[None]))[0]) / 20.0)  # the K it asks for
    rows = np.vstack([row, before])
    model = fit.model(rows, TEST_REALIZATIONS, TEST_SEED)
    level = fit.level(model)
    measured = [r.measured_db for r in fit.residuals]
    after_db = [m[0] + level[0] for m in model]
    before_db = [m[1] + level[1] for m in model]
    k = len(mechanism.parameters)
    if not all(np.isfinite(c).all() for c in after_db):
        lam, single = 0.0, 1.0
    else:
        lam = statistic(measured, after_db, before_db)
        single = nested_p_value(lam, k, independent_bins(measured, after_db), k + 1)
    p_value = 1.0 if single >= 1.0 else sidak(single, tried)
    gain = float("nan")
    if held:
        fit_level = fit.level(fit.model(rows))
        z = held.z(held.model(rows), fit_level)
        rms = np.sqrt(np.nanmean(z**2, axis=1))
        gain = float(1.0 - rms[0] / rms[1])
    accepted = bool(p_value < ACCEPT_P and (np.isnan(gain) or gain > 0))
    if accepted:  # step 4
        at_gain = dataclasses.replace(refit, engine_gain=float(row[GAIN]))
        row, _ = at_gain.refit(Extra(at_gain.base, row, ()))
    scores = refit.run_nrmse(row)
    return Candidate.tested(
        (*refit.held, mechanism.name), row, scores, lam, p_value, k, gain, accepted, frf="eng"
    )


def engine_interval(refit: Refit, found: MismatchMap, candidate: Candidate) -> dict[str, object]:
    """Profile-likelihood 95 % interval and verdict of an accepted candidate's main parameter on
    |G_ENG|: the likelihood-ratio statistic of the model at :data:`INTERVAL_GRID` values over the
    parameter's search bounds (each model's level refitted, nothing else to re-optimise: the
    drivetrain does not shape |G_ENG|) against the candidate
    (:func:`dtid.identification.uncertainty.profile.interval_and_verdict`)."""
    mechanism = BY_NAME[candidate.mechanisms[-1]]
    fit = EngineRuns(refit, found, "fit")
    best = float(candidate.row[EXTRA_INDEX[mechanism.main.name]])
    lower, upper = mechanism.search_bounds()[0]
    values = np.union1d(np.linspace(lower, upper, INTERVAL_GRID), [best])
    rows = np.vstack([with_mechanism(candidate.row, mechanism, v) for v in values])
    model = fit.model(rows, TEST_REALIZATIONS, TEST_SEED)
    level = fit.level(model)
    measured = [r.measured_db for r in fit.residuals]
    at = int(np.flatnonzero(values == best)[0])
    stat = np.array(
        [
            statistic(
                measured,
                [m[at] + level[at] for m in model],
                [m[i] + level[i] for m in model],
            )
            for i in range(len(values))
        ]
    )
    (low, high), verdict = interval_and_verdict(values, stat, best)
    return {mechanism.main.name: {"lower": low, "upper": high, "verdict": verdict}}


def diagnose_engine(
    refit: Refit, found: MismatchMap, mechanisms: Sequence[Mechanism]
) -> tuple[list[Screened], list[Candidate], Candidate | None]:
    """Screen, fit and test the engine-path ``mechanisms`` (the module notes).

    Returns
    -------
    tuple
        Their screen, the candidates tested (none when the map is adequate: nothing to explain)
        and the accepted one (best criterion) or None.
    """
    screened = [screen_engine(refit, found, m) for m in mechanisms]
    if found.adequate:
        return screened, [], None
    tried = [
        engine_candidate(refit, found, BY_NAME[s.mechanism], s.start, len(screened))
        for s in screened
    ]
    tried.sort(key=lambda c: c.criterion)
    accepted = next((c for c in tried if c.accepted), None)
    return screened, tried, accepted
