"""Run one simulated LR-NBV episode from Python and read its result.

    .venv/bin/python examples/run_episode.py

`run_episode` is what `lrnbv run` calls: it writes frames.npz, report.json and replay.html into
the folder (docs/report-json.md lists the report's fields) and returns the report as a dict,
with the planner's log.
"""

import sys

from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.scenario import Scenario


def _mm(values) -> str:
    return " x ".join(f"{1000 * v:.0f}" for v in values) + " mm"


scenario = Scenario(seed=0)
scenario.object.name = "vertical_box"
result = run_episode(scenario, "lrnbv", "out/example_episode")

metrics = result.report["metrics"]
print(f"{result.report['n_poses']} poses; ended: {result.report['termination']}")
if not metrics["box_found"]:
    sys.exit(f"no object found: {result.report['extraction']}")
print(f"estimated L x W x H {_mm(metrics['estimated_dims'])}, true {_mm(metrics['true_dims'])}")
print(f"IoU {metrics['iou']:.3f}, coverage {metrics['coverage']['0.01']:.1%} within 1 cm")
for acquisition in result.log.acquisitions:
    x, y, z = acquisition.X_WS[:3, 3]
    print(f"pose {acquisition.index}: sensor at ({x:.3f}, {y:.3f}, {z:.3f}) m, "
          f"{int(acquisition.frame.valid.sum())} valid zones")
