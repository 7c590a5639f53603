"""Run one simulated LR-NBV episode from Python and read its result.

    .venv/bin/python examples/run_episode.py
"""

from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.scenario import Scenario

scenario = Scenario(seed=0)
scenario.object.name = "gripper"
result = run_episode(scenario, "lrnbv", "out/example_episode")

metrics = result.report["metrics"]
print(f"{result.report['n_poses']} poses; ended: {result.report['termination']}")
print(f"estimated L x W x H {metrics['estimated_dims']} m, true {metrics['true_dims']} m")
print(f"IoU {metrics['iou']:.3f}, coverage {metrics['coverage']['0.01']:.1%} within 1 cm")
for acquisition in result.log.acquisitions:
    print(f"pose {acquisition.index}: sensor at {acquisition.X_WS[:3, 3].round(3)}, "
          f"{int(acquisition.frame.valid.sum())} valid zones")
