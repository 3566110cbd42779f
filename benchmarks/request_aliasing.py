"""Why eq. (24)'s K can be far off: the latch aliases the request.

Eq. (15) divides the measured mean torque's response to the test torque by the request's,
u = T_ecu on the crank-event grid, and by the nominal hold of the strokes' torque |G_p| (eq. 10);
eq. (24) takes the mean of that |G_ENG| for K. But the engine takes the request once per stroke
(the latch), so what it delivers is the request sampled at the stroke rate and held: content of
the request above half the stroke rate folds into the band. A request that varies slowly (a PI
on the speed) leaves |G_ENG| flat at K; a derivative action puts the speed's fast response into
the request, and |G_ENG| then swings with frequency around K.

This simulates the calibration's random vehicles (:func:`benchmarks.diagnosis_calibration.
recording`) and prints, per identifying run and in bands of the sweep, three responses to the
test torque z (Welch cross-spectra over the run, the FRF's own segments):

* ``T/u``: the measured mean torque against the request on the event grid, over |G_p|: the
  product's |G_ENG|, whose mean is eq. (24)'s K;
* ``T/latched``: the measured mean torque against the request each stroke took, held over its
  stroke (the strokes' K, read spectrally);
* ``latched/u``: the latch's own transfer, which the nominal hold |G_p| stands for.

    PYTHONPATH=. python benchmarks/request_aliasing.py --vehicles 53 2

A benchmark, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import signal

from benchmarks.diagnosis_calibration import recording
from benchmarks.identification_trial import draw_vehicle
from dtid.identification.frf.sensor_response import torque_hold_gain
from dtid.identification.model.idle_loop import SAMPLES_PER_STROKE, IdleLoop
from dtid.identification.pipeline import identification_runs

BANDS = 6
"""Bands of the sweep printed per run."""


def latched_on_grid(loop: IdleLoop) -> tuple[np.ndarray, np.ndarray]:
    """The request each stroke took and its measured mean torque, each held over the stroke's
    events before its report (NaN before the first stroke), N*m."""
    taken = np.full(len(loop.t), np.nan)
    torque = np.full(len(loop.t), np.nan)
    for report, request, measured in zip(
        np.searchsorted(loop.t, loop.stroke_t),
        loop.stroke_request_nm,
        loop.stroke_torque_nm,
        strict=True,
    ):
        start = max(0, report - SAMPLES_PER_STROKE)
        taken[start:report], torque[start:report] = request, measured
    return taken, torque


def main() -> None:
    """Print the three responses per vehicle and run."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, nargs="+", default=[53, 2])
    args = parser.parse_args()
    for index in args.vehicles:
        truth, test = recording(index)
        fit = identification_runs([test])
        kept = fit.tests[0]
        loop = kept.loop
        controller = draw_vehicle(index).controller
        print(
            f"vehicle {index}: K {truth.K:.4f} (strokes' {loop.gain:.4f}); kp "
            f"{controller.kp_nm_per_rpm:.3f} N*m/rpm, kd {controller.kd_nm_per_rpm_s:.4f} "
            f"N*m*s/rpm, output delay {controller.delay_samples}, latch {controller.latch_samples}"
        )
        taken, torque = latched_on_grid(loop)
        rate_hz = 1.0 / float(np.median(np.diff(loop.t)))
        for run in fit.runs[0]:
            estimate = kept.estimates[run]
            inside = (loop.t >= estimate.run.start_s) & (loop.t < estimate.run.end_s)
            inside &= np.isfinite(taken)
            z, segment = loop.test_nm[inside], estimate.nperseg
            f, s_zu = signal.csd(z, loop.drive_nm[inside], fs=rate_hz, nperseg=segment)
            _, s_zl = signal.csd(z, taken[inside], fs=rate_hz, nperseg=segment)
            _, s_zx = signal.csd(z, torque[inside], fs=rate_hz, nperseg=segment)
            band = (f >= estimate.frequency_hz[0]) & (f <= estimate.frequency_hz[-1])
            hold = torque_hold_gain(f[band], estimate.speed_rpm)
            columns = {
                "T/u": np.abs(s_zx / s_zu)[band] / hold,
                "T/latched": np.abs(s_zx / s_zl)[band],
                "latched/u": np.abs(s_zl / s_zu)[band],
            }
            print(
                f"  {estimate.run.amplitude_nm:g} N*m run: eq. (24)'s K {estimate.engine_gain:.4f}"
            )
            print(f"  {'band, Hz':>12} {'|G_p|':>7} " + " ".join(f"{k:>10}" for k in columns))
            for part in np.array_split(np.arange(int(band.sum())), BANDS):
                lo, hi = f[band][part[0]], f[band][part[-1]]
                print(
                    f"  {lo:5.1f}-{hi:5.1f} {np.mean(hold[part]):7.3f} "
                    + " ".join(f"{np.mean(v[part]):10.3f}" for v in columns.values())
                )
            print(
                f"  {'mean':>12} {np.mean(hold):7.3f} "
                + " ".join(f"{np.mean(v):10.3f}" for v in columns.values())
            )


if __name__ == "__main__":
    main()
