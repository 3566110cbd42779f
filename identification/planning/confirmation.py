"""Do the profile intervals confirm the precision the linearised prediction says is reached?

The plan's precision is linearised: eq. (17)'s information at the identified parameters, the
curvature of one basin. Where the objective is far from quadratic it promises what the data do
not hold. Measured on the campaign trial's truth 5 (its four rounds regenerated, 2026-11-29):
eq. (17) over the rounds' runs has two optima of the DMF friction at +5.6 % and +37 % of the
truth, 1.0530 and 1.0518, and the search, warm-started from round 1's +121 %, ended at the
second; the linearised prediction there was 14 % at two sigma for a target of 20 %, so the
campaign stopped ``targets_met``. The friction's profile over the same runs gives the 95 %
interval 0.165-0.340 N*m around 0.262 (the truth 0.191): -37 / +30 %, the valley the curvature
at either optimum cannot see.

A profile-likelihood interval (95 %, about two sigma: what a target at
:data:`~dtid.identification.planning.design.SIGMAS` sigma asks of) therefore has the last
word on a target the prediction says is met: the target is **confirmed** when the interval is
closed on both sides and its wider side from the estimate, relative to the value the precision
was predicted for (the estimate but where that is near 0), lies within the target.
Where it is not, the target stays unmet, and where the interval is closed the next test is
planned for the linearised prediction scaled by what the interval showed it to be off by
(:attr:`IntervalCheck.planning_target_percent`; an open interval reaches the search's bound,
which says nothing of the factor).

An identification without a parameter's profile may hold its target test instead
(:mod:`dtid.identification.uncertainty.target_test`, the worker's in an adaptive campaign: the
likelihood-ratio test at the target's two ends, at a fraction of a profile's cost): it confirms
the target when both ends are rejected, and where one is not, it follows the interval beyond
that end to size the next round.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from dtid.errors import ConfigError

PROFILE = "profile"
TARGET_TEST = "target test"


@dataclass(frozen=True)
class IntervalCheck:
    """One target against the parameter's profile interval.

    Attributes
    ----------
    name
        Setup-4 parameter name.
    estimate
        The identified value, SI units.
    reference
        The value the percentages are of, SI units: the one the precision was predicted for
        (the estimate, or where that is near 0, as the friction at its bound often is, the value
        the planning put in its place: :func:`~dtid.identification.planning.design.planning_prior`).
    interval
        The 95 % profile interval (lower, upper), SI units; None on a side where it does not
        close.
    box
        The ends of the profile's grid (the search's bounds), SI units: an open side reaches
        at least to them.
    target_percent
        The target, % at two sigma.
    predicted_percent
        The linearised prediction for the runs recorded, % at two sigma (the worst vehicle
        planned for).
    method
        Where the interval comes from: ``profile`` (the parameter's profile) or ``target
        test`` (the likelihood-ratio test at the target's ends, followed beyond an end not
        rejected).
    """

    name: str
    estimate: float
    reference: float
    interval: tuple[float | None, float | None]
    box: tuple[float, float]
    target_percent: float
    predicted_percent: float
    method: str = PROFILE

    @property
    def closed(self) -> bool:
        """Whether the interval closes on both sides."""
        return None not in self.interval

    @property
    def half_width_percent(self) -> float:
        """The interval's wider side from the estimate, % of :attr:`reference`; an open side
        counts to the box's end (the figure is then a lower bound)."""
        lower = self.box[0] if self.interval[0] is None else self.interval[0]
        upper = self.box[1] if self.interval[1] is None else self.interval[1]
        return 100.0 * max(self.estimate - lower, upper - self.estimate, 0.0) / self.reference

    @property
    def confirms(self) -> bool:
        """Whether the interval is closed and within the target."""
        return self.closed and self.half_width_percent <= self.target_percent

    @property
    def planning_target_percent(self) -> float:
        """The linearised precision the next test must reach for the interval to meet the
        target: the target scaled by prediction over interval where a closed interval is the
        wider (the prediction was optimistic by that factor), else the target, %. An open
        interval's width is the box's, not the data's: it is not scaled by."""
        width = self.half_width_percent
        if self.confirms or not self.closed or width <= self.predicted_percent:
            return self.target_percent
        return self.target_percent * self.predicted_percent / width

    def reason(self) -> str:
        """Why the target is not confirmed (empty when it is)."""
        if self.confirms:
            return ""
        lower, upper = ("open" if v is None else f"{v:.4g}" for v in self.interval)
        width, target, predicted = (
            self.half_width_percent,
            self.target_percent,
            self.predicted_percent,
        )
        source = (
            "profile interval"
            if self.method == PROFILE
            else "interval by the likelihood-ratio test at the target's ends"
        )
        span = (
            f"its 95 % {source} {lower} to {upper} reaches {width:.1f} % from the "
            f"estimate {self.estimate:.4g}" + ("" if self.closed else " (open: at least that far)")
        )
        beyond = f"wider than the target of {target:g} %" if width > target else "not closed"
        said = (
            f"that the linearised prediction ({predicted:.1f} %) says is met"
            if predicted <= target
            else f"(the linearised prediction: {predicted:.1f} %)"
        )
        scaled = self.planning_target_percent
        then = ""
        if scaled < target:
            then = f"; the next test is planned for a linearised {scaled:.1f} %"
        return f"{span}, {beyond} {said}{then}"

    def as_dict(self) -> dict[str, Any]:
        """The plan JSON's ``intervals`` entry."""
        return {
            "estimate": self.estimate,
            "lower": self.interval[0],
            "upper": self.interval[1],
            "half_width_percent": round(self.half_width_percent, 2),
            "target_percent": self.target_percent,
            "predicted_percent": round(self.predicted_percent, 2),
            "confirms": self.confirms,
            "method": self.method,
        }


def interval_checks(
    identification: Mapping[str, Any],
    targets: Mapping[str, float],
    predicted_percent: Mapping[str, float],
    reference: Mapping[str, float],
) -> tuple[IntervalCheck, ...]:
    """Each targeted parameter's check, from an identification's JSON document (``dtid
    identify --json``, the worker's ``result``): from its profile, else from its target test;
    none where it holds neither.

    Parameters
    ----------
    identification
        The document: ``parameters``, ``intervals``, ``profiles`` and ``target_tests`` are read.
    targets
        Targets by parameter name, % at two sigma.
    predicted_percent
        The linearised prediction for the runs the identification used, by name, % at two
        sigma.
    reference
        The value each prediction is relative to, by name, SI units
        (:attr:`IntervalCheck.reference`).

    Raises
    ------
    ConfigError
        If an interval names a parameter the document gives no value or profile for.
    """
    intervals = identification.get("intervals") or {}
    profiles = identification.get("profiles") or {}
    tests = identification.get("target_tests") or {}
    values = identification.get("parameters") or {}
    checks = []
    for name, target in targets.items():
        if name not in predicted_percent or name not in reference:
            continue
        try:
            if name in intervals:
                method, ends = PROFILE, intervals[name]
                grid = [float(v) for v in profiles[name]["values"]]
            elif name in tests:
                method, ends = TARGET_TEST, tests[name]["interval"]
                grid = [float(v) for v in tests[name]["bounds"]]
            else:
                continue
            estimate = float(values[name])
        except (KeyError, TypeError, ValueError) as error:
            raise ConfigError(
                f"the identification's interval of {name} has no value, profile or target test "
                f"beside it ({error}); give the JSON dtid identify wrote"
            ) from None
        checks.append(
            IntervalCheck(
                name,
                estimate,
                float(reference[name]),
                (ends.get("lower"), ends.get("upper")),
                (min(grid), max(grid)),
                float(target),
                float(predicted_percent[name]),
                method,
            )
        )
    return tuple(checks)
