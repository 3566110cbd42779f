"""Quantitative hints for a mismatch: the coupling values each run on its own asks for.

A mechanism the model leaves out shows as parameters that would differ from amplitude to
amplitude: a progressive arc spring as a DMF stiffness rising with the amplitude, a damping
growing with relative speed as a rising d12, a second clutch stage as a c23 that changes. For
each run (identifying and validating) and each of :data:`HINT_NAMES`, the other parameters held
as identified, the value that fits that run best is read from a grid of :data:`HINT_POINTS`
values over the identified value times 1/(1 + :data:`HINT_SPAN`) .. (1 + :data:`HINT_SPAN`)
(log-spaced, refined by a parabola through the best three). The effective values an engineer
compares are then the data's, per amplitude, against the model's one value.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtid.identification.model.response import model_drv_db
from dtid.identification.pipeline import RunSelection
from dtid.identification.search.objective import nrmse
from dtid.simulator.parameters import INDEX, UNITS, DrivetrainParameters

HINT_NAMES = ("c12", "d12", "c23")
"""Parameters whose effective value per run is reported: the DMF's stiffness and damping and the
clutch/gear stiffness."""
HINT_SPAN = 0.6
"""The grid reaches the identified value times 1.6 and divided by 1.6."""
HINT_POINTS = 21
"""Grid points per parameter."""


@dataclass(frozen=True)
class EffectiveValue:
    """The value of one parameter that fits one run best, the others as identified.

    Attributes
    ----------
    name
        The parameter.
    label, role, amplitude_nm
        The run (``recording @ A N*m``), ``fit`` or ``validation``, and its amplitude, N*m.
    identified
        The model's value, SI units.
    effective
        The value the run asks for, SI units (at the grid's edge when the run asks for more).
    nrmse_identified, nrmse_effective
        The run's NRMSE (eq. 16) at the two.
    at_edge
        True when the best value is the grid's edge.
    """

    name: str
    label: str
    role: str
    amplitude_nm: float
    identified: float
    effective: float
    nrmse_identified: float
    nrmse_effective: float
    at_edge: bool

    @property
    def change(self) -> float:
        """Effective over identified, less one."""
        return self.effective / self.identified - 1.0

    def as_dict(self) -> dict[str, object]:
        """The hint for the diagnosis JSON."""
        return {
            "name": self.name,
            "unit": UNITS[self.name],
            "run": self.label,
            "role": self.role,
            "amplitude_nm": self.amplitude_nm,
            "identified": self.identified,
            "effective": self.effective,
            "nrmse_identified": self.nrmse_identified,
            "nrmse_effective": self.nrmse_effective,
            "at_edge": self.at_edge,
        }


def effective_values(
    parameters: DrivetrainParameters,
    selections: Sequence[tuple[str, RunSelection]],
    names: Sequence[str] = HINT_NAMES,
) -> list[EffectiveValue]:
    """Each run's best value of each of ``names``, the others as identified (module notes).

    Parameters
    ----------
    parameters
        The identified model.
    selections
        ``(role, selection)`` pairs as :func:`dtid.identification.diagnosis.mismatch.mismatch_map`
        takes them.
    names
        Parameters to scan one at a time.

    Returns
    -------
    list of EffectiveValue
        Run by run, name by name.
    """
    base = parameters.as_array()
    factors = np.geomspace(1.0 / (1.0 + HINT_SPAN), 1.0 + HINT_SPAN, HINT_POINTS)
    hints = []
    for role, selection in selections:
        for test, runs in zip(selection.tests, selection.runs, strict=True):
            model_test = test.model_test(runs)
            at_identified = model_drv_db(base[None], model_test)
            for name in names:
                sets = np.repeat(base[None], HINT_POINTS, axis=0)
                sets[:, INDEX[name]] = base[INDEX[name]] * factors
                curves = model_drv_db(sets, model_test)
                for position, i in enumerate(runs):
                    estimate = test.estimates[i]
                    scores = nrmse(estimate.drv_db, curves[position])
                    best = int(np.argmin(scores))
                    value = base[INDEX[name]] * refine(np.log(factors), scores, best)
                    hints.append(
                        EffectiveValue(
                            name,
                            test.run_label(i),
                            role,
                            estimate.run.amplitude_nm,
                            float(base[INDEX[name]]),
                            float(value),
                            float(nrmse(estimate.drv_db, at_identified[position])[0]),
                            float(scores[best]),
                            best in (0, HINT_POINTS - 1),
                        )
                    )
    return hints


def refine(log_factors: np.ndarray, scores: np.ndarray, best: int) -> float:
    """The factor at the vertex of the parabola through the best grid point and its neighbours
    (the grid point itself at an edge or when the three do not curve upwards)."""
    if best in (0, len(scores) - 1):
        return float(np.exp(log_factors[best]))
    x, y = log_factors[best - 1 : best + 2], scores[best - 1 : best + 2]
    curvature = (y[2] - y[1]) / (x[2] - x[1]) - (y[1] - y[0]) / (x[1] - x[0])
    if not np.isfinite(curvature) or curvature <= 0:
        return float(np.exp(log_factors[best]))
    a, b, _ = np.polyfit(x, y, 2)
    vertex = float(np.clip(-b / (2 * a), x[0], x[2]))
    return float(np.exp(vertex))
