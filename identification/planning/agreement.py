"""Do two rounds of an adaptive campaign agree? A check before the campaign trusts its targets.

Round k is identified from every run so far, round k-1 from a part of them. Where both searches
end in the same basin, each parameter moves between them by about its scatter; where one of
them ended at another optimum (the campaign trial's truth 6, before the next round's search
polished the previous optimum: J3 from +6 % to +51 % of the truth between rounds 1 and 2), the
parameters jump by many times it, and a precision predicted at either optimum says nothing
about the truth. A basin both rounds share is not seen here (truth 4: round 1 at c12 +167 %,
the later rounds there too); the fit's adequacy test is for that
(:func:`dtid.identification.diagnosis.mismatch.adequacy`). The check: for each parameter,

    z = (theta_k - theta_{k-1}) / sqrt(sigma_{k-1}^2 + sigma_k^2)

with each sigma the 1-sigma precision the worker predicted for the runs recorded up to that
round, absolute: the relative precision times the value it was predicted for (the plan's
``prior``: the value identified, or where that is 0, as the friction at its bound often is, the
value the planning put in its place). For nested data the difference's
variance is sigma_{k-1}^2 - sigma_k^2 (the later estimate is the more efficient); the sum is
larger, so the check is conservative: it flags a jump no round's scatter explains, not a
drift within it. The rounds disagree when any |z| exceeds :data:`Z_LIMIT`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from dtid.identification.search.parameterization import theta_from_parameters
from dtid.simulator.parameters import DrivetrainParameters

Z_LIMIT = 4.0
"""|z| above which two rounds disagree: with 13 parameters, where the predicted precision is
honest and the scatter Gaussian, one passes it in about one campaign in 1200 that is right (3:
one in 30); a precision predicted 1.5 times too small (the issue's tolerance) makes that one in
ten."""


@dataclass(frozen=True)
class Agreement:
    """How far the parameters moved between two rounds.

    Attributes
    ----------
    z
        Move over its scatter, by parameter (None where neither round gives a scatter).
    moved
        Relative move, by parameter (None where the earlier value is 0).
    """

    z: dict[str, float | None]
    moved: dict[str, float | None]

    @property
    def disagreeing(self) -> list[str]:
        """Parameters that moved by more than :data:`Z_LIMIT` times their scatter, worst first."""
        flagged = [n for n, z in self.z.items() if z is not None and abs(z) > Z_LIMIT]
        return sorted(flagged, key=lambda n: -abs(self.z[n] or 0.0))

    @property
    def agree(self) -> bool:
        """True when no parameter moved beyond its scatter."""
        return not self.disagreeing

    def as_dict(self) -> dict[str, object]:
        """JSON form: ``agree``, ``disagreeing``, ``z``, ``moved_percent``, ``z_limit`` and the
        :meth:`summary`."""
        return {
            "agree": self.agree,
            "summary": self.summary(),
            "disagreeing": self.disagreeing,
            "z": {n: None if z is None else round(z, 2) for n, z in self.z.items()},
            "moved_percent": {
                n: None if m is None else round(100 * m, 2) for n, m in self.moved.items()
            },
            "z_limit": Z_LIMIT,
        }

    def summary(self) -> str:
        """One sentence naming the parameters that jumped."""
        if self.agree:
            return "the parameters moved within their scatter"
        parts = [
            f"{n} "
            + ("from 0" if self.moved[n] is None else f"{100 * (self.moved[n] or 0.0):+.1f} %")
            + f" ({abs(self.z[n] or 0.0):.0f} sigma)"
            for n in self.disagreeing
        ]
        return "the parameters jumped: " + ", ".join(parts)


def scatter(precision: Mapping[str, float], prior: DrivetrainParameters) -> dict[str, float]:
    """Absolute 1-sigma scatter by name, SI units.

    Parameters
    ----------
    precision
        Relative 1-sigma precisions by name (a plan's ``recorded.predicted_precision``).
    prior
        The parameters they were predicted for (the plan's ``prior``).
    """
    values = {**theta_from_parameters(prior), "J1": prior.J1, "J2": prior.J2, "J3": prior.J3}
    return {name: float(sd) * abs(values[name]) for name, sd in precision.items() if name in values}


def plan_scatter(plan: Mapping[str, Any]) -> dict[str, float]:
    """:func:`scatter` of the runs a plan document (``dtid plan --json``'s) counts as recorded."""
    prior = DrivetrainParameters(**{str(k): float(v) for k, v in plan["prior"].items()})
    return scatter(plan["recorded"]["predicted_precision"] or {}, prior)


def agreement(
    before: Mapping[str, float],
    before_sd: Mapping[str, float],
    after: Mapping[str, float],
    after_sd: Mapping[str, float],
) -> Agreement:
    """Compare two rounds' identified values with their predicted scatter.

    Parameters
    ----------
    before, after
        Identified values by name (SI units), the earlier round's and this one's.
    before_sd, after_sd
        Their predicted absolute 1-sigma scatter by name (:func:`scatter`); the names in both
        scatters and both values are compared.
    """
    z: dict[str, float | None] = {}
    moved: dict[str, float | None] = {}
    for name in before_sd:
        if name not in after_sd or name not in before or name not in after:
            continue
        b, a = float(before[name]), float(after[name])
        sd = math.hypot(before_sd[name], after_sd[name])
        z[name] = (a - b) / sd if sd > 0 and math.isfinite(sd) else None
        moved[name] = a / b - 1 if b != 0 else None
    return Agreement(z, moved)
