"""The arm's moves of recorded episodes planned again with this tree's motion planner: each
move from the joints the episode held to the view it took next, in the episode's own cell.
Prints the moves, the milliseconds planning each took (median, p95, max) and the seconds the
planned motions take in all, against the recorded episodes' own. The views do not depend on
the motion planner's choice of path, so a change of it is measured on the same moves.

    .venv/bin/python benchmarks/replan_moves.py out/results/paper/runs/lrnbv__*
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from lrnbv_drake.experiments.refit import load_episode
from lrnbv_drake.station.motion import MotionPlanner


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", help="recorded episodes' folders")
    args = parser.parse_args()
    seconds, motion, recorded, failed = [], 0.0, 0.0, 0
    for folder in args.folders:
        episode = load_episode(folder)
        report = json.loads((episode.folder / "report.json").read_text())
        planner = MotionPlanner(episode.scenario)
        q = np.asarray(episode.scenario.robot.initial_position, float)
        for pose in report["poses"]:
            started = time.perf_counter()
            plan = planner.plan(q, np.asarray(pose["X_WS"], float))
            seconds.append(time.perf_counter() - started)
            if plan.ok:
                motion += plan.trajectory.end_time()
            else:
                failed += 1
            q = np.asarray(pose["q"], float)
        recorded += report["cycle_time"]["motion_s"]
    median, p95, most = 1000 * np.percentile(seconds, [50, 95, 100])
    print(f"{len(seconds)} moves of {len(args.folders)} episodes ({failed} not planned): "
          f"planning {median:.1f} ms median, p95 {p95:.1f}, max {most:.1f}; the arm's motion "
          f"{motion:.1f} s planned now, {recorded:.1f} s recorded")


if __name__ == "__main__":
    main()
