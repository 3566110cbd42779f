"""Engine torque of a four-cylinder four-stroke engine, paper eqs. (1)-(5), as angle tables.

Every term of eq. (1) is periodic in crank angle, so it is tabulated once per parameter set on the
angle grid of :mod:`dtid.simulator.angle_grid` (120 steps per working cycle of 4*pi) and costs a
lookup per integration step. Entry k holds the term's mean over step k (the trapezoid of its values
at the step's two ends), which the integrator applies over the whole step; reading the value at the
step's start instead biases |G_DRV| by 0.15 dB against a continuous-time integration (measured in
``benchmarks/bench_simulator.py``):

* combustion, eq. (2): per-cylinder shape g(phi) / N_cyl, to be multiplied by the mean torque T_m,i
  each cylinder holds for its working cycle (the shape is a truncated rect of height 8 over the
  first pi/2 after the cylinder's firing TDC, mean 1);
* compression and expansion, eq. (4): the sum over cylinders, N*m, independent of speed and load;
* oscillating masses, eq. (5): the sum over cylinders divided by omega^2, N*m*s^2/rad^2.

Cylinder i (numbered in firing order, 0..3) sees the crank angle phi_1 - i*pi, its firing TDC at 0.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from dtid.simulator.angle_grid import N_CYL, STEP_RAD, STEPS_PER_CYCLE, STEPS_PER_STROKE

COMBUSTION_ORDERS = np.arange(0.5, 4.01, 0.5)
"""Orders k of the Fourier series of eq. (2)."""


@dataclass(frozen=True)
class EngineGeometry:
    """Crank-train data of the reference engine (a 1.8 l four-cylinder petrol engine at idle).

    Attributes
    ----------
    bore_m
        Cylinder bore, m (82.5 mm).
    crank_radius_m
        Crank radius r, m (half of the 84.2 mm stroke).
    rod_length_m
        Connecting-rod length l, m (144 mm, lambda_P = r/l = 0.29).
    compression_ratio
        Geometric compression ratio (V_z / V_c = 9.6).
    manifold_pressure_pa
        Intake manifold pressure p_l at idle, Pa (0.35 bar absolute, throttled).
    isentropic_exponent
        kappa of the cylinder charge during compression and expansion (1.3).
    oscillating_mass_kg
        m_osc: piston, pin and rings plus a third of the connecting rod, kg (0.55 kg).
    """

    bore_m: float = 0.0825
    crank_radius_m: float = 0.0421
    rod_length_m: float = 0.144
    compression_ratio: float = 9.6
    manifold_pressure_pa: float = 0.35e5
    isentropic_exponent: float = 1.3
    oscillating_mass_kg: float = 0.55


@dataclass(frozen=True)
class EngineTables:
    """Engine torque terms on the angle grid (``STEPS_PER_CYCLE`` points from phi_1 = 0).

    Attributes
    ----------
    combustion_shape
        g(phi)/N_cyl of eq. (2) for cylinder 0; cylinder i uses the index shifted by 30*i. Times the
        cylinder's mean torque T_m,i it gives that cylinder's combustion torque, N*m per N*m.
    compression
        Sum of eq. (4) over the cylinders, N*m.
    inertia
        Sum of eq. (5) over the cylinders divided by omega_1^2, N*m*s^2/rad^2.
    """

    combustion_shape: np.ndarray
    compression: np.ndarray
    inertia: np.ndarray

    @classmethod
    def disabled(cls) -> EngineTables:
        """Tables of an engine without pulsation: each stroke delivers its mean torque.

        Each cylinder's shape is 1 over its working stroke (pi after its firing TDC) and 0
        elsewhere, so the engine torque is the current stroke's T_m, held for the stroke: the
        continuous hold of :func:`dtid.identification.frf.sensor_response.stroke_hold_gain`.
        """
        stroke = np.where(np.arange(STEPS_PER_CYCLE) < STEPS_PER_STROKE, 1.0, 0.0)
        zero = np.zeros(STEPS_PER_CYCLE)
        return cls(combustion_shape=stroke, compression=zero, inertia=zero)


def combustion_shape(phi: np.ndarray) -> np.ndarray:
    """Per-cylinder combustion torque per unit mean torque, eq. (2).

    Parameters
    ----------
    phi
        Cylinder crank angle, rad, zero at its firing TDC.

    Returns
    -------
    numpy.ndarray
        T_cmb / T_m: the truncated Fourier series of a rect of height N_cyl * 2 over
        [0, pi/2], divided by N_cyl; its mean over 4*pi is 1/N_cyl.
    """
    k = COMBUSTION_ORDERS[:, None]
    phase = np.pi / 2 * (1 - k / 2)
    series = 8 / (np.pi * k) * np.sin(k * np.pi / 4) * np.sin(k * phi[None, :] + phase)
    return (1 + series.sum(axis=0)) / N_CYL


def piston_travel(phi: np.ndarray, geometry: EngineGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Piston travel from TDC s(phi), m, and its angle derivative ds/dphi, m/rad."""
    r, lam = geometry.crank_radius_m, geometry.crank_radius_m / geometry.rod_length_m
    root = np.sqrt(1 - (lam * np.sin(phi)) ** 2)
    s = r * (1 - np.cos(phi)) + geometry.rod_length_m * (1 - root)
    ds = r * np.sin(phi) * (1 + lam * np.cos(phi) / root)
    return s, ds


