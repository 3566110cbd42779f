"""From measured tests to an identification report: search, profiles, JSON (``dtid identify``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from identification.identify import (
    Identification,
    Objective,
    Progress,
    SearchSettings,
    engine_gain,
    identify,
    split_runs,
)
from identification.parameterization import THETA_UNITS, Parameterization
from identification.profile import Profile, profile
from identification.start_values import start_theta
from identification.test_setup import MeasuredTest
from simulator.parameters import DrivetrainParameters

OPERATING_POINT = ("K", "T_loss")
"""Parameters measured before the drivetrain fit (eq. 24 and the idle torque); fixable too."""


@dataclass(frozen=True)
class IdentificationReport:
    """An identification with its profiles.

    Attributes
    ----------
    identification
        The search's result.
    profiles
        Profile of each free parameter (empty when profiles were not asked for).
    fixed
        Parameters held at a value, by name (setup-4 names, K, T_loss).
    gain, t_loss
        K and T_loss used, measured or fixed.
    """

    identification: Identification
    profiles: Mapping[str, Profile]
    fixed: Mapping[str, float]
    gain: float
    t_loss: float

    def as_dict(self) -> dict[str, object]:
        """The JSON document of ``dtid identify``."""
        result = self.identification
        p = result.parameters
        parameters = {**result.theta, "J1": p.J1, "J2": p.J2, "J3": p.J3, "K": self.gain}
        intervals = {
            name: {"lower": prof.interval[0], "upper": prof.interval[1]}
            for name, prof in self.profiles.items()
        }
        return {
            "parameters": parameters,
            "units": {**THETA_UNITS, "J1": "kg*m^2", "J2": "kg*m^2", "J3": "kg*m^2", "K": "1"},
            "intervals": intervals,
            "nrmse": {"fit": result.fit_nrmse, "validation": result.validation_nrmse},
            "identifiable": {name: prof.verdict for name, prof in self.profiles.items()},
            "fixed": dict(self.fixed),
            "T_loss": self.t_loss,
            "objective": result.objective,
            "parameter_sets": result.parameter_sets,
            "seconds": result.seconds,
        }


def run_identification(
    tests: Sequence[MeasuredTest],
    prior: DrivetrainParameters,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    identify_amplitudes: Sequence[float] | None = None,
    settings: SearchSettings | None = None,
    profile_points: int = 5,
    progress: Progress | None = None,
) -> IdentificationReport:
    """Identify from measured tests and profile every free parameter.

    Parameters
    ----------
    tests
        The recordings' tests.
    prior
        Centre of the default +-100 % bounds and source of start values the data do not give.
    fixed
        Values to hold, by setup-4 name or K / T_loss.
    bounds
        Explicit bounds by setup-4 name.
    identify_amplitudes
        Amplitudes that identify (default: the two largest); the rest validate.
    settings
        Search budget and seed.
    profile_points
        Grid points per profile; 0 skips the profiles (no intervals, no verdicts).
    progress
        Progress callback.
    """
    fixed = dict(fixed or {})
    operating = {name: fixed.pop(name) for name in OPERATING_POINT if name in fixed}
    gain = operating["K"] if "K" in operating else engine_gain(tests)
    t_loss = (
        operating["T_loss"]
        if "T_loss" in operating
        else float(np.mean([t.idle_torque_nm for t in tests]))
    )
    par = Parameterization.around(prior, t_loss, gain, fixed=fixed, bounds=bounds)
    ident, valid = split_runs(tests, identify_amplitudes)
    start = start_theta(
        [t.estimates[i] for t, runs in zip(tests, ident, strict=True) for i in runs], prior
    )
    result = identify(tests, par, ident, valid, settings, progress, start=start)
    profiles: dict[str, Profile] = {}
    if profile_points:
        used = [(t, runs) for t, runs in zip(tests, ident, strict=True) if runs]
        measured_db = [t.estimates[i].drv_db for t, runs in used for i in runs]
        objective = Objective(
            par,
            [t.model_test(runs) for t, runs in used],
            [[t.estimates[i].drv_db for i in runs] for t, runs in used],
        )
        for step, name in enumerate(par.free):
            if progress:
                progress("profile", step + 1, len(par.free), result.objective)
            profiles[name] = profile(
                objective,
                measured_db,
                name,
                result.unit,
                points=profile_points,
                seed=(settings or SearchSettings()).seed,
            )
    return IdentificationReport(result, profiles, {**fixed, **operating}, gain, t_loss)
