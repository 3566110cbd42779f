"""Re-time crank-synchronous samples that reached the receiver late, in a burst.

A stalled sender or receive path (a USB adapter delivering a batch, a busy laptop, a virtual
vehicle that missed its tick) holds frames back and then delivers them together: in the receive
times a gap, then samples far closer together than the signal's own interval. The samples are all
there, only their times are wrong, and an FRF on those times would see a hole and a burst where
the engine turned evenly. A crank-synchronous signal comes once per crank interval, so the samples
of such a burst belong, in order, to the last crank slots of the gap: they are re-timed there.
Samples that are truly lost leave the earlier slots empty, for the FRF's own gap handling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GAP_INTERVALS = 1.5
"""A spacing of at least this many sample intervals before a burst is a gap."""
BURST_INTERVALS = 0.5
"""Samples closer than this many sample intervals belong to one burst."""
LOCAL_SPACINGS = 64
"""A burst's slots are cut with the median of this many spacings before its gap."""


@dataclass(frozen=True)
class Retiming:
    """What :func:`retime_late_bursts` changed.

    Attributes
    ----------
    times
        The re-timed sample times, s.
    n_moved
        Samples given a new time.
    max_shift_s
        Largest time correction, s (0 when none).
    """

    times: np.ndarray
    n_moved: int
    max_shift_s: float


def retime_late_bursts(times: np.ndarray, interval_s: float | None = None) -> Retiming:
    """Put samples that arrived late in a burst back on their crank slots.

    A burst is a run of samples each closer than :data:`BURST_INTERVALS` intervals to the one
    before, right after a gap of at least :data:`GAP_INTERVALS` intervals; a burst followed at
    once by another stall and its burst (two stalls in a row, seen on a loaded host) is one
    late stretch with it. The span from the
    sample before the gap to the first sample after the burst is cut into whole intervals; the
    burst's samples take its last slots, in order, evenly spaced. A burst with more samples than
    the span has slots is left alone (no crank-synchronous timing explains it). The slots' width
    is the median of the :data:`LOCAL_SPACINGS` spacings before the gap: the engine's own interval
    there, which later data cannot change (the live worker re-times a log still being written
    and must get the times ``dtid identify`` gets from the whole log).

    Parameters
    ----------
    times
        Receive times of one crank-synchronous signal, s, non-decreasing.
    interval_s
        The signal's sample interval, s; when omitted, the median spacing finds the gaps and
        bursts and the local median before each gap cuts its slots.

    Returns
    -------
    Retiming
    """
    t = np.asarray(times, dtype=float)
    if len(t) < 3:
        return Retiming(t, 0, 0.0)
    spacing = np.diff(t)
    interval = float(np.median(spacing)) if interval_s is None else interval_s
    if interval <= 0:
        return Retiming(t, 0, 0.0)
    close = spacing < BURST_INTERVALS * interval
    out = t.copy()
    gaps = spacing >= GAP_INTERVALS * interval
    done = -1
    for gap in np.flatnonzero(gaps):
        if gap < done:
            continue  # inside a chain of bursts already re-timed
        first = gap + 1
        last = first
        while last < len(spacing) and close[last]:
            last += 1
            # a stall right after the burst, releasing another burst: one late stretch
            if last < len(spacing) and gaps[last] and last + 1 < len(spacing) and close[last + 1]:
                last += 1
        done = last
        n_burst = last - first + 1
        if n_burst < 2:
            continue  # one late sample is jitter, or a loss; nothing to re-time
        slot = interval
        if interval_s is None:
            slot = float(np.median(spacing[max(0, gap - LOCAL_SPACINGS) : gap])) if gap else slot
        # the first sample after the burst, or one slot after it when that one is late too
        anchor = min(t[last + 1], t[last] + slot) if last + 1 < len(t) else t[last] + slot
        start = t[gap]
        n_slots = round((anchor - start) / slot) - 1
        if n_burst > n_slots:
            continue
        step = (anchor - start) / (n_slots + 1)
        out[first : last + 1] = start + step * np.arange(n_slots - n_burst + 1, n_slots + 1)
    shift = t - out
    moved = shift != 0
    return Retiming(out, int(np.count_nonzero(moved)), float(np.max(shift, initial=0.0)))
