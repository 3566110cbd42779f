"""The diagnosis of an identification: is the model adequate, and if not, where and how it misses.

:func:`diagnose_report` takes an identification (:class:`dtid.identification.pipeline.
IdentificationReport`); :func:`diagnose_document` takes the JSON ``dtid identify`` wrote and the
recordings it came from. Both give a :class:`Diagnosis`: the mismatch map
(:mod:`dtid.identification.diagnosis.mismatch`), the effective coupling values per run
(:mod:`dtid.identification.diagnosis.hints`) when something is significant, the mechanisms of
the library screened, refitted and tested (those of the engine path on |G_ENG|,
:mod:`dtid.identification.diagnosis.engine_path`, first; the others on |G_DRV|,
:mod:`dtid.identification.diagnosis.refit`), and the verdict. A mismatch no mechanism explains
is reported as unexplained, with its bands and hints (docs/diagnosis.md).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from dtid.errors import AnalysisError, ConfigError
from dtid.identification.diagnosis.candidates import Absorbed, Candidate, Screened
from dtid.identification.diagnosis.engine_path import (
    diagnose_engine,
    engine_interval,
    engine_mechanisms,
)
from dtid.identification.diagnosis.hints import EffectiveValue, effective_values
from dtid.identification.diagnosis.imbalance import (
    MECHANISM,
    StrokeTest,
    imbalance_candidate,
    imbalance_interval,
    screen_strokes,
    stroke_test,
)
from dtid.identification.diagnosis.mismatch import DRAWS, MismatchMap, mismatch_map
from dtid.identification.diagnosis.refit import (
    ACCEPT_P,
    Refit,
    diagnose_mechanisms,
)
from dtid.identification.model.test_setup import MeasuredTest
from dtid.identification.pipeline import (
    IdentificationReport,
    RunSelection,
    identification_runs,
    validation_runs,
    with_variation,
)
from dtid.identification.search.objective import FAILED_NRMSE
from dtid.simulator.mechanisms import BY_NAME, MECHANISMS, kernel_parameters
from dtid.simulator.parameters import NAMES, DrivetrainParameters

logger = logging.getLogger(__name__)

REFIT_REPORTED = 0.05
"""Relative change from which a refitted drivetrain parameter is named in the verdict."""


@dataclass(frozen=True)
class DrivetrainRefit:
    """The model the mechanisms' refits extend, refitted without any (their own baseline,
    :func:`dtid.identification.diagnosis.refit.diagnose_mechanisms`), and its mismatch map.

    Where that map is adequate while the identified model's is not, the recordings need no
    missing physics but other drivetrain values: the identification ended short of the best
    fit (a search caught in another basin), or a mechanism present is absorbed by them.

    Attributes
    ----------
    parameters, before
        The drivetrain refitted, and the one the refits extended (the identified one, with
        any engine-path gain K it was given).
    found
        Its mismatch map.
    nrmse
        ``{"fit": {run: value}, "validation": {run: value}}``.
    """

    parameters: DrivetrainParameters
    before: DrivetrainParameters
    found: MismatchMap
    nrmse: Mapping[str, Mapping[str, float]]

    def changes(self) -> dict[str, tuple[float, float]]:
        """Setup-4 drivetrain parameters moved by at least :data:`REFIT_REPORTED`, largest
        relative change first: ``{name: (identified, refitted)}``."""
        before, after = self.before.as_dict(), self.parameters.as_dict()
        moved = {
            name: (before[name], after[name])
            for name in NAMES
            if name not in ("T_loss", "K")
            and abs(after[name] - before[name]) >= REFIT_REPORTED * abs(before[name]) > 0
        }
        return dict(sorted(moved.items(), key=lambda item: -abs(item[1][1] / item[1][0] - 1.0)))

    def as_dict(self) -> dict[str, object]:
        """The verdict's ``drivetrain_refit`` entry."""
        return {
            "parameters": self.parameters.as_dict(),
            "adequate": self.found.adequate,
            "global_p_value": self.found.global_p_value,
            "bands": len(self.found.bands),
            "nrmse": {role: dict(values) for role, values in self.nrmse.items()},
        }


