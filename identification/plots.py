"""Figures of the FRF pipeline, drawn with matplotlib (imported here only, never by computation).

Each figure has a function that draws it on a :class:`matplotlib.figure.Figure` of its own, outside
pyplot (no backend is chosen or changed, so a notebook's stays as it was and no window opens),
and a ``plot_*`` function that saves it:

* :func:`frf_figure`: |G_DRV| per amplitude as the paper's Fig. 3, |G_ENG| and the coherence below;
* :func:`fit_figure`: measured and identified |G_DRV| per run, as Fig. 6;
* :func:`profiles_figure`: the likelihood profiles of one setup, as a row of Fig. 5.

:func:`new_figure` and :func:`save_figure` are shared with the diagnosis's figure
(:mod:`dtid.identification.diagnosis.figure`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dtid.errors import RecordingError
from dtid.identification.frf.closed_loop import FrfEstimate

if TYPE_CHECKING:
    from matplotlib.figure import Figure

COHERENCE_FLOOR = 0.7
"""Bins below this coherence are drawn faint: noise makes up a third or more of the response."""


def new_figure(**options: object) -> Figure:
    """A matplotlib figure of its own, outside pyplot."""
    from matplotlib.figure import Figure

    return Figure(**options)


def save_figure(figure: Figure, path: str | Path) -> Path:
    """Write a figure (format by suffix: .png, .pdf, .svg); a failure names the file."""
    path = Path(path)
    try:
        figure.savefig(path, dpi=110)
    except (OSError, ValueError) as error:
        raise RecordingError(f"cannot write the plot {path}: {error}") from None
    return path


def frf_figure(estimates: Sequence[FrfEstimate], title: str = "") -> Figure:
    """|G_DRV|, |G_ENG| and the coherence of each chirp run, as the paper's Fig. 3.

    Parameters
    ----------
    estimates
        One FRF per chirp run; runs of equal amplitude share a colour.
    title
        Figure title.
    """
    from matplotlib import colormaps

    figure = new_figure(figsize=(8, 8))
    ax_drv, ax_eng, ax_coh = figure.subplots(3, 1, sharex=True, height_ratios=(3, 1.2, 1.2))
    amplitudes = sorted({round(e.run.amplitude_nm, 2) for e in estimates})
    colours = colormaps["viridis"](np.linspace(0.0, 0.85, max(len(amplitudes), 1)))
    for estimate in estimates:
        colour = colours[amplitudes.index(round(estimate.run.amplitude_nm, 2))]
        f = estimate.frequency_hz
        trusted = np.where(estimate.coherence >= COHERENCE_FLOOR, estimate.drv_db, np.nan)
        label = f"A_test = {estimate.run.amplitude_nm:.1f} N*m ({estimate.run.start_s:.0f} s)"
        ax_drv.plot(f, estimate.drv_db, color=colour, alpha=0.3, linewidth=0.8)
        ax_drv.plot(f, trusted, color=colour, label=label)
        if not np.all(np.isnan(estimate.eng)):
            ax_eng.plot(f, estimate.eng_db, color=colour)
        ax_coh.plot(f, estimate.coherence, color=colour)
    ax_drv.set_ylabel("|G_DRV| / dB re 1 (rad/s)/(N*m)")
    ax_drv.legend(loc="lower left", fontsize="small")
    ax_drv.set_title(title or "Drivetrain frequency response (faint: coherence < 0.7)")
    ax_eng.set_ylabel("|G_ENG| / dB")
    ax_coh.set_ylabel("coherence")
    ax_coh.set_ylim(0, 1.05)
    ax_coh.axhline(COHERENCE_FLOOR, color="grey", linestyle=":", linewidth=0.8)
    ax_coh.set_xlabel("frequency / Hz")
    for axis in (ax_drv, ax_eng, ax_coh):
        axis.grid(True, which="both", alpha=0.3)
    figure.tight_layout()
    return figure


def plot_frf(estimates: Sequence[FrfEstimate], path: str | Path, title: str = "") -> Path:
    """Save :func:`frf_figure` to ``path``; return it."""
    return save_figure(frf_figure(estimates, title), path)


def fit_figure(
    measured: Sequence[FrfEstimate],
    model_db: Sequence[np.ndarray],
    roles: Sequence[str],
    title: str = "",
) -> Figure:
    """Measured and identified |G_DRV| per run, as the paper's Fig. 6.

    Parameters
    ----------
    measured
        Measured FRF of each run.
    model_db
        The identified model's |G_DRV| in dB on each run's grid.
    roles
        ``"fit"`` or ``"validation"`` per run (validation runs are drawn dashed).
    title
        Figure title.
    """
    from matplotlib import colormaps

    figure = new_figure(figsize=(8, 5))
    axis = figure.subplots()
    colours = colormaps["viridis"](np.linspace(0.0, 0.85, max(len(measured), 1)))
    for estimate, db, role, colour in zip(measured, model_db, roles, colours, strict=True):
        label = f"{estimate.run.amplitude_nm:g} N*m ({role})"
        axis.plot(estimate.frequency_hz, estimate.drv_db, color=colour, linewidth=0.8, alpha=0.6)
        axis.plot(
            estimate.frequency_hz,
            db,
            color=colour,
            linewidth=2,
            linestyle="--" if role == "validation" else "-",
            label=label,
        )
    axis.set_xlabel("frequency / Hz")
    axis.set_ylabel("|G_DRV| / dB re 1 (rad/s)/(N*m)")
    axis.set_title(title or "Measured (thin) and identified (thick) frequency responses")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize="small")
    figure.tight_layout()
    return figure


def plot_fit(
    measured: Sequence[FrfEstimate],
    model_db: Sequence[np.ndarray],
    roles: Sequence[str],
    path: str | Path,
    title: str = "",
) -> Path:
    """Save :func:`fit_figure` to ``path``; return it."""
    return save_figure(fit_figure(measured, model_db, roles, title), path)


def profiles_figure(profiles: Mapping[str, object], title: str = "") -> Figure:
    """The likelihood profiles of one setup, as a row of the paper's Fig. 5.

    Parameters
    ----------
    profiles
        :class:`dtid.identification.uncertainty.profile.Profile` by parameter name.
    title
        Figure title.
    """
    names = list(profiles)
    columns = min(len(names), 5)
    rows = -(-len(names) // columns)
    figure = new_figure(figsize=(3 * columns, 2.6 * rows))
    axes = figure.subplots(rows, columns, squeeze=False)
    for axis, name in zip(axes.flat, names, strict=False):
        prof = profiles[name]
        span = prof.values[-1] - prof.values[0]
        axis.plot((prof.values - prof.values[0]) / span, prof.objective, "o-", markersize=3)
        axis.set_title(f"{name} ({prof.verdict})", fontsize="small")
        axis.set_xlabel("normalised value", fontsize="small")
        axis.grid(True, alpha=0.3)
    for axis in list(axes.flat)[len(names) :]:
        axis.axis("off")
    axes[0, 0].set_ylabel("NRMSE (eq. 17)")
    figure.suptitle(title or "Likelihood profiles")
    figure.tight_layout()
    return figure


def plot_profiles(profiles: Mapping[str, object], path: str | Path, title: str = "") -> Path:
    """Save :func:`profiles_figure` to ``path``; return it."""
    return save_figure(profiles_figure(profiles, title), path)
