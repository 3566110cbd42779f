"""The CAN frames a simulated test puts on the vehicle bus, encoded through a signal map.

The engine ECU sends the filtered speed and the total torque request at every speed sample (pi/2
of crank angle) and the mean torque at the end of every working stroke; the tool sends the test
torque request every ``request_period_s`` (enabled during the chirps, with a 4-bit alive counter)
and its heartbeat at 10 Hz. Timestamps are simulated test time. Every message goes through
:meth:`dbc.VehicleInterface.encode`, so any DBC with a signal map receives the same test.
"""

from __future__ import annotations

import can
import numpy as np

from dtid.dbc.interface import VehicleInterface
from dtid.dbc.tool_state import HEARTBEAT_PERIOD_S, TOOL_CHIRP, TOOL_DONE, TOOL_SETTLING
from dtid.simulator.simulate import SimulationResult

_COUNTER_MODULO = {"speed": 1 << 16, "test_torque": 16}
"""Counter wrap per role (the product DBC's signal widths); 8 bits otherwise."""


def _counter(role: str, index: int) -> int:
    return index % _COUNTER_MODULO.get(role, 256)


def _extras(interface: VehicleInterface, role: str, **values: int) -> dict[str, int]:
    """Keep the extra signals the role's map entry names (another DBC may lack some)."""
    spec = interface.signal_map.roles[role]
    return {key: value for key, value in values.items() if getattr(spec, key, None)}


def simulation_frames(result: SimulationResult, interface: VehicleInterface) -> list[can.Message]:
    """Encode a simulated test as the frames of the vehicle bus, sorted by time.

    Parameters
    ----------
    result
        The simulated test.
    interface
        DBC and signal map to encode with; roles the map lacks are not sent.

    Returns
    -------
    list of can.Message
        Frames in time order.
    """
    present = set(interface.present_roles())
    ecu = EcuFrames(interface)
    frames = ecu.speed_frames(
        np.column_stack([result.speed_t, result.speed_rpm, result.torque_request_nm])
    )
    frames += ecu.stroke_frames(
        np.column_stack([result.torque_t, result.mean_torque_nm, result.cylinder])
    )
    chirps = result.plan.chirps
    if "test_torque" in present:
        for i, (t, nm) in enumerate(zip(result.request_t, result.test_torque_nm, strict=True)):
            enabled = int(any(c.start_s <= t < c.end_s for c in chirps))
            extras = _extras(
                interface, "test_torque", counter=_counter("test_torque", i), enable=enabled
            )
            frames.append(interface.encode("test_torque", nm, t, **extras))
    if "heartbeat" in present:
        for i, t in enumerate(np.arange(0.0, result.plan.end_s, HEARTBEAT_PERIOD_S)):
            if any(c.start_s <= t < c.end_s for c in chirps):
                state = TOOL_CHIRP
            elif t >= chirps[-1].end_s:
                state = TOOL_DONE
            else:
                state = TOOL_SETTLING
            extras = _extras(interface, "heartbeat", counter=_counter("heartbeat", i))
            frames.append(interface.encode("heartbeat", state, t, **extras))
    frames.sort(key=lambda frame: frame.timestamp)
    return frames


class EcuFrames:
    """Encode the engine ECU's frames as they happen, with their running counters.

    Parameters
    ----------
    interface
        DBC and signal map; roles the map lacks are not sent.
    """

    def __init__(self, interface: VehicleInterface) -> None:
        self.interface = interface
        present = set(interface.present_roles())
        self._speed = "speed" in present
        self._request = "torque_request" in present
        self._stroke = "mean_torque" in present
        self._n_speed = 0
        self._n_stroke = 0

    def speed_frames(self, rows: np.ndarray) -> list[can.Message]:
        """Frames of speed samples: rows of (t s, filtered speed rpm, T_ecu N*m)."""
        frames = []
        encode = self.interface.encode
        for t, rpm, request in rows:
            i = self._n_speed
            if self._speed:
                extras = _extras(self.interface, "speed", counter=_counter("speed", i))
                frames.append(encode("speed", rpm, t, **extras))
            if self._request:
                extras = _extras(
                    self.interface, "torque_request", counter=_counter("torque_request", i)
                )
                frames.append(encode("torque_request", request, t, **extras))
            self._n_speed += 1
        return frames

    def stroke_frames(self, rows: np.ndarray) -> list[can.Message]:
        """Frames of working strokes: rows of (t s, mean torque N*m, cylinder index)."""
        frames = []
        for t, nm, cylinder in rows:
            if self._stroke:
                extras = _extras(
                    self.interface,
                    "mean_torque",
                    cylinder=int(cylinder),
                    counter=_counter("mean_torque", self._n_stroke),
                )
                frames.append(self.interface.encode("mean_torque", nm, t, **extras))
            self._n_stroke += 1
        return frames
