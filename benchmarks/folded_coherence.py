"""The part of a chirp the strokes fold into the band, in the independent recordings.

The engine takes its request once per stroke, so a chirp swept above the strokes' Nyquist
frequency (the independent recordings sweep 0.5-20 Hz at 800-850 rpm: strokes at 26.7-28.3 Hz)
reaches the drivetrain with its upper part folded into the band, at f_s - f. The folded part is in
the measured torque and the speed, not in the test torque the tool sent, so the FRF's coherence
reads it as noise; against the test torque as the strokes took it
(:func:`dtid.identification.frf.low_coherence.stroke_coherence`) it is excitation.

Per recording and run this prints, in 1 Hz bands, the measured torque's coherence with the tool's
test torque and with the strokes', and K of eq. (24) with its bins chosen by either (the product
chooses them by the first, :attr:`FrfEstimate.engine_gain`) against the recording's true K.

    python benchmarks/folded_coherence.py [--shared ../shared/independent]
    PYTHONPATH=. python benchmarks/folded_coherence.py --trial 20

(``--trial N``: instead, K both ways on the identification trial's truths 1-N, the recordings
of :func:`benchmarks.diagnosis_calibration.recording` with noise seed 100 + N, and their RMS
error.) A benchmark, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

import numpy as np

import dtid
from dtid.identification.frf.closed_loop import GAIN_COHERENCE, FrfEstimate

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shared", type=Path, default=ROOT.parent / "shared" / "independent")
    parser.add_argument("--trial", type=int, metavar="N", help="the trial's truths 1-N instead")
    args = parser.parse_args()
    if args.trial:
        _trial(args.trial)
        return
    for folder in sorted(p for p in args.shared.iterdir() if (p / "truth.toml").exists()):
        truth = tomllib.loads((folder / "truth.toml").read_text())["drivetrain"]["K"]
        for path in sorted(folder.glob("run_A*.*")):
            recording = dtid.read_recording(
                path, dbc=folder / "oem_vehicle.dbc", signals=folder / "signals.toml"
            )
            for estimate in dtid.frf(recording):
                _report(f"{folder.name}/{path.name}", estimate, truth)


def _report(name: str, estimate: FrfEstimate, truth: float) -> None:
    f, tool, strokes = estimate.frequency_hz, estimate.torque_coherence, estimate.stroke_coherence
    print(f"{name} at {estimate.run.amplitude_nm:g} N*m, {estimate.speed_rpm:.0f} rpm")
    for lo in np.arange(np.floor(f[0]), f[-1], 1.0):
        band = (f >= lo) & (f < lo + 1)
        if band.any():
            print(
                f"  {lo:4.0f}-{lo + 1:<4.0f} Hz  coherence with the tool's test torque "
                f"{np.median(tool[band]):.2f}, with the strokes' {np.median(strokes[band]):.2f}"
            )
    for label, coherence in (("tool's", estimate.coherence), ("strokes'", strokes)):
        trusted = coherence >= GAIN_COHERENCE
        gain = float(np.mean(estimate.eng[trusted]))
        print(
            f"  K by the {label} coherence: {gain:.4f} over {trusted.sum()} of {len(f)} bins "
            f"({100 * (gain / truth - 1):+.1f} % of the true {truth:g})"
        )


def _trial(count: int) -> None:
    """K both ways over the identifying runs of the trial's truths 1-``count``."""
    from benchmarks.diagnosis_calibration import recording
    from dtid.identification.pipeline import identification_runs

    errors = []
    for index in range(1, count + 1):
        truth, test = recording(index, 100 + index)
        fit = identification_runs([test])
        estimates = [fit.tests[0].estimates[i] for i in fit.runs[0]]
        gains = [
            float(np.mean([np.mean(e.eng[coherence(e) >= GAIN_COHERENCE]) for e in estimates]))
            for coherence in (lambda e: e.coherence, lambda e: e.stroke_coherence)
        ]
        errors.append([gain / truth.K - 1 for gain in gains])
        tool, strokes = (100 * error for error in errors[-1])
        print(
            f"truth {index:2d}: {estimates[0].speed_rpm:4.0f} rpm, K {truth.K:.3f}: by the "
            f"tool's coherence {tool:+.1f} %, the strokes' {strokes:+.1f} %"
        )
    rms = 100 * np.sqrt(np.mean(np.square(errors), axis=0))
    closer = int(np.sum(np.abs(np.array(errors)[:, 1]) < np.abs(np.array(errors)[:, 0])))
    print(
        f"RMS: the tool's {rms[0]:.2f} %, the strokes' {rms[1]:.2f} %; the strokes' closer on "
        f"{closer} of {count}"
    )


if __name__ == "__main__":
    main()
