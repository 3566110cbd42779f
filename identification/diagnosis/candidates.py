"""What a diagnosis's refits give: the screen's word on each mechanism, each refitted candidate
with its test, and what the drivetrain would make of a mechanism the data cannot tell from it.

The results of :mod:`dtid.identification.diagnosis.refit`, read by the verdict
(:mod:`dtid.identification.diagnosis.diagnose`) and written to the diagnosis JSON.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dtid.identification.diagnosis.mismatch import MismatchMap
from dtid.jsonfile import json_number
from dtid.simulator.mechanisms import BY_NAME, EXTRA_INDEX
from dtid.simulator.parameters import NAMES, DrivetrainParameters


@dataclass(frozen=True)
class Absorbed:
    """What the drivetrain parameters make of a mechanism the data cannot tell from them.

    Attributes
    ----------
    mechanism
        Its name.
    parameters
        The mechanism's parameters it was present with, SI units (the main one at the top of
        its typical range, the others in the middle of theirs).
    shift
        Relative change of each setup-4 parameter (``THETA_NAMES``) when the model without
        the mechanism is fitted to the model's curves with it; a parameter identified near 0
        (below ``refit.NEAR_ZERO`` of the prior's value: a friction or damping at its bound) has
        no meaningful relative change and is left out (the blind trial's case 12: d12 identified
        at 0.4 % of its truth, "+84,637 %").
    values
        The setup-4 values the drivetrain moves to, SI units (every parameter).
    objective
        Eq. (17) of that fit: how closely the drivetrain imitates the mechanism (0: exactly).
    """

    mechanism: str
    parameters: dict[str, float]
    shift: dict[str, float]
    values: dict[str, float]
    objective: float

    def as_dict(self) -> dict[str, object]:
        """The JSON entry (``verdict.absorbed``)."""
        return {
            "mechanism": self.mechanism,
            "parameters": self.parameters,
            "shift_percent": {name: 100 * value for name, value in self.shift.items()},
            "values": self.values,
            "objective": self.objective,
        }


@dataclass(frozen=True)
class Screened:
    """What the screen says of one mechanism.

    Attributes
    ----------
    mechanism
        Its name.
    visible_z
        Largest |z| of its effect at the top of its typical range after the drivetrain
        parameters have imitated what they can (linearised).
    gain
        Share of the identifying runs' squared standardised residual that its remaining effect
        explains (linearised, 0..1).
    start
        The magnitude of its main parameter the screen preferred, SI units.
    ladder
        The ``refit.LADDER_STEPS`` magnitudes the screen tried that explain most (SI units, the
        best first), each with the drivetrain's normalised free values that best accompany it
        (linearised from the screened model): where refits start.
    frf
        Where it was screened: ``drv`` (|G_DRV|, here), ``eng`` (|G_ENG|, an engine-path
        mechanism, :mod:`dtid.identification.diagnosis.engine_path`) or ``strokes`` (the
        strokes' own torques, :mod:`dtid.identification.diagnosis.imbalance`).
    threshold
        The |z| its own test needs, where that is not the map's (None: the map's).
    behind
        For a spring's second stage: a magnitude of a stage that the screened model's single
        spring may be imitating beyond its knee with the first stage behind it inside the search
        box (:func:`dtid.simulator.mechanisms.behind_imitation`), the one nearest the middle of
        the typical range; None where no typical stage fits behind it. ``visible_z`` is then
        the smaller of the least visible such stage's and the top of the range's.
    """

    mechanism: str
    visible_z: float
    gain: float
    start: float
    ladder: tuple[tuple[float, np.ndarray], ...] = dataclasses.field(repr=False, default=())
    frf: str = "drv"
    threshold: float | None = None
    behind: float | None = None

    def detectable(self, found: MismatchMap) -> bool:
        """Whether the data can see it at all: its imitation-free effect passes the threshold
        of ``found``'s map on its FRF, or its own."""
        threshold = found.threshold_of(self.frf) if self.threshold is None else self.threshold
        return self.visible_z >= threshold


@dataclass(frozen=True)
class Candidate:
    """One refitted model with mechanisms added, and its test against the model before it.

    Attributes
    ----------
    mechanisms
        The mechanisms it adds (one, or two for a greedy combination).
    row
        Its kernel parameter row (:data:`dtid.simulator.mechanisms.KERNEL_WIDTH`).
    objective
        Eq. (17) on the identifying runs.
    nrmse
        ``{"fit": {run: value}, "validation": {run: value}}``.
    statistic, p_value
        The likelihood-ratio statistic against the model it extends and its p-value (the F
        reference of nested models,
        :func:`dtid.identification.uncertainty.statistic.nested_p_value`), family-wise over
        the candidates tested against that model (Sidak).
    criterion
        2 k - statistic (AIC in the statistic's units; below zero it pays for its parameters).
    validation_gain
        Relative fall of the held-out runs' summed NRMSE against the model it extends (NaN
        without held-out runs).
    accepted
        p < ``refit.ACCEPT_P`` and the held-out NRMSE fell, below both the model it extends and
        the identified model (a refitted baseline can fit the held-out runs worse than the
        identification did).
    frf
        The FRF whose likelihood ratio and held-out runs tested it: ``drv`` (|G_DRV|), ``eng``
        (|G_ENG|, an engine-path mechanism, whose ``validation_gain`` is then the fall of the
        held-out runs' RMS z; :mod:`dtid.identification.diagnosis.engine_path`) or ``strokes``
        (the strokes' own torques, a cylinder imbalance, whose ``validation_gain`` is the fall of
        the held-out strokes' departure from its pattern; :mod:`dtid.identification.diagnosis.
        imbalance`).
    """

    mechanisms: tuple[str, ...]
    row: np.ndarray
    objective: float
    nrmse: dict[str, dict[str, float]]
    statistic: float
    p_value: float
    criterion: float
    validation_gain: float
    accepted: bool
    frf: str = "drv"

    @classmethod
    def tested(
        cls,
        mechanisms: tuple[str, ...],
        row: np.ndarray,
        scores: dict[str, dict[str, float]],
        statistic: float,
        p_value: float,
        k: int,
        validation_gain: float,
        accepted: bool,
        frf: str = "drv",
    ) -> Candidate:
        """A candidate from its test's figures (``scores``: ``Refit.run_nrmse`` of ``row``;
        ``k`` parameters added): its objective the identifying runs' summed NRMSE, its
        criterion 2 k - statistic."""
        return cls(
            mechanisms,
            row,
            float(sum(scores["fit"].values())),
            scores,
            float(statistic),
            p_value,
            float(2 * k - statistic),
            float(validation_gain),
            bool(accepted),
            frf,
        )

    def parameters(self) -> dict[str, float]:
        """The added mechanisms' parameter values, SI units."""
        return {
            name: float(self.row[EXTRA_INDEX[name]])
            for m in self.mechanisms
            for name in BY_NAME[m].names()
        }

    def drivetrain(self) -> DrivetrainParameters:
        """The drivetrain parameters refitted with it."""
        return DrivetrainParameters.from_array(self.row[: len(NAMES)])

    def as_dict(self) -> dict[str, object]:
        """The entry of the diagnosis JSON's ``candidates``."""
        return {
            "mechanism": "+".join(self.mechanisms),
            "parameters": self.parameters(),
            "drivetrain": self.drivetrain().as_dict(),
            "nrmse": self.nrmse,
            "objective": self.objective,
            "statistic": self.statistic,
            "p_value": self.p_value,
            "criterion": self.criterion,
            "validation_gain": json_number(self.validation_gain),  # null: no held-out run
            "accepted": self.accepted,
            "frf": self.frf,
        }
