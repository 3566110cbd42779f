"""The safety envelope of a running test: when to abort.

* Speed window: the idle set-point is the mean engine speed over the settle phase (when the plan
  has no settle phase, the first speed sample of the test). From the end of the settle phase on,
  the test aborts (``speed_window``) when the speed leaves set-point +- ``speed_window_rpm``. The
  speed checked is the ECU's filtered speed after a median of three consecutive samples, so one
  corrupted frame cannot abort a test; a real excursion is seen one sample (15 ms at 1000 rpm)
  later.
* Vehicle timeout: the test aborts (``vehicle_timeout``) when no speed frame has arrived for
  ``vehicle_timeout_s`` of bus time. The daemon checks this only when it has taken every frame
  waiting on the bus, so its own pauses do not count as the vehicle's.

The amplitude cap is enforced when the configuration is loaded
(:class:`dtid.acquisition.config.AcquisitionConfig`); the other aborts (``foreign_tx``, ``signal``,
``error``) are decided by the daemon. Reasons are the keys of
:data:`dtid.acquisition.stream.ABORT_REASONS`. What an abort does (zero request, end event) is the
job of :class:`dtid.acquisition.sequence.RequestSender` and the daemon.
"""

from __future__ import annotations

import numpy as np

from dtid.acquisition.config import SafetyConfig

SETTLE_SAMPLES = 50
"""Fewest speed samples in the settle phase from which their rate per revolution is read (about
a second at idle; the default settle phase of 3 s holds 150-200)."""


class SafetyMonitor:
    """Watch the engine speed of a test for the speed window and the vehicle timeout.

    Parameters
    ----------
    config
        ``[safety]`` of the configuration.
    t_start
        Bus time at which the test started, s.
    settle_s
        Duration of the settle phase, s.

    Attributes
    ----------
    setpoint_rpm : float or None
        The idle set-point once known, rpm.
    """

    def __init__(self, config: SafetyConfig, t_start: float, settle_s: float) -> None:
        self.config = config
        self.setpoint_rpm: float | None = None
        self._settle_end = t_start + settle_s
        self._settle_times: list[np.ndarray] = []  # bus time, s
        self._settle_rpm: list[np.ndarray] = []  # rpm
        self._last_speed_t = t_start
        self._recent: list[float] = []  # the last two samples, for the median of three

    def on_speed(self, times: np.ndarray, rpm: np.ndarray) -> str | None:
        """Take new speed samples (bus time, s; rpm); ``speed_window`` to abort, else None."""
        if len(times) == 0:
            return None
        self._last_speed_t = max(self._last_speed_t, float(times[-1]))
        in_settle = times < self._settle_end
        if self.setpoint_rpm is None:
            self._settle_times.append(times[in_settle])
            self._settle_rpm.append(rpm[in_settle])
            if not np.all(in_settle):
                settled = np.concatenate(self._settle_rpm)
                self.setpoint_rpm = float(np.mean(settled) if len(settled) else rpm[~in_settle][0])
        checked = rpm[~in_settle]
        if self.setpoint_rpm is None or len(checked) == 0:
            return None
        window = np.concatenate([self._recent, checked])
        self._recent = window[-2:].tolist()
        if len(window) < 3:
            return None
        a, b, c = window[:-2], window[1:-1], window[2:]
        filtered = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))  # median of 3
        if np.any(np.abs(filtered - self.setpoint_rpm) > self.config.speed_window_rpm):
            return "speed_window"
        return None

    @property
    def settle_samples_per_revolution(self) -> float | None:
        """Speed samples per crank revolution over the settle phase: a revolution at its mean
        speed over the samples' median interval (a burst of frames stamped as they were read,
        at the start, does not move it); None before the settle phase has ended or with fewer
        than :data:`SETTLE_SAMPLES` samples."""
        if self.setpoint_rpm is None:
            return None
        times = np.concatenate(self._settle_times)
        if len(times) < SETTLE_SAMPLES:
            return None
        interval = float(np.median(np.diff(times)))
        return 60.0 / (self.setpoint_rpm * interval) if interval > 0 else None

    def check_timeout(self, now: float) -> str | None:
        """Return ``vehicle_timeout`` when no speed frame came for too long before ``now`` (bus
        time, s), else None."""
        if now - self._last_speed_t > self.config.vehicle_timeout_s:
            return "vehicle_timeout"
        return None