@dataclass(frozen=True)
class Diagnosis:
    """What the diagnosis found.

    Attributes
    ----------
    baseline
        The identification diagnosed: ``parameters``, ``nrmse`` ({``fit``, ``validation``}),
        ``objective`` and ``intervals``, as in the identification JSON.
    parameters
        Its parameter set.
    mismatch
        The mismatch map.
    hints
        Effective coupling values per run (empty when the model is adequate).
    seconds
        Wall time of the diagnosis (not of the identification), s.
    screened
        The screen of every mechanism considered.
    candidates
        Every model refitted, best criterion first.
    accepted
        The accepted models in the order accepted (each extends the one before).
    after
        The mismatch map of the last accepted model (None when none was).
    intervals
        Profile-likelihood intervals of the accepted mechanisms' parameters (None when not
        computed).
    absorbed
        For each indistinguishable mechanism, what the drivetrain parameters would make of it
        at the top of its typical range (:meth:`Refit.absorbed`).
    cylinders
        What the strokes say of the cylinders (None: not asked, or no torque request on the
        bus; :mod:`dtid.identification.diagnosis.imbalance`).
    refitted
        Where |G_DRV| refits ran and none was accepted: the drivetrain refitted alone and its
        map (None otherwise).
    """

    baseline: Mapping[str, Any]
    parameters: DrivetrainParameters
    mismatch: MismatchMap
    hints: tuple[EffectiveValue, ...]
    seconds: float
    screened: tuple[Screened, ...] = ()
    candidates: tuple[Candidate, ...] = ()
    accepted: tuple[Candidate, ...] = ()
    after: MismatchMap | None = None
    intervals: Mapping[str, Mapping[str, object]] | None = None
    absorbed: tuple[Absorbed, ...] = ()
    cylinders: StrokeTest | None = None
    refitted: DrivetrainRefit | None = None

    @property
    def mechanisms(self) -> tuple[str, ...]:
        """The accepted mechanisms."""
        return self.accepted[-1].mechanisms if self.accepted else ()

    @property
    def indistinguishable(self) -> tuple[str, ...]:
        """Mechanisms these data can neither detect nor exclude: invisible to the screen at
        their typical magnitude at a model that explains the recordings (the identified one
        when adequate, else the accepted one), and, where refitted, not significant. Empty when
        a mismatch is left unexplained: the screen is local, and at a model bent around missing
        physics it cannot tell what the data would show."""
        if not (self.adequate or self.accepted):
            return ()
        significant = {c.mechanisms[-1] for c in self.candidates if c.p_value < ACCEPT_P}
        return tuple(
            s.mechanism
            for s in unseen(self.screened, self.after or self.mismatch)
            if s.mechanism not in significant and s.mechanism not in self.mechanisms
        )

    @property
    def unexplained(self) -> tuple[Any, ...]:
        """The bands left: the accepted model's, else the identified model's."""
        return (self.after or self.mismatch).bands

    @property
    def adequate(self) -> bool:
        """True when the model explains the recordings: no band in the map, the strokes show no
        cylinder apart, and no mechanism is accepted (the map's test is omnibus: a mechanism's
        refit tests one direction of the residual and can find what no band shows)."""
        return (
            self.mismatch.adequate
            and not (self.cylinders and self.cylinders.significant)
            and not self.accepted
        )

    def sentence(self) -> str:
        """The verdict in one sentence."""
        test = self.mismatch
        if self.adequate:
            frfs = "|G_DRV| or |G_ENG|" if test.engine is not None else "|G_DRV|"
            text = (
                f"The identified model explains these recordings: no band of {frfs} differs "
                f"significantly (family-wise {100 * test.family_error:g} %; the largest "
                f"deviation has p = {test.global_p_value:.2g})"
            )
            hidden = self.indistinguishable
            if hidden:  # absorbed when present: blind trial case 3 fitted with c12 -58 %
                text += (
                    f"; these data cannot tell {', '.join(hidden)} from the drivetrain "
                    "parameters, which would absorb any of them present"
                )
            refused = [c for c in self.candidates if c.p_value < ACCEPT_P]  # best first
            if refused:  # a check significant on the identifying runs alone
                text += (
                    f"; {refused[0].mechanisms[-1]} fits the identifying runs significantly "
                    f"better (p = {refused[0].p_value:.1g}), but the held-out run does not "
                    f"confirm it ({_held_out_change(refused[:1])}), so it is not named"
                )
            return text + "."
        misses = []
        if test.bands:
            # a located band first: a run's smooth trend spans its whole band
            first = next((b for b in test.bands if b.kind == "bins"), test.bands[0])
            where = (
                f"|G_{first.frf.upper()}| at {first.amplitude_nm:g} N*m, {first.f_lo_hz:.1f}-"
                f"{first.f_hi_hz:.1f} Hz, {first.excess_db:+.1f} dB, p = {first.p_value:.1g}"
                f"{', a smooth trend' if first.kind == 'trend' else ''}"
            )
            count = len(test.bands)
            misses.append(
                f"misses these recordings in {count} band{'s' if count > 1 else ''} (most "
                f"significant located: {where})"
            )
        cylinders = self.cylinders
        if cylinders is not None and cylinders.significant:
            misses.append(
                "takes the cylinders as equal where the strokes show one apart (one-cylinder "
                f"share {cylinders.share:+.3f} +- {cylinders.standard_error:.3f}, "
                f"p = {cylinders.p_value:.1g})"
            )
        if not misses:  # accepted by the check of what the screen would list
            misses.append(
                f"misses these recordings where its map locates no band (family-wise "
                f"{100 * test.family_error:g} %, the largest deviation has p = "
                f"{test.global_p_value:.2g})"
            )
        text = "The identified model " + " and ".join(misses)
        if self.accepted:
            last = self.accepted[-1]
            values = ", ".join(
                f"{name} = {value:.3g}{_unit(name)}" for name, value in last.parameters().items()
            )
            verb = "explains" if len(last.mechanisms) == 1 else "explain"
            text += (
                f"; {' and '.join(last.mechanisms)} {verb}"
                f" it ({values}; p = {max(c.p_value for c in self.accepted):.1g}, "
                f"{_held_out_change(self.accepted)})"
            )
            left = len(self.unexplained)
            if left:
                text += f"; {left} band{'s' if left > 1 else ''} remain unexplained"
            return text + "."
        tried = ", ".join(c.mechanisms[-1] for c in self.candidates)
        refitted = self.refitted
        if refitted is not None and refitted.found.adequate:
            moved = ", ".join(
                f"{name} {old:.4g} -> {new:.4g}"
                for name, (old, new) in list(refitted.changes().items())[:4]
            )
            return text + (
                f"; no mechanism of the library explains it better than the drivetrain "
                f"refitted alone (tried: {tried}), which explains the recordings "
                f"(largest deviation p = {refitted.found.global_p_value:.2g}): the "
                f"identification ended short of the best fit, or a mechanism present is "
                f"absorbed by {moved or 'the drivetrain parameters'}."
            )
        text += (
            f"; no mechanism of the library explains it (refitted: {tried})"
            if tried
            else "; no mechanism of the library could explain its signature"
        )
        hint = self.strongest_hint()
        if hint:
            text += f": {hint}"
        return text + "."

    def strongest_hint(self) -> str:
        """The parameter whose per-run values improve the fit most, as text ('' if none)."""
        values = strongest(self.hints)
        if not values:
            return ""
        per_run = ", ".join(
            f"{h.effective:.4g}{' (edge)' if h.at_edge else ''} at {h.amplitude_nm:g} N*m"
            f"{'' if h.role == 'fit' else ' (validation)'}"
            for h in values
        )
        text = (
            f"the runs ask for {values[0].name} = {per_run}, against "
            f"{values[0].identified:.4g} identified"
        )
        trend = amplitude_trend(values)
        return f"{text}; {trend}" if trend else text

    def as_dict(self) -> dict[str, object]:
        """The JSON document of ``dtid diagnose`` (docs/schemas/diagnosis.schema.json)."""
        bands = [band.as_dict() for band in self.mismatch.bands]
        return {
            "adequate": self.adequate,
            "mismatch": bands,
            "baseline": {key: self.baseline[key] for key in ("parameters", "nrmse", "objective")},
            "candidates": [candidate.as_dict() for candidate in self.candidates],
            "verdict": self._verdict(bands),
            "test": self.mismatch.as_dict(),
            "screen": [
                {
                    "mechanism": s.mechanism,
                    "visible_z": s.visible_z,
                    "gain": s.gain,
                    "detectable": s.detectable(self.mismatch),
                    "frf": s.frf,
                }
                for s in self.screened
            ],
            "hints": [hint.as_dict() for hint in self.hints],
            "cylinders": None if self.cylinders is None else self.cylinders.as_dict(),
            "library": [m.name for m in MECHANISMS],
            "seconds": self.seconds,
        }

    def _verdict(self, bands: list[dict[str, object]]) -> dict[str, object]:
        common = {
            "explanation": self.sentence(),
            "indistinguishable": list(self.indistinguishable),
            "absorbed": [entry.as_dict() for entry in self.absorbed],
            "drivetrain_refit": None if self.refitted is None else self.refitted.as_dict(),
        }
        if not self.accepted:
            return {
                "mechanisms": [],
                **common,
                "parameters": self.baseline["parameters"],
                "intervals": self.baseline.get("intervals", {}),
                "nrmse": self.baseline["nrmse"],
                "unexplained": bands,
            }
        last = self.accepted[-1]
        drivetrain = last.drivetrain().as_dict()
        return {
            "mechanisms": list(last.mechanisms),
            **common,
            "parameters": {
                **{n: drivetrain[n] for n in self.baseline["parameters"] if n in drivetrain},
                **last.parameters(),
            },
            "intervals": dict(self.intervals or {}),
            **(
                {}
                if self.intervals is not None
                else {"intervals_note": "not computed: give --profile-points N (5-7)"}
            ),
            "nrmse": {
                "fit": last.nrmse.get("fit", {}),
                "validation": last.nrmse.get("validation", {}),
            },
            "unexplained": [band.as_dict() for band in self.unexplained],
        }


