r"""Interval coverage: how many profile intervals of the identification trial hold the truth.

Reads the JSON files that ``benchmarks/identification_trial.py --truth N --profile-points P
--json tN.json`` wrote, redraws each truth from its number, and prints per recording the
intervals that hold it (all, and those closed on both sides: an open ``no`` interval holds any
truth), the misses with their intervals, eq. (17) found, at the truth and at the optimum nearest
it, and whether the search restarted from a profile; then the totals. Issue 15 asks that the
95 % intervals hold the truth in at least 90 % of cases over 30 or more recordings. Not a test:
nothing is asserted.

    PYTHONPATH=. python benchmarks/interval_coverage.py \
        benchmarks/results/identification_trial/*.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmarks.identification_trial import draw_truth
from dtid.identification.search.parameterization import theta_from_parameters


def coverage(document: dict) -> tuple[list[int], list[str]]:
    """Of one trial's profiles: the counts of intervals, those holding the truth, closed ones and
    closed ones holding it; and a line per miss."""
    truth = theta_from_parameters(draw_truth(int(document["truth"])))
    counts = [0, 0, 0, 0]
    misses = []
    for name, profile in document["profiles"].items():
        lower, upper = profile["interval"]["lower"], profile["interval"]["upper"]
        value = truth[name]
        holds = (lower is None or lower <= value) and (upper is None or value <= upper)
        closed = lower is not None and upper is not None
        for i, counted in enumerate((True, holds, closed, holds and closed)):
            counts[i] += counted
        if not holds:
            ends = f"{lower:.4g}-{upper:.4g}" if closed else f"({lower}, {upper})"
            misses.append(f"{name} {ends} for {value:.4g}")
    return counts, misses


def main() -> None:
    """Print the coverage of the trials given."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path, help="identification_trial.py --json files")
    args = parser.parse_args()
    documents = sorted(
        (json.loads(path.read_text(encoding="utf-8")) for path in args.files),
        key=lambda d: int(d["truth"]),
    )
    totals = [0, 0, 0, 0]
    for document in documents:
        counts, misses = coverage(document)
        totals = [t + c for t, c in zip(totals, counts, strict=True)]
        objective = document["objective"]
        print(
            f"truth {document['truth']}: {counts[1]} of {counts[0]} hold, closed {counts[3]} of "
            f"{counts[2]}; eq. 17 found {objective['found']:.4f}, at the truth "
            f"{objective['truth']:.4f}, nearest it {objective['nearest']:.4f}"
            + ("; the search restarted" if document.get("search_restart") else "")
            + (f"; misses: {'; '.join(misses)}" if misses else "")
        )
    print(
        f"{len(documents)} recordings: {totals[1]} of {totals[0]} intervals hold the truth "
        f"({100 * totals[1] / totals[0]:.1f} %), closed {totals[3]} of {totals[2]} "
        f"({100 * totals[3] / max(totals[2], 1):.1f} %)"
    )


if __name__ == "__main__":
    main()
