"""Bus time: the time base of a test's frames, wall time stretched by ``[bus] time_factor``.

On a vehicle the factor is 1 and bus time is wall time (``time.time()``): the receive timestamps
of the frames are recorded unchanged. With a virtual vehicle run faster than real time
(``dtid vehicle --speedup F`` with ``time_factor = F``), one wall second carries F seconds of the
test, so the daemon maps every wall time ``w`` to bus time

    ``b = w0 + (w - w0) * F``

where ``w0`` is the wall time at which the daemon started. Received frames get their receive
timestamps mapped this way before they are recorded; the daemon's own frames get the bus time at
which they are sent; the test sequence, the safety timeouts and the events all run in bus time. A
recording thus carries the test's own time base (Unix-epoch times starting at the daemon's start),
whatever the factor.
"""

from __future__ import annotations

import math
import time

MAX_TIME_FACTOR = 20.0
"""Largest bus time per wall time: a virtual vehicle run faster than this no longer keeps pace
on a 2-core host (at 50 its frames came 9.6 s late), so the test's timing would be the host's;
at 1e9 it computed days of bus time in one step that Ctrl-C could not stop."""


class BusClock:
    """Map wall time to bus time and back.

    Parameters
    ----------
    time_factor
        Bus seconds per wall second, > 0.
    start_wall_s
        The wall time ``w0`` at which both clocks agree, s since the Unix epoch; now if omitted.
    """

    def __init__(self, time_factor: float = 1.0, start_wall_s: float | None = None) -> None:
        if not (math.isfinite(time_factor) and 0 < time_factor <= MAX_TIME_FACTOR):
            raise ValueError(f"time factor must lie in (0, {MAX_TIME_FACTOR:g}], got {time_factor}")
        self.time_factor = float(time_factor)
        self.start_wall_s = time.time() if start_wall_s is None else float(start_wall_s)
        self.identity = self.time_factor == 1.0
        """True when bus time is wall time (factor 1: timestamps stay bit for bit)."""

    def to_bus(self, wall_s: float) -> float:
        """Bus time of a wall time, s."""
        if self.identity:
            return wall_s
        return self.start_wall_s + (wall_s - self.start_wall_s) * self.time_factor

    def to_wall(self, bus_s: float) -> float:
        """Wall time of a bus time, s."""
        if self.identity:
            return bus_s
        return self.start_wall_s + (bus_s - self.start_wall_s) / self.time_factor

    def now(self) -> float:
        """The bus time now, s."""
        return self.to_bus(time.time())
