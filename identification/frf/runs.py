"""Find the chirp runs of a test in its test-torque signal.

A run is a stretch where the test torque is not zero, ended by a pause of at least
``min_pause_s``. Its amplitude is the peak of the request; its start and end frequencies come from
a robust straight-line fit (Theil-Sen) of the instantaneous frequency measured between zero
crossings, which is what eq. (11) prescribes for a linear chirp.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from dtid.identification.samples.testdata import Series

MIN_PAUSE_S = 0.5
"""A test torque of zero for at least this long separates two runs, s."""
MIN_RUN_S = 1.0
"""Shorter stretches of non-zero test torque are not chirp runs (a blip, a test frame), s."""
MAX_SPACING = 1.5
"""Samples further apart than this many median sample intervals (a hole: the sender stalled), or
closer than its inverse (a burst: the sender caught up), make the half periods across them
irregular: they are not used for the frequency sweep."""
MIN_HALF_PERIODS = 8
"""Fewer regular half periods than this and the sweep is fitted through all of them."""
ZERO_FRACTION = 1e-3
"""Test-torque values below this fraction of the recording's peak count as zero."""


@dataclass(frozen=True)
class ChirpRun:
    """One chirp found in a recording.

    Attributes
    ----------
    start_s, end_s
        First and last non-zero test-torque sample, s (recording time).
    amplitude_nm
        Peak test torque, N*m.
    f1_hz, f2_hz
        Instantaneous frequency at the start and end of the run, Hz.
    """

    start_s: float
    end_s: float
    amplitude_nm: float
    f1_hz: float
    f2_hz: float

    @property
    def duration_s(self) -> float:
        """Length of the run, s."""
        return self.end_s - self.start_s

    def as_dict(self) -> dict[str, float]:
        """The run as a JSON-ready dict (keys as the attributes)."""
        return {key: float(value) for key, value in asdict(self).items()}


def find_runs(test_torque: Series) -> list[ChirpRun]:
    """Find the chirp runs in a test-torque signal.

    Parameters
    ----------
    test_torque
        Test torque request, N*m.

    Returns
    -------
    list of ChirpRun
        In time order; empty when the signal is zero throughout.
    """
    t, value = test_torque.t, test_torque.value
    if len(t) < 2:
        return []
    peak = float(np.max(np.abs(value)))
    if peak == 0.0:
        return []
    active = np.flatnonzero(np.abs(value) > ZERO_FRACTION * peak)
    breaks = np.flatnonzero(np.diff(t[active]) > MIN_PAUSE_S)
    firsts = np.concatenate(([0], breaks + 1))
    lasts = np.concatenate((breaks, [len(active) - 1]))
    runs = []
    for first, last in zip(firsts, lasts, strict=True):
        lo, hi = active[first], active[last] + 1
        if t[hi - 1] - t[lo] < MIN_RUN_S:
            continue
        run = _describe(t[lo:hi], value[lo:hi])
        if run is not None:
            runs.append(run)
    return runs


def _describe(t: np.ndarray, value: np.ndarray) -> ChirpRun | None:
    """Amplitude and frequency sweep of one run, or None if it does not oscillate."""
    sign = np.signbit(value)
    cross = np.flatnonzero(sign[1:] != sign[:-1])
    if len(cross) < 4:
        return None
    # linear interpolation of each zero crossing between its two samples
    v0, v1 = value[cross], value[cross + 1]
    frac = np.where(v1 != v0, v0 / (v0 - v1), 0.5)
    t_cross = t[cross] + frac * (t[cross + 1] - t[cross])
    half_periods = np.diff(t_cross)
    with np.errstate(divide="ignore"):  # a request pause's zero sample is crossed twice at once
        frequency = 0.5 / half_periods
    t_mid = 0.5 * (t_cross[1:] + t_cross[:-1])
    # a sender that stalled leaves a hole in the requests, then catches up in a burst: a half
    # period across either has the wrong length (a least-squares line through them gave f1 < 0)
    spacing = np.diff(t)
    typical = np.median(spacing)
    irregular = (spacing > MAX_SPACING * typical) | (spacing < typical / MAX_SPACING)
    breaks = np.concatenate(([0], np.cumsum(irregular)))
    whole = breaks[cross[1:] + 1] == breaks[cross[:-1]]
    finite = np.isfinite(frequency)
    if np.count_nonzero(whole & finite) >= MIN_HALF_PERIODS:
        t_mid, frequency = t_mid[whole & finite], frequency[whole & finite]
    else:
        t_mid, frequency = t_mid[finite], frequency[finite]
    # Theil-Sen, robust to the irregular half periods this cannot see (jitter within the bounds)
    slope, intercept, _, _ = stats.theilslopes(frequency, t_mid)
    start, end = float(t[0]), float(t[-1])
    return ChirpRun(
        start_s=start,
        end_s=end,
        amplitude_nm=float(np.max(np.abs(value))),
        f1_hz=float(intercept + slope * start),
        f2_hz=float(intercept + slope * end),
    )
