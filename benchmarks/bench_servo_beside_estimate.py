"""How late the servo stream's ticks come while the stop check (the box estimate and the stop
rule) runs in a thread beside them, as on the real cell during a move
(core/planning/stop_while_moving.py), against the same stream with nothing beside it in the
same run.

A Drake diagram whose one system publishes every `hardware.servo_period` (8 ms), as the
command sender does, runs at real-time rate 1 while a `StopWhileMoving` thread estimates,
pose after pose, the frames of a simulated HEU episode of an object (the flange by default:
the slowest estimate of the paper objects). It prints the gaps between ticks: median, p99 and
max, and how many exceed twice the period; beside, with the check's parallel kernels on every
core and leaving `SPARE_CORES` to the stream, as the real cell does.

    .venv/bin/python benchmarks/bench_servo_beside_estimate.py [--object flange] [--seconds 8]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from unittest import mock

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, EventStatus, LeafSystem

from lrnbv_drake.core.acquisition import estimator_inputs
from lrnbv_drake.core.planning import stop_while_moving
from lrnbv_drake.core.planning.stop import BoxStop
from lrnbv_drake.core.planning.stop_while_moving import StopWhileMoving
from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.parts import episode_estimator
from lrnbv_drake.station.scenario import Scenario, override


class Ticks(LeafSystem):
    """Notes the wall time of each periodic publish."""

    def __init__(self, period: float) -> None:
        super().__init__()
        self.times: list[float] = []
        self.DeclarePeriodicPublishEvent(period, 0.0, self._tick)

    def _tick(self, context) -> EventStatus:
        self.times.append(time.perf_counter())
        return EventStatus.Succeeded()


def gaps(seconds: float, period: float, beside=None) -> np.ndarray:
    """The gaps between ticks, seconds, over `seconds` of real time; `beside()` is called
    every tick (to keep a check running)."""
    builder = DiagramBuilder()
    ticks = builder.AddSystem(Ticks(period))
    if beside is not None:
        ticks.DeclarePeriodicPublishEvent(period, 0.0, lambda context: beside())
    simulator = Simulator(builder.Build())
    simulator.set_target_realtime_rate(1.0)
    simulator.AdvanceTo(seconds)
    return np.diff(ticks.times)


def gaps_beside_checks(scenario: Scenario, readings, boxes, seconds: float, spare: int
                       ) -> tuple[np.ndarray, int]:
    """`gaps` with a threaded stop check started again as soon as the last is done, pose
    after pose, its kernels leaving `spare` cores; and how many checks were started."""
    estimator = episode_estimator(scenario)
    estimator.update(readings[:1], boxes[:1])
    dut = StopWhileMoving(estimator, BoxStop(scenario.planner.stop), threaded=True)
    poses = [1]

    def keep_checking() -> None:
        if (dut.running and dut.result(0.0) is None) or poses[-1] == len(readings):
            return
        poses.append(poses[-1] + 1)
        dut.start(readings[:poses[-1]], boxes[:poses[-1]], 0.0)

    with mock.patch.object(stop_while_moving, "SPARE_CORES", spare):
        return gaps(seconds, scenario.hardware.servo_period, keep_checking), len(poses) - 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="flange")
    parser.add_argument("--seconds", type=float, default=8.0)
    args = parser.parse_args()

    scenario = override(Scenario(seed=0), {"object": {"name": args.object}})
    with tempfile.TemporaryDirectory() as out:
        log = run_episode(override(scenario, {"extraction": {"estimator": "cells"}}), "heu",
                          out).log
    readings, boxes = estimator_inputs(log)
    period = scenario.hardware.servo_period
    # Every kernel the checks call compiled (or loaded) before anything is timed.
    BoxStop(scenario.planner.stop).update(episode_estimator(scenario).update(readings, boxes))
    alone = gaps(args.seconds, period)
    results = [("nothing beside (peer)", alone)]
    for spare in (0, stop_while_moving.SPARE_CORES):
        g, n = gaps_beside_checks(scenario, readings, boxes, args.seconds, spare)
        results.append((f"stop checks beside ({n} poses of the {args.object}), {spare} "
                        f"spare core{'s' if spare != 1 else ''}", g))
    for name, g in results:
        print(f"servo ticks every {1e3 * period:.0f} ms, {name}: gap median "
              f"{1e3 * np.median(g):.2f} ms, p99 {1e3 * np.percentile(g, 99):.2f}, max "
              f"{1e3 * g.max():.2f}; over {2e3 * period:.0f} ms: {int((g > 2 * period).sum())} "
              f"of {len(g)}; max gap / the peer's: {g.max() / alone.max():.2f}x")


if __name__ == "__main__":
    main()
