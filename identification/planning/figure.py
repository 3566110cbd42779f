"""``dtid plan``'s figure: each parameter's predicted precision against the test's duration.

Two panels, the paper's plan and the recommended one, each with its repeats scaled from one
chirp per amplitude to twice the recommended test's duration: the precision at
:data:`~dtid.identification.planning.design.SIGMAS` sigma (%, log scale) of every parameter
with a target against the whole test's time, the targets as dotted lines and each plan itself
as dots. Where the plan holds for vehicles around the prior, each curve is the worst of them.
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
    Recommendation,
    predict_worst,
    scaled,
)
from dtid.identification.planning.information import PlanInformation
from dtid.identification.planning.spread import describe
from dtid.identification.plots import new_figure, save_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

POINTS = 16
"""Scalings drawn of each plan's repeats: from one chirp per amplitude to twice the
recommended plan's test time."""


def plan_figure(
    info: PlanInformation, recommendation: Recommendation, targets: Mapping[str, float]
) -> Figure:
    """Draw the two panels (see the module notes); a follow-up's panel counts the recorded runs
    in, and without a recommended test (the recorded runs meet the targets) only the paper's
    panel is drawn."""
    design, recorded = recommendation.design, recommendation.recorded
    panels: list[tuple[str, Design, tuple[Design, ...]]] = [("the paper's plan", PAPER_DESIGN, ())]
    if design is not None:
        title = "recommended follow-up" if recorded else "recommended plan"
        panels.append((title, design, recorded))
    figure = new_figure(figsize=(5.5 * len(panels), 4.8), layout="constrained")
    axes = np.atleast_1d(figure.subplots(1, len(panels), sharey=True))
    names = [n for n in PRECISION_NAMES if n in targets]
    colours = {n: f"C{i % 10}" for i, n in enumerate(names)}
    styles = {n: "-" if i < 10 else "--" for i, n in enumerate(names)}
    longest_s = max(d.test_time_s for _, d, _ in panels)
    for ax, (title, shown, before) in zip(axes, panels, strict=True):
        factors = np.geomspace(
            1 / max(shown.repeats), max(2 * longest_s / shown.test_time_s, 1.0), POINTS
        )
        variants = sorted({scaled(shown, f) for f in factors}, key=lambda d: d.test_time_s)
        times = [d.test_time_s / 60 for d in variants]
        curves = [predict_worst(info, d, before) for d in variants]
        point = predict_worst(info, shown, before)
        for name in names:
            ax.plot(
                times,
                [100 * SIGMAS * c[name] for c in curves],
                styles[name],
                color=colours[name],
                label=name,
            )
            ax.plot(shown.test_time_s / 60, 100 * SIGMAS * point[name], "o", color=colours[name])
        for level in sorted(set(targets.values())):
            ax.axhline(level, color="0.4", linestyle=":", linewidth=1)
        amplitudes = " + ".join(
            f"{n} x {a:g}" for a, n in zip(shown.amplitudes_nm, shown.repeats, strict=True)
        )
        ax.set_title(
            f"{title}: {amplitudes} N*m, {shown.duration_s:g} s, "
            f"{shown.f1_hz:g}-{shown.f2_hz:g} Hz",
            fontsize=9,
        )
        ax.set_xlabel("whole test, min" + (" (after the recorded runs)" if before else ""))
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel(f"predicted precision at {SIGMAS:g} sigma, % (dotted: targets)")
    if info.around:
        figure.suptitle(
            f"each curve the worst of the prior and {len(info.around)} vehicles within "
            f"{describe(info.spread)} of it",
            fontsize=9,
        )
    axes[-1].legend(fontsize=7, ncol=2, loc="upper right")
    return figure


def plot_plan(
    info: PlanInformation,
    recommendation: Recommendation,
    targets: Mapping[str, float],
    path: str | Path,
) -> Path:
    """Save :func:`plan_figure` as PNG."""
    return save_figure(plan_figure(info, recommendation, targets), path)