TREND_SPREAD = 0.05
"""Relative spread of the identifying runs' effective values above which they are read as
depending on the amplitude."""


def unseen(screened: Sequence[Screened], found: MismatchMap) -> list[Screened]:
    """The screened mechanisms that ``found``'s map cannot see at their typical magnitude
    (:meth:`Screened.detectable`): what the diagnosis lists as indistinguishable when the model
    explains the recordings, and checks by their refits where the map has no |G_DRV| band."""
    return [s for s in screened if not s.detectable(found)]


def strongest(hints: Sequence[EffectiveValue]) -> list[EffectiveValue]:
    """The hints of the parameter whose per-run values improve the fit most, identifying runs
    first, by amplitude (empty when none improves it)."""
    gains: dict[str, float] = {}
    for value in hints:
        gains[value.name] = gains.get(value.name, 0.0) + (
            value.nrmse_identified - value.nrmse_effective
        )
    if not gains or max(gains.values()) <= 0:
        return []
    name = max(gains, key=lambda n: gains[n])
    return sorted((h for h in hints if h.name == name), key=lambda h: (h.role, h.amplitude_nm))


def amplitude_trend(values: Sequence[EffectiveValue]) -> str:
    """How one parameter's effective value changes over the runs' amplitudes.

    Returns ``''`` for fewer than two identifying runs or a value at the grid's edge. Else,
    when the identifying runs agree (within :data:`TREND_SPREAD`): on a value other than the
    model's (the model's value is off, one value fits every amplitude), or on the model's,
    with a held-out run asking for another (:func:`held_out_stage`); or whether the value rises or
    falls with the amplitude (an amplitude dependence the model lacks, as a progressive spring
    or a free play would give).
    """
    runs = sorted((v for v in values if v.role == "fit"), key=lambda v: v.amplitude_nm)
    if len(runs) < 2 or any(v.at_edge for v in runs):
        return ""
    effective = np.array([v.effective for v in runs])
    identified = runs[0].identified
    if float(np.ptp(effective) / identified) > TREND_SPREAD:
        steps = np.diff(effective)
        if np.all(steps > 0):
            return "rising with the amplitude"
        if np.all(steps < 0):
            return "falling with the amplitude"
        return "differing between the amplitudes"
    if abs(float(np.mean(effective)) / identified - 1.0) > TREND_SPREAD:
        return "the identifying runs agree on one value: the model's is off"
    departing = held_out_stage(values, (runs[0].amplitude_nm, runs[-1].amplitude_nm))
    if departing is None:
        return "the identifying runs agree with the model's value"
    run, stage = departing
    text = (
        f"the identifying runs agree with the model's value, the held-out run at "
        f"{run.amplitude_nm:g} N*m asks for {abs(run.change):.0%} "
        f"{'less' if run.change < 0 else 'more'}{' at least' if run.at_edge else ''}"
    )
    if stage:
        text += (
            f": {run.name} grows with the amplitude beyond the identifying runs' reach, as "
            f"{stage} engaged at every identifying amplitude would make it, which refits on the "
            "identifying runs alone cannot find"
        )
    return text


