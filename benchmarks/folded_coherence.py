"""The part of a chirp the strokes fold into the band, in the independent recordings.

The engine takes its request once per stroke, so a chirp swept above the strokes' Nyquist
frequency (the independent recordings sweep 0.5-20 Hz at 800-850 rpm: strokes at 26.7-28.3 Hz)
reaches the drivetrain with its upper part folded into the band, at f_s - f. The folded part is in
the measured torque and the speed, not in the test torque the tool sent, so the FRF's coherence
reads it as noise; against the test torque as the strokes took it
(:func:`dtid.identification.frf.closed_loop.stroke_coherence`) it is excitation.

Per recording and run this prints, in 1 Hz bands, the measured torque's coherence with the tool's
test torque and with the strokes', and K of eq. (24) with its bins chosen by either (the product
chooses them by the first, :attr:`FrfEstimate.engine_gain`) against the recording's true K.

    python benchmarks/folded_coherence.py [--shared ../shared/independent]

A benchmark, not a test: nothing is asserted.
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
    args = parser.parse_args()
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


if __name__ == "__main__":
    main()
