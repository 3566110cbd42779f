"""Linear models of the drivetrain: the analytic references of the identification.

* :func:`three_mass_frf`: eq. (6) without free play and friction, the frequency response from the
  torque on J1 to its speed omega_1, (rad/s)/(N*m).
* :func:`two_mass_frf`: the reduced model of eq. (18), including the engine gain K.
* :func:`two_mass_characteristics`: the minimal description of eq. (19).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtid.simulator.parameters import DrivetrainParameters


def three_mass_matrices(p: DrivetrainParameters) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inertia, damping and stiffness matrices of the linear three-mass chain (SI units)."""
    mass = np.diag([p.J1, p.J2, p.J3])
    damping = np.array(
        [[p.d12, -p.d12, 0.0], [-p.d12, p.d12 + p.d23, -p.d23], [0.0, -p.d23, p.d23]]
    )
    stiffness = np.array(
        [[p.c12, -p.c12, 0.0], [-p.c12, p.c12 + p.c23, -p.c23], [0.0, -p.c23, p.c23]]
    )
    return mass, damping, stiffness


def three_mass_frf(p: DrivetrainParameters, frequency_hz: np.ndarray) -> np.ndarray:
    """Complex frequency response omega_1 / T_1 of the linear three-mass chain, (rad/s)/(N*m).

    Free play and Coulomb friction are left out (the couplings are the linear springs and
    dampers); the response is that of the plant in open loop.

    Parameters
    ----------
    p
        Parameter set (eps12, eps23, Tc12, T_loss and K are not used).
    frequency_hz
        Frequencies, Hz (non-zero).
    """
    mass, damping, stiffness = three_mass_matrices(p)
    s = 2j * np.pi * np.asarray(frequency_hz, dtype=np.float64)
    dynamic = s[:, None, None] ** 2 * mass + s[:, None, None] * damping + stiffness
    unit = np.zeros((len(s), 3, 1))
    unit[:, 0, 0] = 1.0
    return s * np.linalg.solve(dynamic, unit)[:, 0, 0]


def three_mass_modes(p: DrivetrainParameters) -> np.ndarray:
    """Undamped natural frequencies of the two elastic modes, Hz, ascending."""
    mass, _, stiffness = three_mass_matrices(p)
    eigen = np.linalg.eigvals(np.linalg.solve(mass, stiffness))
    return np.sort(np.sqrt(np.abs(eigen.real)))[1:] / (2 * np.pi)


def two_mass_frf(
    frequency_hz: np.ndarray, j_sum: float, x: float, c: float, d: float, gain: float
) -> np.ndarray:
    """Eq. (18): speed response of two masses J1 = x J_sum, J2 = (1-x) J_sum to K times a torque.

    Parameters
    ----------
    frequency_hz
        Frequencies, Hz (non-zero).
    j_sum
        J_sum = J1 + J2, kg*m^2.
    x
        Mass ratio J1 / J_sum, 1.
    c, d
        Coupling stiffness, N*m/rad, and damping, N*m*s/rad.
    gain
        Engine gain K, 1.

    Returns
    -------
    numpy.ndarray
        Complex G(j omega), (rad/s)/(N*m).
    """
    s = 2j * np.pi * np.asarray(frequency_hz, dtype=np.float64)
    j1, j2 = x * j_sum, (1 - x) * j_sum
    numerator = 1 + s * d / c + s**2 * j2 / c
    denominator = 1 + s * d / c + s**2 * j1 * j2 / (j_sum * c)
    return gain / (s * j_sum) * numerator / denominator


@dataclass(frozen=True)
class TwoMassCharacteristics:
    """The minimal parameters of eq. (19) that fix |G| of the two-mass model.

    Attributes
    ----------
    low_gain
        K / J_sum: |G| * omega at low frequency, 1/(kg*m^2).
    high_gain
        K / (x J_sum): |G| * omega at high frequency, 1/(kg*m^2).
    omega_d, damping_d
        Natural frequency, rad/s, and damping ratio of the denominator (resonance).
    omega_n, damping_n
        Natural frequency, rad/s, and damping ratio of the numerator (anti-resonance).
    """

    low_gain: float
    high_gain: float
    omega_d: float
    damping_d: float
    omega_n: float
    damping_n: float


def two_mass_characteristics(
    j_sum: float, x: float, c: float, d: float, gain: float
) -> TwoMassCharacteristics:
    """Eq. (19): asymptotes, natural frequencies and damping ratios of eq. (18).

    Scaling J_sum, c, d and K by one factor leaves all six unchanged: only x is structurally
    identifiable from |G| (section IV-A).
    """
    omega_d = np.sqrt(c / ((1 - x) * j_sum * x))
    damping_d = 0.5 * np.sqrt(d**2 / ((1 - x) * x * j_sum * c))
    return TwoMassCharacteristics(
        low_gain=gain / j_sum,
        high_gain=gain / (x * j_sum),
        omega_d=float(omega_d),
        damping_d=float(damping_d),
        omega_n=float(omega_d * np.sqrt(x)),
        damping_n=float(damping_d * np.sqrt(x)),
    )
