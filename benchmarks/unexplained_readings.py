"""Would a container that also holds the readings the shape does not explain hold the parts
the model cannot draw? Each recorded episode is estimated again pose by pose to its recorded
last pose (`lrnbv refit`'s track); of its final fit, the zones that read nearer than the
shape by more than `fit.OUTLIER` sigmas at a point above the table, in groups of at least
`fit.MIN_OUTLIERS` by single linkage at 3 cm (as `fit._proposed` groups them), are the
unexplained solid. The container is chosen for the interval's upper dimensions and for them
grown to hold those points too, and each is scored against the truth (fits, right size).
Record 0033.

    .venv/bin/python benchmarks/unexplained_readings.py out/results/paper/runs/lrnbv__*
"""

from __future__ import annotations

import argparse

import numpy as np
import scipy.cluster.hierarchy

from lrnbv_drake.core.estimation.fit import MIN_OUTLIERS, OUTLIER
from lrnbv_drake.core.evaluation.packing import choose_container, packing_metrics
from lrnbv_drake.experiments.refit import load_episode
from lrnbv_drake.station.parts import container_catalogue, episode_estimator


def unexplained_points(problem, fit) -> np.ndarray:
    """(n, 3) the unexplained solid readings' points (the module doc)."""
    r = problem.rays
    residual = (r.measured - np.nan_to_num(fit.predicted, nan=np.inf)) / r.sigma
    zones = np.flatnonzero(residual < -OUTLIER)
    points = r.origins[zones] + r.measured[zones, None] * r.directions[zones].mean(axis=1)
    points = points[points[:, 2] > problem.table + 0.005]
    if len(points) < MIN_OUTLIERS:
        return points[:0]
    groups = scipy.cluster.hierarchy.fcluster(
        scipy.cluster.hierarchy.linkage(points, "single"), 0.03, criterion="distance")
    return points[np.bincount(groups)[groups] >= MIN_OUTLIERS]


def holding(box, table: float, points: np.ndarray) -> np.ndarray:
    """(3,) the length, width and height about `box`'s centre and axes that hold `points`."""
    if len(points) == 0:
        return np.zeros(3)
    local = (points[:, :2] - box.center[:2]) @ box.rotation_xy()
    return np.r_[2 * np.abs(local).max(axis=0), points[:, 2].max() - table]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+")
    args = parser.parse_args()
    scores = {"interval": [], "with unexplained": []}
    for folder in args.folders:
        episode = load_episode(folder)
        tracked = episode_estimator(episode.scenario)
        estimate = tracked.update(episode.readings, episode.cell_boxes).latest
        if estimate is None or estimate.shape is None or episode.true is None:
            continue
        problem = tracked._estimator._last_problem
        points = unexplained_points(problem, problem.evaluate(estimate.shape))
        catalogue, clearance = container_catalogue(episode.scenario), \
            episode.scenario.packing.clearance
        upper = estimate.dims_upper
        line = [folder.rstrip("/").split("/")[-1], f"{len(points)} unexplained"]
        for name, need in (("interval", upper),
                           ("with unexplained", np.maximum(upper, holding(
                               estimate.box, problem.table, points)))):
            decision = choose_container(need, np.zeros(3), clearance, catalogue)
            score = packing_metrics(decision, episode.true.dims, catalogue)
            scores[name].append((score["fits"], score["right_size"]))
            line.append(f"{name}: fits {score['fits']}, right size {score['right_size']}")
        print("; ".join(line), flush=True)
    for name, rows in scores.items():
        rows = np.array(rows, bool).reshape(-1, 2)
        print(f"{name}: fits {rows[:, 0].sum()} of {len(rows)}, right size {rows[:, 1].sum()}")


if __name__ == "__main__":
    main()
