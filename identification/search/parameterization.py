"""The identified parameters of setup 4 and their normalisation (paper section IV-B).

The optimiser works on theta = (J_sum, x1, x12, c12, c23, d12, d23, Tc12, eps12, eps23), each
normalised to [0, 1] within its bounds, with x1 = J1/(J1+J2) and x12 = (J1+J2)/(J1+J2+J3). T_loss
and K are not identified by the drivetrain fit: K comes from |G_ENG| (eq. 24) and T_loss from the
mean torque at idle. Any subset of theta can be fixed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from dtid.errors import ConfigError
from dtid.simulator.parameters import INDEX, UNITS, DrivetrainParameters

THETA_NAMES: tuple[str, ...] = (
    "J_sum",
    "x1",
    "x12",
    "c12",
    "c23",
    "d12",
    "d23",
    "Tc12",
    "eps12",
    "eps23",
)
THETA_UNITS: dict[str, str] = {
    "J_sum": UNITS["J1"],
    "x1": "1",
    "x12": "1",
    **{name: UNITS[name] for name in ("c12", "c23", "d12", "d23", "Tc12", "eps12", "eps23")},
}
"""Units of the setup-4 parameters: the simulator's (:data:`dtid.simulator.parameters.UNITS`),
the mass ratios dimensionless."""
PRIOR_SPAN = 1.0
"""Default bounds: the prior value times (1 - span, 1 + span), i.e. +-100 % (section IV-B)."""
PASSENGER_CAR_RANGES: dict[str, tuple[float, float]] = {
    "x1": (0.05, 0.95),  # J1 / (J1 + J2): DMF primary side against secondary side
    "x12": (0.05, 0.99),  # (J1 + J2) / J_sum: J3 in neutral is at least 1 % of the total
    "c12": (0.0, 1000.0),  # N*m/rad: first-stage DMF arc springs, up to 17 N*m/deg
    "c23": (0.0, 300.0),  # N*m/rad: clutch-disc pre-damper and input shaft, up to 5 N*m/deg
    "d12": (0.0, 3.0),  # N*m*s/rad: DMF grease and arc-spring rubbing
    "d23": (0.0, 1.0),  # N*m*s/rad: pre-damper damping
    "Tc12": (0.0, 4.0),  # N*m: DMF base friction at small angles
    "eps12": (0.0, 0.1),  # rad: DMF free angle, up to 5.7 deg
    "eps23": (0.0, 0.06),  # rad: clutch-hub spline and input-gear play, up to 3.4 deg
}
"""Where a passenger car's drivetrain at idle in neutral may lie, SI units: the default search
box covers these ranges as well as the prior +-100 % (one reference car's +-100 % leaves out
cars whose free plays or friction are 2-5 times its own, and the search cannot find a truth
outside its box). J_sum is not listed: the FRF's low-frequency asymptote starts it."""
MIN_INERTIA_FRACTION = 0.05
"""Lower bound on J_sum (and on K where it is free) as a fraction of its prior, and the margin
keeping x1, x12 in (0, 1): a vanishing inertia or engine gain cannot idle, so +-100 % bounds are
narrowed there."""
EDGE_TOLERANCE = 1e-3
"""A result within this share of a parameter's box width from a bound ended on the box's edge
(:meth:`Parameterization.at_edges`): the search's stages clip at the bounds, so a parameter
pushed against one ends on it."""


MASS_RATIOS = ("x1", "x12")
"""The setup-4 parameters that are shares of an inertia: strictly between 0 and 1."""


