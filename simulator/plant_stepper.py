"""The plant advanced in segments of simulated time, for a vehicle that runs in real time.

:func:`dtid.simulator.simulate.simulate` runs a whole test against a known request table; a virtual
vehicle does not know its requests in advance. :class:`PlantStepper` keeps the kernel's state
vector and advances it segment by segment with the test torque the ECU holds at that moment,
through the same numba kernel (:func:`dtid.simulator.kernel.advance`), so the physics is the
simulator's own.
"""

from __future__ import annotations

import numpy as np

from dtid.simulator.kernel import (
    S_T,
    STATUS_BUFFER_FULL,
    STATUS_OK,
    Job,
    advance,
    initial_state,
)
from dtid.simulator.mechanisms import kernel_parameters
from dtid.simulator.parameters import DrivetrainParameters
from dtid.simulator.simulate import SimulationOptions, output_capacity, substeps


class PlantStepper:
    """One drivetrain with its engine, idle controller and sensors, advanced on demand.

    Parameters
    ----------
    parameters
        The drivetrain.
    options
        Engine, controller and noise (realistic by default).
    seed
        Seed of the combustion variation and sensor noise.
    """

    def __init__(
        self,
        parameters: DrivetrainParameters,
        options: SimulationOptions | None = None,
        seed: int = 0,
    ) -> None:
        self.options = options or SimulationOptions()
        self.parameters = parameters
        self._params = kernel_parameters(parameters.as_array(), self.options.effects)
        self._loop = self.options.loop(np.zeros(1), np.zeros(1))
        self._n_sub = substeps(self._params, self.options.controller)
        self._rng = np.random.default_rng(seed)
        self._state = initial_state(self._params, self._loop, 0.0)
        self.stalled = False

    @property
    def time_s(self) -> float:
        """Simulated time of the plant, s."""
        return float(self._state[S_T])

    def set_setpoint(self, setpoint_rpm: float) -> None:
        """Change the idle controller's set-point, rpm (a disturbance for fault tests)."""
        self._loop = self._loop._replace(reference=np.array([setpoint_rpm], dtype=np.float64))

    def advance(self, t_end: float, test_nm: float) -> tuple[np.ndarray, np.ndarray]:
        """Advance to ``t_end`` with the ECU holding the test torque ``test_nm``.

        Parameters
        ----------
        t_end
            Simulated time to reach, s.
        test_nm
            Test torque the ECU adds to its controller output over the whole segment, N*m.

        Returns
        -------
        speed, torque
            The segment's speed events (n, 5) and stroke events (m, 3) in the kernel's columns
            (:data:`dtid.simulator.kernel.SPEED_COLUMNS`,
            :data:`dtid.simulator.kernel.TORQUE_COLUMNS`). Empty once the engine has stalled or run
            away (:attr:`stalled`).
        """
        duration = t_end - self.time_s
        if self.stalled or duration <= 0:
            return np.empty((0, 5)), np.empty((0, 3))
        n_speed_max, n_stroke_max = output_capacity(duration, self.options.controller)
        out_speed = np.empty((n_speed_max, 5))
        out_torque = np.empty((n_stroke_max, 3))
        loop = self._loop._replace(
            request_t=np.array([self.time_s]), request_nm=np.array([float(test_nm)])
        )
        job = Job(
            self._params,
            1.0,
            self._n_sub,
            self._rng.standard_normal(n_stroke_max),
            self._rng.standard_normal(n_speed_max),
            self._rng.standard_normal(n_stroke_max),
            out_speed,
            out_torque,
        )
        n_speed, n_torque, status = advance(self._state, loop, job, t_end)
        if status == STATUS_BUFFER_FULL:
            raise RuntimeError("plant stepper: output buffer too small for the segment")
        self.stalled = status != STATUS_OK
        return out_speed[:n_speed], out_torque[:n_torque]
