"""Whether the map's unknown space beside the reported box tells a confident stop on a wrong
box from one on a right box (record 0031).

For each recorded episode that ended on the box stop, the map is rebuilt from its frames
(the map is a function of them) and the cells in a shell around the reported box, within
`--shell` of its sides and from a cell above the table to a centimetre above its top, are
classified: the share still unknown is what a stop asking "could a part hide beside the
estimate?" would read. The summary compares the stops whose worst dimension is more than
`--wrong-mm` off with the others (medians, and the probability that a wrong stop's share
exceeds a right one's: 0.5 is no signal). Simulated episodes only: their reports hold the
truth.

    .venv/bin/python benchmarks/unknown_beside_box.py out/results/{family,paper}/runs/lrnbv__*
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import scipy.stats

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.planning.utility import UNKNOWN
from lrnbv_drake.experiments.refit import load_episode
from lrnbv_drake.station.parts import map_system

#: How the box stop's reason begins (core/planning/stop.py, `BoxStop.update`).
BOX_STOP = "the box held still"


def unknown_share(folder: Path, shell: float) -> float:
    """The share of unknown cells within `shell` of the reported box's sides."""
    episode = load_episode(folder)
    occupancy = map_system(episode.scenario, period=None)
    occupancy.insert_recorded(occupancy.CreateDefaultContext(), episode.readings)
    grid = occupancy.occupancy_map
    entry = episode.reported
    box = OrientedBox(np.array(entry["center"]), np.array(entry["dims"]), entry["yaw"])
    table, step = episode.scenario.cell.table_height, grid.resolution / 2
    half = box.dims[:2] / 2 + shell
    x, y, z = np.meshgrid(np.arange(-half[0], half[0], step), np.arange(-half[1], half[1], step),
                          np.arange(table + 1.2 * grid.resolution, table + box.dims[2] + 0.01,
                                    step), indexing="ij")
    xy = np.c_[x.ravel(), y.ravel()] @ box.rotation_xy().T + box.center[:2]
    points = np.c_[xy, z.ravel()]
    beside = points[~box.contains(np.c_[points[:, :2], np.full(len(points), box.center[2])])]
    return float(np.mean(grid.classify(beside) == UNKNOWN))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--shell", type=float, default=0.02, help="metres beside the box")
    parser.add_argument("--wrong-mm", type=float, default=10.0)
    args = parser.parse_args()
    wrong, right = [], []
    for folder in args.folders:
        report = json.loads((folder / "report.json").read_text())
        if (not report["termination"].startswith(BOX_STOP)
                or not report.get("metrics", {}).get("dim_errors_mm")):
            continue  # another stop, or no truth (the real cell)
        worst = max(abs(v) for v in report["metrics"]["dim_errors_mm"])
        share = unknown_share(folder, args.shell)
        (wrong if worst > args.wrong_mm else right).append(share)
        print(json.dumps({"folder": str(folder), "worst_mm": worst, "unknown": round(share, 3)}),
              flush=True)
    if not (wrong and right):
        print(f"{len(wrong)} wrong and {len(right)} right box stops among the folders: "
              f"nothing to compare")
    else:
        u = scipy.stats.mannwhitneyu(wrong, right).statistic / len(wrong) / len(right)
        print(f"unknown within {1000 * args.shell:.0f} mm: wrong stops (> {args.wrong_mm:g} mm) "
              f"median {np.median(wrong):.3f} (n {len(wrong)}), right {np.median(right):.3f} "
              f"(n {len(right)}); P(wrong > right) = {u:.2f}")


if __name__ == "__main__":
    main()
