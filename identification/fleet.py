"""The fleet view of many tests' identifications: trends per vehicle, outliers against the fleet.

Input: the rows of ``dtid batch``'s table (:mod:`dtid.batch`), one per test, each with its
vehicle, date and the identified parameters.

- **Trend**: per vehicle and parameter with two tests or more, the least-squares slope over
  time, in % of the vehicle's mean per 30 days (a DMF stiffness falling, a free play growing:
  wear), and the change from the first test to the last.
- **Outlier**: a test whose parameter lies more than :data:`OUTLIER_Z` robust standard scores
  from the fleet's median (scale: 1.4826 times the median absolute deviation, which a few
  outliers cannot inflate as they do a standard deviation). Needs :data:`MIN_FLEET` tests.

:func:`fleet_view` writes both as ``fleet.png`` (each parameter over time, one line per vehicle,
outliers ringed) and ``fleet.html`` (the figure and the tables, self-contained).
"""

from __future__ import annotations

import datetime
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dtid.identification.html_report import escape, figure_html, page, table_html, write_html
from dtid.identification.plots import new_figure, save_figure

FLEET_PARAMETERS = ("c12", "eps12", "d12", "Tc12", "c23", "eps23")
"""The parameters the fleet view follows (the couplings, where wear shows)."""
OUTLIER_Z = 3.5
"""Robust standard score beyond which a test is flagged (Iglewicz and Hoaglin's 3.5)."""
MIN_FLEET = 5
"""Fewest tests with a value for a parameter before its outliers are judged."""
_MAD_SCALE = 1.4826
"""Median absolute deviation to standard deviation for normal data."""


@dataclass(frozen=True)
class Outlier:
    """A test's parameter far from the fleet's."""

    test: str
    vehicle: str
    parameter: str
    value: float
    fleet_median: float
    z: float


@dataclass(frozen=True)
class Trend:
    """A vehicle's parameter over its tests."""

    vehicle: str
    parameter: str
    tests: int
    first: float
    last: float
    percent_per_30_days: float


def _days(date: str) -> float:
    moment = datetime.datetime.fromisoformat(date)
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=datetime.UTC)
    return moment.timestamp() / 86400.0


def _values(rows: Sequence[Mapping[str, Any]], name: str) -> list[Mapping[str, Any]]:
    return [
        r
        for r in rows
        if r.get("status") == "ok"
        and isinstance(r.get(name), float | int)
        and math.isfinite(r[name])
    ]


def outliers(
    rows: Sequence[Mapping[str, Any]], names: Sequence[str] = FLEET_PARAMETERS
) -> list[Outlier]:
    """The tests whose parameters lie beyond :data:`OUTLIER_Z` robust scores of the fleet."""
    found = []
    for name in names:
        valid = _values(rows, name)
        if len(valid) < MIN_FLEET:
            continue
        values = np.array([r[name] for r in valid], dtype=float)
        median = float(np.median(values))
        scale = _MAD_SCALE * float(np.median(np.abs(values - median)))
        if scale <= 0.0:
            continue
        for row, value in zip(valid, values, strict=True):
            z = (value - median) / scale
            if abs(z) > OUTLIER_Z:
                found.append(Outlier(row["test"], row["vehicle"], name, float(value), median, z))
    return found


def trends(
    rows: Sequence[Mapping[str, Any]], names: Sequence[str] = FLEET_PARAMETERS
) -> list[Trend]:
    """Each vehicle's parameters over time (vehicles with two or more dated tests)."""
    found = []
    vehicles = sorted({r["vehicle"] for r in rows})
    for vehicle in vehicles:
        for name in names:
            valid = sorted(
                (r for r in _values(rows, name) if r["vehicle"] == vehicle),
                key=lambda r: _days(r["date"]),
            )
            if len(valid) < 2:
                continue
            days = np.array([_days(r["date"]) for r in valid])
            values = np.array([r[name] for r in valid], dtype=float)
            if np.ptp(days) <= 0.0:
                continue
            slope = float(np.polyfit(days - days[0], values, 1)[0])
            mean = float(np.mean(values))
            percent = 100.0 * slope * 30.0 / mean if mean != 0.0 else math.nan
            found.append(
                Trend(vehicle, name, len(valid), float(values[0]), float(values[-1]), percent)
            )
    return found