def compression_torque(phi: np.ndarray, geometry: EngineGeometry) -> np.ndarray:
    """Compression and expansion torque of one cylinder without combustion, eq. (4), N*m.

    The charge is compressed isentropically from the manifold pressure at bottom dead centre; the
    law holds over the compression and expansion strokes (phi in [-pi, pi) around the firing TDC)
    and the torque is zero over the gas-exchange strokes. Symmetric about TDC, it has zero mean.
    """
    area = np.pi / 4 * geometry.bore_m**2
    swept = area * 2 * geometry.crank_radius_m
    v_c = swept / (geometry.compression_ratio - 1)
    v_z = v_c + swept
    wrapped = (phi + np.pi) % (4 * np.pi) - np.pi
    s, ds = piston_travel(wrapped, geometry)
    kappa = geometry.isentropic_exponent
    pressure = geometry.manifold_pressure_pa * (v_z / (v_c + area * s)) ** kappa
    return np.where(wrapped < np.pi, area * pressure * ds, 0.0)


def inertia_coefficient(phi: np.ndarray, geometry: EngineGeometry) -> np.ndarray:
    """Oscillating-mass torque of one cylinder divided by omega^2, eq. (5), N*m*s^2/rad^2."""
    lam = geometry.crank_radius_m / geometry.rod_length_m
    bracket = (
        lam / 4 * np.sin(phi)
        - 0.5 * np.sin(2 * phi)
        - 3 * lam / 4 * np.sin(3 * phi)
        - (lam / 2) ** 2 * np.sin(4 * phi)
    )
    return geometry.oscillating_mass_kg * geometry.crank_radius_m**2 * bracket


@functools.cache
def engine_tables(geometry: EngineGeometry | None = None, step_mean: bool = True) -> EngineTables:
    """Tabulate the engine torque terms of eq. (1) on the angle grid.

    Computed once per geometry and shared by every simulation (the identification replays
    thousands of parameter sets on one engine; tabulating per call cost 3 % of a profile's
    time): the tables are not to be written to.

    Parameters
    ----------
    geometry
        Crank-train data; the reference engine when omitted.
    step_mean
        True: entry k is the mean over step k, as the angle-step integrator applies it. False:
        entry k is the value at grid angle k (for an integrator that interpolates).

    Returns
    -------
    EngineTables
        The three tables, ``STEPS_PER_CYCLE`` points each.
    """
    geometry = geometry or EngineGeometry()
    phi1 = np.arange(STEPS_PER_CYCLE) * STEP_RAD
    compression = np.zeros(STEPS_PER_CYCLE)
    inertia = np.zeros(STEPS_PER_CYCLE)
    for cylinder in range(N_CYL):
        phi = phi1 - cylinder * STEPS_PER_STROKE * STEP_RAD
        compression += compression_torque(phi, geometry)
        inertia += inertia_coefficient(phi, geometry)
    shape = combustion_shape(phi1)
    if not step_mean:
        return EngineTables(shape, compression, inertia)
    return EngineTables(_step_mean(shape), _step_mean(compression), _step_mean(inertia))


def _step_mean(values: np.ndarray) -> np.ndarray:
    """Trapezoid mean of a periodic table over each step: (v[k] + v[k+1]) / 2."""
    return 0.5 * (values + np.roll(values, -1))
