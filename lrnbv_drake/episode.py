"""One reconstruction episode: the cell, a viewpoint policy driving it, and what it writes.

`run_episode` builds the closed loop (cell -> planner -> cell), simulates until the policy
terminates, and writes into the output folder:

- `frames.npz`: every captured frame with its sensor pose and joint configuration;
- `report.json`: the run's settings, every pose, the termination reason and the timings;
- `replay.html`: a self-contained Meshcat replay of the whole motion (when Meshcat is allowed).
"""

from __future__ import annotations

import dataclasses as dc
import json
import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.cell import make_cell, place_object, zone_geometry
from lrnbv_drake.motion import MotionPlanner
from lrnbv_drake.planning.heu import HeuPolicy
from lrnbv_drake.planning.policy import ViewpointPolicy
from lrnbv_drake.scenario import Scenario
from lrnbv_drake.systems.nbv_planner import EpisodeLog, NbvPlanner
from lrnbv_drake.systems.tof_visualizer import ToFVisualizer

log = logging.getLogger(__name__)

PLANNERS = ("heu",)
#: Simulated seconds after which an episode is stopped whatever the policy says.
MAX_EPISODE_SECONDS = 1200.0


@dc.dataclass
class EpisodeResult:
    """What `run_episode` produced."""

    log: EpisodeLog
    report: dict[str, Any]
    out_dir: Path
    wall_seconds: float


def make_policy(planner: str, scenario: Scenario, object_center: np.ndarray) -> ViewpointPolicy:
    """The viewpoint policy called `planner` for this scenario."""
    if planner == "heu":
        return HeuPolicy(object_center)
    raise ValueError(f"unknown planner '{planner}': expected one of {', '.join(PLANNERS)}")


def make_meshcat(live: bool) -> Meshcat | None:
    """A Meshcat for the live view and the replay, or None where Drake may not open one."""
    policy = os.environ.get("DRAKE_ALLOW_NETWORK")
    if policy is not None and "meshcat" not in policy.split(":"):
        log.warning("DRAKE_ALLOW_NETWORK=%s forbids Meshcat: no replay.html is written (set "
                    "DRAKE_ALLOW_NETWORK=meshcat to allow it)", policy)
        return None
    return Meshcat(MeshcatParams(host="localhost" if not live else "*"))


def build_episode(scenario: Scenario, policy: ViewpointPolicy, meshcat: Meshcat | None = None):
    """The closed-loop diagram of an episode; returns (diagram, cell, planner)."""
    builder = DiagramBuilder()
    cell = builder.AddNamedSystem("cell", make_cell(scenario, meshcat))
    motion = MotionPlanner(scenario)
    period = scenario.sensor.period / 2
    planner = builder.AddNamedSystem("planner", NbvPlanner(
        policy, motion, scenario.robot.initial_position, period=period,
        frame_period=scenario.sensor.period, settle_frames=scenario.sensor.settle_frames))
    builder.Connect(cell.GetOutputPort("ur5e.position_measured"),
                    planner.GetInputPort("position_measured"))
    builder.Connect(cell.GetOutputPort("tof.frame"), planner.GetInputPort("tof_frame"))
    builder.Connect(cell.GetOutputPort("tof.pose"), planner.GetInputPort("X_WS"))
    builder.Connect(planner.GetOutputPort("position_command"), cell.GetInputPort("ur5e.position"))
    if meshcat is not None:
        vis = builder.AddNamedSystem("tof_visualizer", ToFVisualizer(
            meshcat, zone_geometry(scenario), publish_period=period,
            show_rays=scenario.visualization.show_rays,
            show_points=scenario.visualization.show_points))
        builder.Connect(planner.GetOutputPort("acquired_frame"), vis.GetInputPort("acquired_frame"))
        builder.Connect(planner.GetOutputPort("acquired_pose"), vis.GetInputPort("acquired_pose"))
    diagram = builder.Build()
    diagram.set_name("episode")
    return diagram, cell, planner