def held_out_stage(
    values: Sequence[EffectiveValue], fit_amplitudes: tuple[float, float]
) -> tuple[EffectiveValue, str | None] | None:
    """The held-out run asking most for another value of a parameter on whose identified value
    the identifying runs (from ``fit_amplitudes[0]`` to ``[1]`` N*m) agree, and the mechanism
    that would explain it: one adding a second stage to that coupling beyond a knee (its
    ``<name>_2`` and ``knee<ij>``), where the run lies below the identifying amplitudes and
    asks for less, or above them and asks for more (else None). None when no held-out run
    departs by more than :data:`TREND_SPREAD`.

    Such a stage, engaged at every identifying amplitude, makes the coupling there one
    stiffer linear spring: the identifying runs agree, and only a run short of the knee shows
    the first stage (blind trial case 6, a two-stage clutch: c23 275 and 278 at 5 and 10 N*m,
    171 or less at 2 N*m, 274 identified).
    """
    held = [v for v in values if v.role != "fit" and abs(v.change) > TREND_SPREAD]
    if not held:
        return None
    run = max(held, key=lambda v: abs(v.change))
    below, above = run.amplitude_nm < fit_amplitudes[0], run.amplitude_nm > fit_amplitudes[1]
    stage = next(
        (
            m.name
            for m in MECHANISMS
            if {p.name for p in m.parameters} >= {f"{run.name}_2", f"knee{run.name[1:]}"}
        ),
        None,
    )
    grows = (below and run.change < 0) or (above and run.change > 0)
    return run, stage if grows else None