def check_theta_value(name: str, value: float, source: str) -> None:
    """Refuse a setup-4 value outside its physical domain.

    Every value is finite and >= 0, J_sum > 0 and the mass ratios x1, x12 lie strictly between
    0 and 1 (at 0 or 1 an inertia vanishes; beyond, one is negative).

    Parameters
    ----------
    name
        One of :data:`THETA_NAMES`.
    value
        The value in :data:`THETA_UNITS`.
    source
        Where the value came from, for the message (``--fix x1=1.5``).

    Raises
    ------
    ConfigError
        Naming the value, its meaning and the domain.
    """
    unit = THETA_UNITS[name]
    if not math.isfinite(value) or value < 0:
        raise ConfigError(f"{source}: {name} must be a finite number >= 0 {unit}, got {value}")
    if name == "J_sum" and value == 0:
        raise ConfigError(f"{source}: J_sum, the total inertia, must be > 0 {unit}")
    if name in MASS_RATIOS and not 0 < value < 1:
        share = "J1/(J1+J2)" if name == "x1" else "(J1+J2)/(J1+J2+J3)"
        raise ConfigError(
            f"{source}: {name} = {value:g} is the mass ratio {share}: it lies strictly between "
            "0 and 1"
        )


def passenger_car_bounds(
    prior: DrivetrainParameters, span: float = PRIOR_SPAN
) -> dict[str, tuple[float, float]]:
    """The default search box: the prior +- ``span`` widened to :data:`PASSENGER_CAR_RANGES`
    (the mass ratios: those ranges), by setup-4 name, SI units (J_sum is left to the span)."""
    centre = theta_from_parameters(prior)
    box = {
        name: (min(centre[name] * (1 - span), lo), max(centre[name] * (1 + span), hi))
        for name, (lo, hi) in PASSENGER_CAR_RANGES.items()
    }
    for ratio in ("x1", "x12"):  # a mass ratio's range is its physical one
        box[ratio] = PASSENGER_CAR_RANGES[ratio]
    return box


def theta_from_parameters(p: DrivetrainParameters) -> dict[str, float]:
    """The setup-4 parameters of a physical parameter set."""
    j12 = p.J1 + p.J2
    return {
        "J_sum": j12 + p.J3,
        "x1": p.J1 / j12,
        "x12": j12 / (j12 + p.J3),
        "c12": p.c12,
        "c23": p.c23,
        "d12": p.d12,
        "d23": p.d23,
        "Tc12": p.Tc12,
        "eps12": p.eps12,
        "eps23": p.eps23,
    }


def theta_to_arrays(theta: np.ndarray, t_loss: float, gain: float) -> np.ndarray:
    """Physical parameter arrays (n, 12) from setup-4 values (n, 10), SI units."""
    theta = np.atleast_2d(theta)
    j_sum, x1, x12 = theta[:, 0], theta[:, 1], theta[:, 2]
    out = np.empty((theta.shape[0], len(INDEX)))
    out[:, INDEX["J1"]] = j_sum * x12 * x1
    out[:, INDEX["J2"]] = j_sum * x12 * (1 - x1)
    out[:, INDEX["J3"]] = j_sum * (1 - x12)
    for name in ("c12", "c23", "d12", "d23", "Tc12", "eps12", "eps23"):
        out[:, INDEX[name]] = theta[:, THETA_NAMES.index(name)]
    out[:, INDEX["T_loss"]] = t_loss
    out[:, INDEX["K"]] = gain
    return out