def _report(planner_name: str, scenario: Scenario, episode_log: EpisodeLog, cell,
            wall_seconds: float, sim_seconds: float) -> dict[str, Any]:
    placed = cell.models.placed_object
    return {
        "planner": planner_name,
        "object": scenario.object.name,
        "object_scale": scenario.object.scale,
        "object_pose": [scenario.object.x, scenario.object.y, scenario.object.yaw_deg],
        "seed": scenario.seed,
        "termination": episode_log.termination,
        "n_poses": len(episode_log.acquisitions),
        "poses": [{
            "index": a.index,
            "time": a.time,
            "q": a.q.tolist(),
            "X_WS": a.X_WS.tolist(),
            "n_valid_zones": int(a.frame.valid.sum()),
            "info": a.info,
        } for a in episode_log.acquisitions],
        "motion_failures": [{"time": t, "position": X[:3, 3].tolist(), "failure": f,
                             "reason": r} for t, X, f, r in episode_log.motion_failures],
        "true_object_vertices_bounds": [placed.mesh.bounds[0].tolist(),
                                        placed.mesh.bounds[1].tolist()],
        "timing": {
            "wall_seconds": wall_seconds,
            "simulated_seconds": sim_seconds,
            "policy_seconds": episode_log.policy_seconds,
            "motion_planning_seconds": episode_log.motion_seconds,
        },
        "scenario": yaml_dump_typed(scenario),
    }


def save_frames(path: Path, episode_log: EpisodeLog) -> None:
    """Writes every acquisition (frame, sensor pose, joints, time) to an .npz file."""
    acq = episode_log.acquisitions
    res = acq[0].frame.resolution if acq else 8
    np.savez_compressed(
        path,
        distance_mm=np.array([a.frame.distance_mm for a in acq], np.int16).reshape(-1, res, res),
        status=np.array([a.frame.status for a in acq], np.uint8).reshape(-1, res, res),
        sigma_mm=np.array([a.frame.sigma_mm for a in acq], np.uint16).reshape(-1, res, res),
        sequence=np.array([a.frame.sequence for a in acq], np.int64),
        timestamp_us=np.array([a.frame.timestamp_us for a in acq], np.int64),
        X_WS=np.array([a.X_WS for a in acq], float).reshape(-1, 4, 4),
        q=np.array([a.q for a in acq], float).reshape(-1, 6),
        time=np.array([a.time for a in acq], float),
    )


def run_episode(scenario: Scenario, planner: str, out_dir: str | Path,
                meshcat: Meshcat | None = None) -> EpisodeResult:
    """Runs one episode and writes frames.npz, report.json and (with Meshcat) replay.html."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    # The object's true centre is given to the HEU baseline only, as in the paper.
    center = place_object(scenario).mesh.bounds.mean(axis=0)
    policy = make_policy(planner, scenario, center)
    diagram, cell, planner_system = build_episode(scenario, policy, meshcat)
    simulator = Simulator(diagram)
    if meshcat is not None:
        # Look at the object area from the front-left, a little above the table.
        meshcat.SetCameraPose([1.5, -1.1, 1.0], [0.4, 0.0, 0.15])
        visualizer = cell.visualizer
        visualizer.StartRecording(set_transforms_while_recording=True)
    simulator.Initialize()
    simulator.AdvanceTo(MAX_EPISODE_SECONDS)
    context = simulator.get_context()
    episode_log: EpisodeLog = planner_system.GetOutputPort("log").Eval(
        planner_system.GetMyContextFromRoot(context))
    if not episode_log.termination:
        episode_log.termination = f"stopped at the {MAX_EPISODE_SECONDS:.0f} s time limit"
    save_frames(out_dir / "frames.npz", episode_log)
    wall = time.perf_counter() - started
    report = _report(planner, scenario, episode_log, cell, wall, context.get_time())
    (out_dir / "report.json").write_text(json.dumps(report, indent=2))
    if meshcat is not None:
        visualizer.StopRecording()
        visualizer.PublishRecording()
        (out_dir / "replay.html").write_text(meshcat.StaticHtml())
    return EpisodeResult(log=episode_log, report=report, out_dir=out_dir, wall_seconds=wall)
