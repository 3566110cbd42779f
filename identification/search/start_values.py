"""Start values from what the frequency response itself says (sections IV-A and V).

* J_sum: below the first mode |G_DRV| = 1/(J_sum omega) (eq. 18 as s -> 0, the engine's stroke
  hold removed); the prior's J_sum is kept as a second start.
Stiffness and free play are not started from eq. (23): it needs the torque amplitude across the
DMF spring at resonance, which is not the test amplitude (it depends on the damping and on the
play itself), and reading it from the FRF gave start values off by a factor of two on the
reference vehicle. Everything but J_sum comes from the prior.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dtid.identification.frf.closed_loop import FrfEstimate
from dtid.identification.frf.sensor_response import stroke_hold_gain
from dtid.identification.search.parameterization import theta_from_parameters
from dtid.simulator.parameters import DrivetrainParameters

LOW_BAND_FRACTION = 0.3
"""J_sum is read below this fraction of the DMF resonance frequency."""


def dmf_resonance_hz(estimate: FrfEstimate) -> float:
    """Frequency of the strongest resonance: the peak of |G_DRV| * omega, Hz."""
    f = estimate.frequency_hz
    return float(f[np.argmax(estimate.drv_db + 20 * np.log10(f))])


def total_inertia(estimate: FrfEstimate) -> float | None:
    """J_sum from the low-frequency asymptote of |G_DRV|, kg*m^2 (None without low bins).

    Read well below the DMF resonance: its anti-resonance (eq. 19) sits at sqrt(x) times the
    resonance and lowers |G_DRV| long before it.
    """
    f = estimate.frequency_hz
    low = f < LOW_BAND_FRACTION * dmf_resonance_hz(estimate)
    if low.sum() < 2:
        return None
    drv = estimate.drv[low] / stroke_hold_gain(f[low], estimate.speed_rpm)
    return float(np.median(1.0 / (drv * 2 * np.pi * f[low])))


def start_thetas(
    estimates: Sequence[FrfEstimate], prior: DrivetrainParameters
) -> list[dict[str, float]]:
    """Setup-4 start values: the prior with J_sum from the FRFs' low-frequency asymptote, and the
    prior itself.

    Both join the search's initial population. The asymptote often rests on the two or three
    bins below 0.3 times the DMF resonance that a chirp from 1 Hz leaves; where frames were lost
    or came late there, it was measured 30 % high, and a search that had only that start missed
    the optimum; the prior is kept as a start of its own.

    Parameters
    ----------
    estimates
        The identification runs' FRFs.
    prior
        Prior parameter set.
    """
    theta = theta_from_parameters(prior)
    inertias = [j for j in (total_inertia(e) for e in estimates) if j is not None]
    if not inertias:
        return [theta]
    return [{**theta, "J_sum": float(np.median(inertias))}, theta]
