"""Pose by pose, where the estimator searched a recorded episode's readings cold and why
(record 0032): after each pose, every search (warm or cold, the zones fitted, the structure
it ended on) and the misfit after it (flagged or not, the bare table's beside it: a cold
search follows a flagged refit only where the table is not flagged; the zones beyond
`fit.OUTLIER` sigmas), and the worst dimension's error against the truth. A diagnostic: it
wraps the estimator's private search and misfit steps to see them.

    .venv/bin/python benchmarks/trace_cold_searches.py out/results/paper/runs/nbv__flange__3
"""

from __future__ import annotations

import argparse

import numpy as np

from lrnbv_drake.core.estimation.fit import _outliers
from lrnbv_drake.experiments.refit import load_episode
from lrnbv_drake.station.parts import episode_estimator


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    args = parser.parse_args()
    episode = load_episode(args.folder)
    tracked = episode_estimator(episode.scenario)
    estimator = tracked._estimator
    search, misfits, steps = estimator._search, estimator._misfits, []

    def traced_search(problem, starts, cold):
        fit = search(problem, starts, cold)
        steps.append(f"{'cold' if cold else 'warm'} search of {len(problem)} zones: "
                     f"{fit.shape.name()}")
        return fit

    def traced_misfits(problem, fit):
        out = misfits(problem, fit)
        steps.append(f"misfit {out[0]:.2f}{' flagged' if out[1] else ''} (the table's "
                     f"{out[2]:.2f}{' flagged' if out[3] else ''}), "
                     f"{int(_outliers(problem, fit).sum())} outlier zones")
        return out

    estimator._search, estimator._misfits = traced_search, traced_misfits
    for i in range(len(episode.readings)):
        steps.clear()
        latest = tracked.update(episode.readings[:i + 1], episode.cell_boxes[:i + 1]).latest
        error = ("" if latest is None or episode.true is None else
                 f"worst error {1000 * np.abs(latest.box.dims - episode.true.dims).max():.0f} mm; ")
        print(f"pose {i + 1}: {error}{'; '.join(steps)}", flush=True)


if __name__ == "__main__":
    main()