def _unit(name: str) -> str:
    """' unit' of a mechanism parameter, '' for a dimensionless one."""
    for mechanism in MECHANISMS:
        for spec in mechanism.parameters:
            if spec.name == name and spec.unit != "1":
                return f" {spec.unit}"
    return ""


def _held_out_change(accepted: Sequence[Candidate]) -> str:
    """The held-out runs' change over the accepted steps, as text: their |G_DRV| NRMSE, and
    their |G_ENG| RMS z for an engine-path mechanism."""
    parts = []
    measures = (("strokes", "strokes' departure"), ("eng", "|G_ENG| RMS z"), ("drv", "NRMSE"))
    for frf, measure in measures:
        gains = [c.validation_gain for c in accepted if c.frf == frf]
        if not gains:
            continue
        if any(np.isnan(g) for g in gains):
            parts.append(f"held-out {measure} not measured (no held-out run)")
            continue
        remaining = float(np.prod([1.0 - g for g in gains]))
        parts.append(f"held-out {measure} {-100 * (1.0 - remaining):+.0f} %")
    return ", ".join(parts)


def diagnose(
    parameters: DrivetrainParameters,
    selections: Sequence[tuple[str, RunSelection]],
    baseline: Mapping[str, Any],
    draws: int = DRAWS,
    mechanisms: Sequence[str] | None = None,
    profile_points: int = 0,
) -> Diagnosis:
    """Diagnose a parameter set against its identification and validation runs.

    Parameters
    ----------
    parameters
        The identified model.
    selections
        ``(role, selection)`` pairs, ``fit`` and ``validation``.
    baseline
        The identification's JSON figures (``parameters``, ``nrmse``, ``objective``,
        ``intervals``).
    draws
        Model recordings per run for the scatter.
    mechanisms
        The mechanisms to consider (default: the whole library; empty: none).
    profile_points
        Grid points of the accepted mechanisms' profile intervals (0: none).
    """
    began = time.perf_counter()
    unknown = [m for m in mechanisms or () if m not in BY_NAME]
    if unknown:
        raise ConfigError(f"unknown mechanism {unknown[0]!r}; the library: {', '.join(BY_NAME)}")
    failed = [
        label
        for scores in baseline.get("nrmse", {}).values()
        for label, value in scores.items()
        if value >= FAILED_NRMSE
    ]
    if failed:
        raise AnalysisError(
            f"the identified model could not idle through {', '.join(failed)} (NRMSE "
            f"{FAILED_NRMSE:g}): its parameters do not describe "
            f"{'that run' if len(failed) == 1 else 'those runs'}, so there is no model curve to "
            "diagnose against; identify again (`dtid identify` names such runs with the "
            "recording's idle scatter)"
        )
    found = mismatch_map(parameters, selections, draws)
    for message in found.noise_warnings():
        logger.warning("%s", message)
    roles = dict(selections)
    refit = Refit(parameters, roles["fit"], roles.get("validation"))
    allowed = list(BY_NAME) if mechanisms is None else list(mechanisms)
    screened: list[Screened] = []
    candidates: list[Candidate] = []
    accepted: list[Candidate] = []
    refitted = None
    # the strokes first: the cylinders' spread, whatever the map says (imbalance.py's notes)
    strokes = stroke_test(refit.fit, refit.validation) if MECHANISM.name in allowed else None
    start = found
    if strokes is not None:
        screened.append(screen_strokes(strokes))
        if strokes.significant:
            candidates.append(imbalance_candidate(refit, strokes))
        if candidates and candidates[-1].accepted:
            accepted.append(candidates[-1])
            refit = refit.holding(accepted[-1])
            start = mismatch_map(accepted[-1].row, selections, draws)
    engine_map = start
    on_engine = engine_mechanisms(engine_map, allowed)
    screened_eng, tried_eng, engine = diagnose_engine(refit, engine_map, on_engine)
    screened += screened_eng
    candidates += tried_eng
    if engine:  # the refits hold its mechanism and the K its |G_ENG| asked for
        accepted.append(engine)
        refit = dataclasses.replace(refit.holding(engine), engine_gain=engine.drivetrain().K)
        # the drivetrain's mechanisms answer what the model with it misses
        start = mismatch_map(engine.row, selections, draws)
    # on |G_DRV|: the drivetrain's, and an engine path's where no request gives |G_ENG|
    drivetrain = [m for m in allowed if BY_NAME[m] not in on_engine and m != MECHANISM.name]
    if drivetrain:
        at = refit.start_row() if accepted else None
        screened += [s for s in refit.screen(start, at) if s.mechanism in drivetrain]
    if any(band.frf == "drv" for band in start.bands) and drivetrain:
        screened_drv, tried, accepted_drv, alone = diagnose_mechanisms(
            refit, start, drivetrain, [s for s in screened if s.frf == "drv"]
        )
        screened = [s for s in screened if s.frf != "drv"] + screened_drv
        candidates += tried
        accepted += accepted_drv
        if alone is not None and not accepted_drv:
            refitted = DrivetrainRefit(
                DrivetrainParameters.from_array(alone[: len(NAMES)]),
                DrivetrainParameters.from_array(refit.start_row()[: len(NAMES)]),
                mismatch_map(alone, selections, draws),
                refit.run_nrmse(alone),
            )
    elif drivetrain:  # no band: what the screen would list is checked by its refit
        hidden = unseen(screened, start)
        listed = [s for s in hidden if s.frf == "drv" and s.mechanism in drivetrain]
        if listed:
            _, tried, accepted_drv, _ = diagnose_mechanisms(
                refit, start, [s.mechanism for s in listed], listed, checking=True
            )
            candidates += tried
            accepted += accepted_drv
    candidates.sort(key=lambda c: c.criterion)
    after = intervals = None
    if accepted:
        after = start  # the map of the last model accepted, drawn already unless on |G_DRV|
        on_drv = accepted[-1].frf == "drv"
        if on_drv:
            after = mismatch_map(accepted[-1].row, selections, draws)
            rescreened = {x.mechanism: x for x in refit.screen(after, accepted[-1].row)}
            screened = [rescreened.get(x.mechanism, x) if x.frf == "drv" else x for x in screened]
        if profile_points > 0:
            intervals = {
                **(imbalance_interval(strokes) if strokes and strokes.accepted else {}),
                **(engine_interval(refit, engine_map, engine) if engine else {}),
                **(refit.intervals(accepted[-1], profile_points) if on_drv else {}),
            }
    hints = () if found.adequate or accepted else tuple(effective_values(parameters, selections))
    diagnosis = Diagnosis(
        baseline,
        parameters,
        found,
        hints,
        0.0,
        tuple(screened),
        tuple(candidates),
        tuple(accepted),
        after,
        intervals,
        cylinders=strokes,
        refitted=refitted,
    )
    final = accepted[-1].row if accepted else kernel_parameters(parameters.as_array())
    behind = {x.mechanism: x.behind for x in diagnosis.screened}
    absorbed = tuple(
        refit.absorbed(BY_NAME[m], final, behind.get(m)) for m in diagnosis.indistinguishable
    )
    return dataclasses.replace(diagnosis, absorbed=absorbed, seconds=time.perf_counter() - began)


