"""``dtid plan``'s figure: each parameter's predicted precision against the test's duration.

Two panels, the paper's plan and the recommended one, each with its repeats scaled from one
chirp per amplitude to twice the recommended test's duration: the precision at
:data:`~dtid.identification.planning.design.SIGMAS` sigma (%, log scale) of every parameter
with a target against the whole test's time, the targets as dotted lines and each plan itself
as dots.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dtid.identification.planning.design import (
    PAPER_DESIGN,
    PRECISION_NAMES,
    SIGMAS,
    Design,
    predict,
    scaled,
)
from dtid.identification.planning.information import PlanInformation
from dtid.identification.plots import new_figure, save_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

POINTS = 16
"""Scalings drawn of each plan's repeats: from one chirp per amplitude to twice the
recommended plan's test time."""


def plan_figure(info: PlanInformation, recommended: Design, targets: Mapping[str, float]) -> Figure:
    """Draw the two panels (see the module notes)."""
    figure = new_figure(figsize=(11, 4.8), layout="constrained")
    axes = figure.subplots(1, 2, sharey=True)
    names = [n for n in PRECISION_NAMES if n in targets]
    colours = {n: f"C{i % 10}" for i, n in enumerate(names)}
    styles = {n: "-" if i < 10 else "--" for i, n in enumerate(names)}
    for ax, (title, design) in zip(
        axes, (("the paper's plan", PAPER_DESIGN), ("recommended plan", recommended)), strict=True
    ):
        longest = 2 * recommended.test_time_s / design.test_time_s
        factors = np.geomspace(1 / max(design.repeats), max(longest, 1.0), POINTS)
        variants = sorted({scaled(design, f) for f in factors}, key=lambda d: d.test_time_s)
        times = [d.test_time_s / 60 for d in variants]
        curves = [predict(info, d) for d in variants]
        point = predict(info, design)
        for name in names:
            ax.plot(
                times,
                [100 * SIGMAS * c[name] for c in curves],
                styles[name],
                color=colours[name],
                label=name,
            )
            ax.plot(design.test_time_s / 60, 100 * SIGMAS * point[name], "o", color=colours[name])
        for level in sorted(set(targets.values())):
            ax.axhline(level, color="0.4", linestyle=":", linewidth=1)
        amplitudes = " + ".join(
            f"{n} x {a:g}" for a, n in zip(design.amplitudes_nm, design.repeats, strict=True)
        )
        ax.set_title(
            f"{title}: {amplitudes} N*m, {design.duration_s:g} s, "
            f"{design.f1_hz:g}-{design.f2_hz:g} Hz",
            fontsize=9,
        )
        ax.set_xlabel("whole test, min")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel(f"predicted precision at {SIGMAS:g} sigma, % (dotted: targets)")
    axes[1].legend(fontsize=7, ncol=2, loc="upper right")
    return figure


def plot_plan(
    info: PlanInformation, recommended: Design, targets: Mapping[str, float], path: str | Path
) -> Path:
    """Save :func:`plan_figure` as PNG."""
    return save_figure(plan_figure(info, recommended, targets), path)