def fleet_figure(rows: Sequence[Mapping[str, Any]], flagged: Sequence[Outlier]) -> Any:
    """Each followed parameter over time, a line per vehicle, outliers ringed in red."""
    from matplotlib import colormaps

    names = list(FLEET_PARAMETERS)
    figure = new_figure(figsize=(11, 6.5))
    axes = figure.subplots(2, 3, squeeze=False).flat
    vehicles = sorted({r["vehicle"] for r in rows})
    colours = colormaps["tab10"](np.arange(len(vehicles)) % 10)
    ringed = {(o.test, o.parameter) for o in flagged}
    for axis, name in zip(axes, names, strict=False):
        for vehicle, colour in zip(vehicles, colours, strict=True):
            valid = sorted(
                (r for r in _values(rows, name) if r["vehicle"] == vehicle),
                key=lambda r: _days(r["date"]),
            )
            if not valid:
                continue
            dates = [datetime.datetime.fromisoformat(r["date"]) for r in valid]
            values = [r[name] for r in valid]
            axis.plot(dates, values, "o-", color=colour, markersize=4, label=vehicle)
            for date, value, row in zip(dates, values, valid, strict=True):
                if (row["test"], name) in ringed:
                    axis.plot(date, value, "o", markersize=12, markerfacecolor="none", color="red")
        axis.set_title(name, fontsize="small")
        axis.grid(True, alpha=0.3)
        axis.tick_params(axis="x", labelrotation=30, labelsize="x-small")
    handles, labels = next(iter(figure.axes)).get_legend_handles_labels()
    if handles:
        figure.legend(handles, labels, loc="upper right", fontsize="small")
    figure.suptitle("Identified parameters per vehicle over time (red rings: fleet outliers)")
    figure.tight_layout(rect=(0, 0, 0.9, 0.95))
    return figure


def fleet_view(rows: Sequence[Mapping[str, Any]], out: str | Path) -> tuple[Path, Path]:
    """Write ``fleet.png`` and ``fleet.html`` into ``out``; return their paths."""
    out = Path(out)
    flagged = outliers(rows)
    found = trends(rows)
    figure = fleet_figure(rows, flagged)
    png = save_figure(figure, out / "fleet.png")
    failed = [r for r in rows if r.get("status") != "ok"]
    sections = [
        f"<p>{len(rows)} test(s) of {len({r['vehicle'] for r in rows})} vehicle(s); "
        f"{len(failed)} failed.</p>",
        figure_html(figure, "fleet", "Identified parameters per vehicle over time."),
        "<h2 id='outliers'>Outliers against the fleet</h2>",
        table_html(
            ["test", "vehicle", "parameter", "value", "fleet median", "robust z"],
            [
                (
                    escape(o.test),
                    escape(o.vehicle),
                    o.parameter,
                    f"{o.value:.4g}",
                    f"{o.fleet_median:.4g}",
                    f"{o.z:+.1f}",
                )
                for o in flagged
            ],
            numeric=(3, 4, 5),
        )
        if flagged
        else f"<p>None beyond {OUTLIER_Z} robust standard scores.</p>",
        "<h2 id='trends'>Trends per vehicle</h2>",
        table_html(
            ["vehicle", "parameter", "tests", "first", "last", "% per 30 days"],
            [
                (
                    escape(t.vehicle),
                    t.parameter,
                    str(t.tests),
                    f"{t.first:.4g}",
                    f"{t.last:.4g}",
                    f"{t.percent_per_30_days:+.2f}",
                )
                for t in found
            ],
            numeric=(2, 3, 4, 5),
        )
        if found
        else "<p>No vehicle has two dated tests yet.</p>",
    ]
    if failed:
        sections.append("<h2 id='failed'>Failed tests</h2>")
        sections.append(
            table_html(
                ["test", "vehicle", "error"],
                [
                    (escape(r["test"]), escape(r["vehicle"]), escape(r.get("error", "")))
                    for r in failed
                ],
            )
        )
    html = write_html(out / "fleet.html", page("drivetrain-id fleet", sections))
    return png, html