def diagnose_report(
    report: IdentificationReport,
    draws: int = DRAWS,
    mechanisms: Sequence[str] | None = None,
    profile_points: int = 0,
) -> Diagnosis:
    """Diagnose an identification (:func:`dtid.workflow.identify`'s report)."""
    if report.fit is None:
        raise ValueError("the report holds no identification runs to diagnose")
    selections = [("fit", report.fit)]
    if report.validation is not None and report.validation.tests:
        selections.append(("validation", report.validation))
    return diagnose(
        report.identification.parameters,
        selections,
        report.as_dict(),
        draws,
        mechanisms,
        profile_points,
    )


def diagnose_document(
    tests: Sequence[MeasuredTest],
    document: Mapping[str, Any],
    identify_amplitudes: Sequence[float] | None = None,
    draws: int = DRAWS,
    mechanisms: Sequence[str] | None = None,
    profile_points: int = 0,
) -> Diagnosis:
    """Diagnose an identification JSON of ``dtid identify`` against the recordings it came from.

    Parameters
    ----------
    tests
        The recordings' tests, as the identification had them.
    document
        The identification JSON (its ``parameters``, ``T_loss`` and ``combustion_variation``).
    identify_amplitudes
        The amplitudes that identified (default: the two largest).
    draws
        Model recordings per run for the scatter.

    Raises
    ------
    ConfigError
        If the document lacks a parameter or does not name the recordings given.
    """
    values = dict(document.get("parameters", {}))
    values["T_loss"] = document.get("T_loss")
    missing = [name for name in NAMES if not isinstance(values.get(name), int | float)]
    if missing:
        raise ConfigError(
            f"the identification JSON lacks {', '.join(missing)}: give the JSON `dtid identify "
            "--json` wrote for these recordings"
        )
    parameters = DrivetrainParameters(**{name: float(values[name]) for name in NAMES})
    variations = dict(document.get("combustion_variation", {}))
    selections = []
    for role, select in (("fit", identification_runs), ("validation", validation_runs)):
        selection = select(tests, identify_amplitudes)
        unknown = [t.name for t in selection.tests if t.name not in variations]
        if unknown:
            raise ConfigError(
                f"the identification JSON has no combustion_variation for {', '.join(unknown)}: "
                "it was identified from other recordings (or other paths); give the recordings "
                "it names"
            )
        if selection.tests:
            selections.append((role, with_variation(selection, variations)))
    return diagnose(parameters, selections, document, draws, mechanisms, profile_points)
