"""The diagnosis's figure: measured and model |G_DRV| per run over the mismatch map."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dtid.identification.diagnosis.bin_statistics import smooth_trend
from dtid.identification.diagnosis.diagnose import Diagnosis
from dtid.identification.plots import new_figure, save_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def mismatch_figure(diagnosis: Diagnosis, title: str = "") -> Figure:
    """A diagnosis's FRFs and mismatch maps.

    Top: measured (thin), identified model (thick) and, when a mechanism was accepted, the
    augmented model's (dotted) |G_DRV| of every run (validation dashed). Below: the mismatch map
    of the identified model, each run's standardised residual z = (measured - model) / scatter
    over frequency at its amplitude (|G_ENG|'s dotted, in its run's colour), with |G_DRV|'s
    family-wise threshold and the significant bands shaded (a significant smooth trend over a
    run's whole band drawn as a broad line in its colour); and, with an accepted mechanism, the
    same map of the augmented model.

    Parameters
    ----------
    diagnosis
        The diagnosis (:func:`dtid.identification.diagnosis.diagnose.diagnose_report`).
    title
        Figure title.
    """
    from matplotlib import colormaps

    maps = [("identified model", diagnosis.mismatch)]
    if diagnosis.after is not None:
        maps.append((f"with {' + '.join(diagnosis.mechanisms)}", diagnosis.after))
    residuals = diagnosis.mismatch.residuals
    runs = list(dict.fromkeys(residual.label for residual in residuals))
    figure = new_figure(figsize=(8, 4 + 3 * len(maps)))
    top, *rows = figure.subplots(1 + len(maps), 1, sharex=True)
    shades = colormaps["viridis"](np.linspace(0.0, 0.85, max(len(runs), 1)))
    colours = dict(zip(runs, shades[: len(runs)], strict=True))
    for k, residual in enumerate(residuals):
        if residual.frf != "drv":
            continue
        style = "--" if residual.role == "validation" else "-"
        label = f"{residual.amplitude_nm:g} N*m ({residual.role})"
        f, colour = residual.frequency_hz, colours[residual.label]
        top.plot(f, residual.measured_db, color=colour, linewidth=0.8, alpha=0.7)
        top.plot(f, residual.model_db, color=colour, linewidth=2, linestyle=style, label=label)
        if diagnosis.after is not None:
            augmented = diagnosis.after.residuals[k].model_db
            top.plot(f, augmented, color=colour, linewidth=1.5, linestyle=":")
    for axis, (name, found) in zip(rows, maps, strict=True):
        for residual in found.residuals:
            if residual.frf == "drv":
                style, width = ("--" if residual.role == "validation" else "-"), 1.2
            else:
                style, width = ":", 1.0
            axis.plot(
                residual.frequency_hz,
                residual.z,
                color=colours[residual.label],
                linewidth=width,
                linestyle=style,
            )
        by_run = {(residual.label, residual.frf): residual for residual in found.residuals}
        for band in found.bands:
            if band.kind == "trend":  # a whole run's smooth trend: drawn, not shaded
                residual = by_run[(band.label, band.frf)]
                trend = smooth_trend(residual.z, residual.frequency_hz)
                colour = colours[residual.label]
                axis.plot(residual.frequency_hz, trend, color=colour, linewidth=5, alpha=0.3)
            else:
                axis.axvspan(band.f_lo_hz, band.f_hi_hz, color="tab:red", alpha=0.15)
        for level in (found.drv.threshold_z, -found.drv.threshold_z):
            axis.axhline(level, color="tab:red", linewidth=1, linestyle=":")
        axis.set_ylabel(f"z, {name}")
    top.set_ylabel("|G_DRV| / dB re 1 (rad/s)/(N*m)")
    heading = "adequate" if diagnosis.adequate else "mismatch located"
    if diagnosis.mechanisms:
        heading += f"; explained by {' + '.join(diagnosis.mechanisms)} (dotted)"
    top.set_title(title or heading)
    top.legend(fontsize="small")
    rows[-1].set_xlabel("frequency / Hz")
    for axis in (top, *rows):
        axis.grid(True, alpha=0.3)
    figure.tight_layout()
    return figure


def plot_mismatch(diagnosis: Diagnosis, path: str | Path, title: str = "") -> Path:
    """Save :func:`mismatch_figure` to ``path``; return it."""
    return save_figure(mismatch_figure(diagnosis, title), path)
