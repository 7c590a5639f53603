"""Milliseconds of the shape estimator's final estimate (the box fit, the height map around it
and the interval of the box reported) against the box fit alone, in the same run.

Frames come from simulated LR-NBV episodes of the gripper and the flange (seeds 0..n-1), the
objects the height map is for. Both estimators start from the episode's final cell box and
fit every frame, as the report does once at the end of an episode.

    .venv/bin/python benchmarks/bench_height_map.py [--seeds 2]
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import tempfile
import time

import numpy as np

from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.parts import box_estimator
from lrnbv_drake.station.scenario import Scenario


def _timed_estimate(scenario: Scenario, log) -> tuple[float, str]:
    estimator = box_estimator(scenario)
    for a in log.acquisitions:
        estimator.add(a.frame, a.X_WS)
    started = time.perf_counter()
    fit = estimator.estimate(log.extractions[-1].oriented_box, interval=True)
    return 1e3 * (time.perf_counter() - started), fit.shape


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    shape_ms, box_ms, used = [], [], []
    for name in ("gripper", "flange"):
        for seed in range(args.seeds):
            scenario = Scenario(seed=seed)
            scenario.object = dc.replace(scenario.object, name=name)
            scenario.extraction = dc.replace(scenario.extraction, estimator="shape")
            with tempfile.TemporaryDirectory() as out:
                log = run_episode(scenario, "lrnbv", out).log
            ms, shape = _timed_estimate(scenario, log)
            shape_ms.append(ms)
            used.append(shape)
            scenario.extraction = dc.replace(scenario.extraction, estimator="model")
            box_ms.append(_timed_estimate(scenario, log)[0])
            print(f"{name} seed {seed}: {len(log.acquisitions)} poses, shape estimate "
                  f"{shape_ms[-1]:.0f} ms ({shape}), box fit {box_ms[-1]:.0f} ms")
    ratio = np.array(shape_ms) / np.array(box_ms)
    print(f"final estimate, median of {len(shape_ms)} episodes: shape {np.median(shape_ms):.0f} "
          f"ms, box fit {np.median(box_ms):.0f} ms, ratio {np.median(ratio):.1f}; height map "
          f"reported in {used.count('height_map')} of {len(used)}")


if __name__ == "__main__":
    main()
