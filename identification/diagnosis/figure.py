"""The diagnosis's figure: measured and model |G_DRV| per run over the mismatch map."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dtid.identification.diagnosis.diagnose import Diagnosis
from dtid.identification.plots import new_figure, save_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def mismatch_figure(diagnosis: Diagnosis, title: str = "") -> Figure:
    """A diagnosis's FRFs and mismatch map.

    Top: measured (thin) and model (thick) |G_DRV| of every run (validation dashed). Bottom: the
    mismatch map, each run's standardised residual z = (measured - model) / scatter over
    frequency at its amplitude, with the family-wise threshold and the significant bands shaded.

    Parameters
    ----------
    diagnosis
        The diagnosis (:func:`dtid.identification.diagnosis.diagnose.diagnose_report`).
    title
        Figure title.
    """
    from matplotlib import colormaps

    residuals = diagnosis.mismatch.residuals
    figure = new_figure(figsize=(8, 7))
    top, bottom = figure.subplots(2, 1, sharex=True)
    colours = colormaps["viridis"](np.linspace(0.0, 0.85, max(len(residuals), 1)))
    for residual, colour in zip(residuals, colours, strict=True):
        style = "--" if residual.role == "validation" else "-"
        label = f"{residual.amplitude_nm:g} N*m ({residual.role})"
        f = residual.frequency_hz
        top.plot(f, residual.measured_db, color=colour, linewidth=0.8, alpha=0.7)
        top.plot(f, residual.model_db, color=colour, linewidth=2, linestyle=style, label=label)
        bottom.plot(f, residual.z, color=colour, linewidth=1.2, linestyle=style, label=label)
    for band in diagnosis.mismatch.bands:
        bottom.axvspan(band.f_lo_hz, band.f_hi_hz, color="tab:red", alpha=0.15)
    threshold = diagnosis.mismatch.threshold_z
    for level in (threshold, -threshold):
        bottom.axhline(level, color="tab:red", linewidth=1, linestyle=":")
    top.set_ylabel("|G_DRV| / dB re 1 (rad/s)/(N*m)")
    top.set_title(title or ("adequate" if diagnosis.adequate else "mismatch located"))
    top.legend(fontsize="small")
    bottom.set_xlabel("frequency / Hz")
    bottom.set_ylabel("z = (measured - model) / scatter")
    for axis in (top, bottom):
        axis.grid(True, alpha=0.3)
    figure.tight_layout()
    return figure


def plot_mismatch(diagnosis: Diagnosis, path: str | Path, title: str = "") -> Path:
    """Save :func:`mismatch_figure` to ``path``; return it."""
    return save_figure(mismatch_figure(diagnosis, title), path)