@dataclass(frozen=True)
class Parameterization:
    """Bounds, fixed values and the [0, 1] normalisation of the free setup-4 parameters.

    Attributes
    ----------
    lower, upper
        Bounds of all ten theta values (ordered as :data:`THETA_NAMES`), SI units.
    fixed
        Values of the fixed parameters, by name.
    t_loss, gain
        T_loss (N*m) and K, held fixed (K only when ``gain_bounds`` is None).
    gain_bounds
        (lower, upper) to identify K as well, as the last free parameter (setup 1 of section IV-B,
        which shows why the product does not: K scales with J_sum, c and d).
    prior_inertias
        J1, J2, J3 of the prior, kg*m^2.
    modal
        Whether a free stiffness's coordinate is its mode's frequency (:meth:`theta`, the
        search's coordinates, :meth:`modal_coordinates`) rather than the stiffness itself.
    """

    lower: np.ndarray
    upper: np.ndarray
    fixed: Mapping[str, float]
    t_loss: float
    gain: float
    gain_bounds: tuple[float, float] | None = None
    prior_inertias: tuple[float, float, float] | None = None
    modal: bool = False

    @classmethod
    def around(
        cls,
        prior: DrivetrainParameters,
        t_loss: float,
        gain: float,
        fixed: Mapping[str, float] | None = None,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        span: float = PRIOR_SPAN,
        gain_bounds: tuple[float, float] | None = None,
    ) -> Parameterization:
        """Bounds of +-``span`` around a prior (narrowed where a value cannot idle).

        Parameters
        ----------
        prior
            Prior parameter set (the reference vehicle by default in the command line).
        t_loss, gain
            T_loss, N*m, and K, held fixed.
        fixed
            Parameters to hold at a value, by theta name.
        bounds
            Explicit (lower, upper) bounds by theta name, overriding the span.
        span
            Relative half-width of the default bounds.
        gain_bounds
            Bounds of K to identify it too (setup 1 only); None holds it at ``gain``.
        """
        fixed = dict(fixed or {})
        bounds = dict(bounds or {})
        for name in (*fixed, *bounds):
            if name not in THETA_NAMES:
                raise ConfigError(
                    f"unknown parameter {name!r}; the identified parameters are "
                    f"{', '.join(THETA_NAMES)}"
                )
        centre = theta_from_parameters(prior)
        lower = np.array([centre[n] * (1 - span) for n in THETA_NAMES])
        upper = np.array([centre[n] * (1 + span) for n in THETA_NAMES])
        lower[0] = max(lower[0], MIN_INERTIA_FRACTION * centre["J_sum"])
        for name in ("x1", "x12"):
            i = THETA_NAMES.index(name)
            lower[i] = max(lower[i], MIN_INERTIA_FRACTION)
            upper[i] = min(upper[i], 1 - MIN_INERTIA_FRACTION)
        for name, value in fixed.items():
            check_theta_value(name, value, f"fixed {name}")
        for name, (lo, hi) in bounds.items():
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
                raise ConfigError(
                    f"bounds of {name} must satisfy 0 <= lower < upper, got {lo}, {hi}"
                )
            if name in MASS_RATIOS:
                check_theta_value(name, lo, f"bounds of {name}")
                check_theta_value(name, hi, f"bounds of {name}")
            i = THETA_NAMES.index(name)
            lower[i], upper[i] = lo, hi
        return cls(
            np.maximum(lower, 0.0),
            upper,
            fixed,
            t_loss,
            gain,
            gain_bounds,
            (prior.J1, prior.J2, prior.J3),
        )

    def modal_coordinates(self) -> Parameterization:
        """The same box with each free stiffness's coordinate its mode's squared frequency at the
        prior's inertias (see :meth:`theta`): the search's coordinates."""
        return dataclasses.replace(self, modal=self.prior_inertias is not None)

    @property
    def free(self) -> tuple[str, ...]:
        """Names of the free parameters, in theta order (then K when it is free)."""
        theta = tuple(n for n in THETA_NAMES if n not in self.fixed)
        return (*theta, "K") if self.gain_bounds else theta

    def bounds_of(self, name: str) -> tuple[float, float]:
        """(lower, upper) of a free parameter, SI units."""
        if name == "K" and self.gain_bounds:
            return self.gain_bounds
        i = THETA_NAMES.index(name)
        return float(self.lower[i]), float(self.upper[i])

    def theta(self, unit: np.ndarray) -> np.ndarray:
        """Full theta (n, 10) from normalised free values (n, n_free) in [0, 1].

        With :attr:`modal` coordinates a free stiffness's coordinate is its mode's squared
        frequency at the prior's inertias, not the stiffness itself (:meth:`_modal_factors`; the
        stiffness is kept inside its bounds): moving the inertias leaves the coordinate's mode
        where it is, so the valleys along which an inertia and a stiffness trade (J3 and c23
        keeping the gear mode's frequency) run along the coordinates, where differential
        evolution's crossover can follow them.
        """
        unit = np.atleast_2d(unit)
        theta = np.empty((unit.shape[0], len(THETA_NAMES)))
        free = 0
        for i, name in enumerate(THETA_NAMES):
            if name in self.fixed:
                theta[:, i] = self.fixed[name]
            else:
                theta[:, i] = self.lower[i] + unit[:, free] * (self.upper[i] - self.lower[i])
                free += 1
        for name, factor in self._modal_factors(theta).items():
            i = THETA_NAMES.index(name)
            theta[:, i] = np.clip(theta[:, i] * factor, self.lower[i], self.upper[i])
        return theta

    def _modal_factors(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Per free stiffness, the factor from its coordinate's value to the stiffness: the mode's
        inertia term (1/J1 + 1/(J2 + J3) for the DMF, 1/J2 + 1/J3 for the gear coupling) at
        the prior's inertias over the one at each row's inertias (none without :attr:`modal`)."""
        if not self.modal or self.prior_inertias is None:
            return {}
        rows = theta_to_arrays(theta, 0.0, 1.0)
        centre = np.array([self.prior_inertias])
        terms = {
            "c12": lambda j: 1 / j[:, 0] + 1 / (j[:, 1] + j[:, 2]),
            "c23": lambda j: 1 / j[:, 1] + 1 / j[:, 2],
        }
        return {
            name: term(centre) / term(rows)
            for name, term in terms.items()
            if name not in self.fixed
        }

    def at_edges(self, theta: Mapping[str, float]) -> dict[str, str]:
        """The free parameters of a result (setup-4 values by name, SI units) that ended on an
        edge of the box the vehicle could lie beyond: ``"upper"``, or ``"lower"`` where the
        lower bound is above zero (zero is a physical end, not the box's). A stiffness is on
        its edge also where its search coordinate is (its mode's frequency, :meth:`theta`),
        within :data:`EDGE_TOLERANCE` of the box's width."""
        row = np.array([[theta[n] for n in THETA_NAMES]])
        coordinate = dict(zip(self.free, self.modal_coordinates().unit(row)[0], strict=True))
        edges = {}
        for name in self.free:
            if name == "K":
                continue
            lo, hi = self.bounds_of(name)
            position = (theta[name] - lo) / (hi - lo)
            if max(position, coordinate[name]) >= 1 - EDGE_TOLERANCE:
                edges[name] = "upper"
            elif lo > 0 and min(position, coordinate[name]) <= EDGE_TOLERANCE:
                edges[name] = "lower"
        return edges

    def unit(self, theta: np.ndarray, gain: float | None = None) -> np.ndarray:
        """Normalised free values (n, n_free) of a full theta (n, 10) (and K when it is free)."""
        theta = np.array(np.atleast_2d(theta), dtype=float)
        for name, factor in self._modal_factors(theta).items():
            theta[:, THETA_NAMES.index(name)] /= factor
        idx = [THETA_NAMES.index(n) for n in self.free if n != "K"]
        unit = (theta[:, idx] - self.lower[idx]) / (self.upper[idx] - self.lower[idx])
        if self.gain_bounds:
            lo, hi = self.gain_bounds
            column = np.full((theta.shape[0], 1), ((gain or self.gain) - lo) / (hi - lo))
            unit = np.hstack([unit, column])
        return unit

    def parameters(self, unit: np.ndarray) -> np.ndarray:
        """Physical parameter arrays (n, 12) from normalised free values."""
        unit = np.atleast_2d(unit)
        out = theta_to_arrays(self.theta(unit), self.t_loss, self.gain)
        if self.gain_bounds:
            lo, hi = self.gain_bounds
            out[:, INDEX["K"]] = lo + unit[:, -1] * (hi - lo)
        return out
