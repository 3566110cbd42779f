"""Whole searches of recommended tests against the precision the plan predicted at the truth.

Each ``benchmarks/plan_trial.py --searches N --json F`` file holds, per parameter, the errors of
``dtid identify``'s whole search on N recordings of the recommended test at one truth and the
precision predicted there (1 sigma, first order). One recording per truth gives no scatter of
its own; pooled over truths and parameters, the errors over their predictions do: an honest
prediction gives a root mean square of about 1. The plan's own prediction, the worst of the
prior and the vehicles around it, is the promise; the one at the truth tests the machinery.

    PYTHONPATH=. python benchmarks/search_scatter.py \\
        benchmarks/results/plan_trial/search_truth{1..6}.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from dtid.identification.planning.design import SIGMAS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path, help="plan_trial.py --json files")
    args = parser.parse_args()
    ratios: dict[str, list[float]] = {}  # over the prediction at the truth
    promised: list[float] = []  # over the plan's own (the worst of its vehicles)
    for path in args.results:
        trial = json.loads(path.read_text())
        missed, unsaid = [], []
        said = {u["name"] for u in trial["unmet_at_prior"]}
        for name, p in trial["parameters"].items():
            errors = np.array(p["search_errors"])
            ratios.setdefault(name, []).extend(errors / p["predicted_at_truth"])
            promised.extend(errors / p["predicted_at_prior"])
            worst = 100.0 * float(np.max(np.abs(errors)))
            if worst > p["target_percent"]:
                missed.append(f"{name} {worst:.1f} %")
                if name not in said:
                    unsaid.append(name)
        print(
            f"{trial['truth']}: {trial['searches']} search(es); outside the targets: "
            f"{', '.join(missed) or 'none'}; said upfront unmet: {', '.join(sorted(said)) or '-'}; "
            f"missed and not said: {', '.join(unsaid) or 'none'}"
        )
    everything = np.concatenate([np.array(r) for r in ratios.values()])
    print(f"error / predicted (1 sigma at the truth), rms per parameter over {len(args.results)}:")
    for name, r in ratios.items():
        print(f"  {name:>6} {np.sqrt(np.mean(np.square(r))):5.2f}")
    print(
        f"all {everything.size}: rms {np.sqrt(np.mean(everything**2)):.2f}, "
        f"|ratio| > {SIGMAS:g} in {int(np.sum(np.abs(everything) > SIGMAS))} "
        f"(about {0.0455 * everything.size:.1f} expected of a normal error)"
    )
    promised_rms = float(np.sqrt(np.mean(np.square(promised))))
    print(f"error / the plan's own prediction (the worst of its vehicles): rms {promised_rms:.2f}")


if __name__ == "__main__":
    main()
