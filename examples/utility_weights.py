"""Change the utility weights and see what they do to an episode.

Table 1's weights are the defaults (we = 500, wd = 0.05, wq = 0.08, wv = 500). This runs the
same object and seed with the visited gain switched off, then with a stronger density gain.
A scenario file does the same:

    planner:
      weights: {exploration: 500, density: 5.0, quality: 0.08, visited: 500}

    .venv/bin/python examples/utility_weights.py
"""

import dataclasses as dc

from lrnbv_drake.core.planning.config import UtilityWeights
from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.scenario import Scenario

for label, weights in [
    ("Table 1", UtilityWeights()),
    ("no visited gain", UtilityWeights(visited=0.0)),
    ("density x100", UtilityWeights(density=5.0)),
]:
    scenario = Scenario(seed=2)
    scenario.planner = dc.replace(scenario.planner, weights=weights)
    report = run_episode(scenario, "lrnbv", f"out/example_weights/{label}").report
    m = report["metrics"]
    print(f"{label:16s} {report['n_poses']:3d} poses  IoU {m['iou']:.3f}  "
          f"coverage {m['coverage']['0.01']:.1%}  useless {m['n_useless_poses']}")
