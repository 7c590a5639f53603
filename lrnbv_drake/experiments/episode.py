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

from lrnbv_drake.core import metrics
from lrnbv_drake.core.boxes import AlignedBox
from lrnbv_drake.core.objects import PlacedObject, sample_surface
from lrnbv_drake.core.perception import ExtractionParams
from lrnbv_drake.core.planning.heu import HeuPolicy
from lrnbv_drake.core.planning.lrnbv import LrNbvPolicy
from lrnbv_drake.core.planning.policy import ViewpointPolicy
from lrnbv_drake.station.cell import make_cell, zone_geometry
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.scenario import Scenario, ScenarioError
from lrnbv_drake.systems.acquisition_loop import AcquisitionLoop, EpisodeLog
from lrnbv_drake.systems.object_clustering import ObjectClustering
from lrnbv_drake.systems.occupancy_map import OccupancyMapSystem
from lrnbv_drake.systems.planner_visualizer import PlannerVisualizer
from lrnbv_drake.systems.tof_visualizer import ToFVisualizer

log = logging.getLogger(__name__)

PLANNERS = ("lrnbv", "nbv", "heu")
#: Spacing of the surface samples the coverage metric counts, metres (threshold / 2).
COVERAGE_SPACING = 0.005
#: Simulated seconds after which an episode is stopped whatever the policy says.
MAX_EPISODE_SECONDS = 1200.0


@dc.dataclass
class EpisodeResult:
    """What `run_episode` produced."""

    log: EpisodeLog
    report: dict[str, Any]
    out_dir: Path
    wall_seconds: float


def make_policy(planner: str, scenario: Scenario, motion: MotionPlanner,
                placed: PlacedObject) -> ViewpointPolicy:
    """The viewpoint policy called `planner` for this scenario."""
    if planner == "heu":
        # The object's true centre is given to the HEU baseline only, as in the paper.
        return HeuPolicy(placed.mesh.bounds.mean(axis=0))
    if planner in ("lrnbv", "nbv"):
        return LrNbvPolicy(
            scenario.planner, zone_geometry(scenario),
            workspace=AlignedBox(*(np.asarray(v, float) for v in motion.workspace)),
            ik=motion.ik_batch, collision_free=motion.collision_free,
            table_height=scenario.cell.table_height, seed=scenario.seed, variant=planner)
    raise ValueError(f"unknown planner '{planner}': expected one of {', '.join(PLANNERS)}")


def extraction_params(scenario: Scenario) -> ExtractionParams:
    """The object extraction's parameters from the scenario."""
    e, m = scenario.extraction, scenario.mapping
    return ExtractionParams(
        table_height=scenario.cell.table_height, table_tolerance=e.table_tolerance,
        dbscan_eps=e.dbscan_eps, dbscan_min_samples=e.dbscan_min_samples,
        min_cluster_points=e.min_cluster_points,
        workspace=AlignedBox(np.asarray(m.lower, float), np.asarray(m.upper, float)),
        workspace_center=np.asarray(e.center, float),
        max_center_distance=e.max_center_distance, roi_margin=e.roi_margin,
        cell_size=m.resolution, enclose_cells=e.enclose_cells, seed=scenario.seed)


def make_map_system(scenario: Scenario, period: float) -> OccupancyMapSystem:
    """The occupancy map system from the scenario."""
    m = scenario.mapping
    if m.insertion not in ("ray", "cone"):
        raise ScenarioError(f"field 'mapping.insertion': expected 'ray' or 'cone', got "
                            f"{m.insertion!r}")
    return OccupancyMapSystem(
        bounds=(m.lower, m.upper), resolution=m.resolution, mode=m.insertion,
        geometry=zone_geometry(scenario), max_range=m.max_range if m.max_range > 0 else None,
        period=period, cone_k=m.cone_subrays, free_no_target=m.free_no_target)


def make_meshcat(live: bool) -> Meshcat | None:
    """A Meshcat for the live view and the replay, or None where Drake may not open one."""
    policy = os.environ.get("DRAKE_ALLOW_NETWORK")
    if policy is not None and "meshcat" not in policy.split(":"):
        log.warning("DRAKE_ALLOW_NETWORK=%s forbids Meshcat: no replay.html is written (set "
                    "DRAKE_ALLOW_NETWORK=meshcat to allow it)", policy)
        return None
    return Meshcat(MeshcatParams(host="localhost" if not live else "*"))


@dc.dataclass
class EpisodeDiagram:
    """The closed loop of an episode and the parts a runner reads."""

    diagram: Any
    cell: Any
    planner: AcquisitionLoop
    map_system: OccupancyMapSystem
    policy: ViewpointPolicy


def build_episode(scenario: Scenario, planner: str, meshcat: Meshcat | None = None,
                  hardware: bool = False, history: EpisodeLog | None = None) -> EpisodeDiagram:
    """The closed-loop diagram of an episode: cell, map, clustering and the planner.

    With `hardware`, the cell is the real one (`make_cell(..., hardware=True)`); everything
    else is the same diagram. `history` goes to the planner (`AcquisitionLoop`: an episode to carry
    on); restoring the map and the policy to match it is the caller's part.
    """
    builder = DiagramBuilder()
    cell = builder.AddNamedSystem("cell", make_cell(scenario, meshcat, hardware=hardware))
    motion = MotionPlanner(scenario)
    policy = make_policy(planner, scenario, motion, cell.models.placed_object)
    period = scenario.sensor.period / 2
    loop = builder.AddNamedSystem("planner", AcquisitionLoop(
        policy, motion, scenario.robot.initial_position, period=period,
        frame_period=scenario.sensor.period, settle_frames=scenario.sensor.settle_frames,
        max_poses=scenario.max_poses, history=history))
    map_system = builder.AddNamedSystem("map", make_map_system(scenario, period))
    clustering = builder.AddNamedSystem("clustering",
                                        ObjectClustering(extraction_params(scenario)))
    builder.Connect(loop.GetOutputPort("acquired_frame"), map_system.GetInputPort("tof_frame"))
    builder.Connect(loop.GetOutputPort("acquired_pose"), map_system.GetInputPort("X_WS"))
    builder.Connect(map_system.GetOutputPort("map"), loop.GetInputPort("map"))
    builder.Connect(map_system.GetOutputPort("occupied_points"),
                    clustering.GetInputPort("occupied_points"))
    builder.Connect(clustering.GetOutputPort("object"), loop.GetInputPort("object"))
    builder.Connect(cell.GetOutputPort("ur5e.position_measured"),
                    loop.GetInputPort("position_measured"))
    builder.Connect(cell.GetOutputPort("tof.frame"), loop.GetInputPort("tof_frame"))
    builder.Connect(cell.GetOutputPort("tof.pose"), loop.GetInputPort("X_WS"))
    builder.Connect(loop.GetOutputPort("position_command"), cell.GetInputPort("ur5e.position"))
    if meshcat is not None:
        vis = builder.AddNamedSystem("tof_visualizer", ToFVisualizer(
            meshcat, zone_geometry(scenario), publish_period=period,
            show_rays=scenario.visualization.show_rays,
            show_points=scenario.visualization.show_points))
        builder.Connect(loop.GetOutputPort("acquired_frame"), vis.GetInputPort("acquired_frame"))
        builder.Connect(loop.GetOutputPort("acquired_pose"), vis.GetInputPort("acquired_pose"))
        view = builder.AddNamedSystem("planner_visualizer", PlannerVisualizer(
            meshcat, publish_period=period, cell_size=scenario.mapping.resolution))
        builder.Connect(loop.GetOutputPort("plan"), view.GetInputPort("plan"))
        builder.Connect(clustering.GetOutputPort("object"), view.GetInputPort("object"))
        builder.Connect(map_system.GetOutputPort("occupied_points"),
                        view.GetInputPort("occupied_points"))
    diagram = builder.Build()
    diagram.set_name("episode")
    return EpisodeDiagram(diagram, cell, loop, map_system, policy)


def episode_metrics(scenario: Scenario, placed: PlacedObject,
                    episode_log: EpisodeLog) -> metrics.EpisodeMetrics:
    """Box, coverage and pose metrics of an episode against the true object."""
    final = episode_log.extractions[-1] if episode_log.extractions else None
    estimated = final.oriented_box if final is not None and final.found else None
    table = scenario.cell.table_height
    # The same samples for every planner and trial (seed 0): differences are the planners'.
    samples = sample_surface(placed.mesh, COVERAGE_SPACING, table_height=table, seed=0)
    cells = [e.object_points if e is not None and e.found else np.zeros((0, 3))
             for e in episode_log.extractions]
    return metrics.episode_metrics(estimated, metrics.true_box(placed.mesh.vertices, table),
                                   samples, cells, scenario.mapping.resolution)


def _report(planner_name: str, scenario: Scenario, episode_log: EpisodeLog, parts: EpisodeDiagram,
            wall_seconds: float, sim_seconds: float) -> dict[str, Any]:
    placed = parts.cell.models.placed_object
    final = episode_log.extractions[-1] if episode_log.extractions else None
    found = final is not None and final.found
    return {
        "planner": planner_name,
        "object": scenario.object.name,
        "object_scale": scenario.object.scale,
        "object_pose": [scenario.object.x, scenario.object.y, scenario.object.yaw_deg],
        "seed": scenario.seed,
        "termination": episode_log.termination,
        "n_poses": len(episode_log.acquisitions),
        "metrics": episode_metrics(scenario, placed, episode_log).to_dict(),
        "estimated_box": ({"center": final.oriented_box.center.tolist(),
                           "dims": final.oriented_box.dims.tolist(),
                           "yaw": float(final.oriented_box.yaw)} if found else None),
        "extraction": final.reason if final is not None else "no extraction",
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
        "timing": {
            "wall_seconds": wall_seconds,
            "simulated_seconds": sim_seconds,
            "planning_steps": [{
                "policy_s": p,
                "motion_planning_s": m,
            } for p, m in zip(episode_log.policy_seconds, episode_log.motion_seconds,
                              strict=False)],
            "tree_expansion_s": [a.info["tree_expansion_s"] for a in episode_log.acquisitions
                                 if "tree_expansion_s" in a.info],
            "cache_reevaluation_s": [a.info["cache_reevaluation_s"]
                                     for a in episode_log.acquisitions
                                     if "cache_reevaluation_s" in a.info],
            "map_update_s": list(parts.map_system.insert_seconds),
            "clustering_s": episode_log.clustering_seconds,
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
                meshcat: Meshcat | None = None, realtime_rate: float = 0.0) -> EpisodeResult:
    """Runs one episode and writes frames.npz, report.json and (with Meshcat) replay.html.

    `realtime_rate` 1.0 plays the episode at the speed of the real arm (to watch it live);
    0 runs as fast as it computes.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    parts = build_episode(scenario, planner, meshcat)
    simulator = Simulator(parts.diagram)
    simulator.set_target_realtime_rate(realtime_rate)
    visualizer = parts.cell.visualizer
    if visualizer is not None:
        # Look at the object area from the front-left, a little above the table.
        meshcat.SetCameraPose([1.5, -1.1, 1.0], [0.4, 0.0, 0.15])
        visualizer.StartRecording(set_transforms_while_recording=True)
    simulator.Initialize()
    simulator.AdvanceTo(MAX_EPISODE_SECONDS)
    context = simulator.get_context()
    episode_log: EpisodeLog = parts.planner.GetOutputPort("log").Eval(
        parts.planner.GetMyContextFromRoot(context))
    if not episode_log.termination:
        episode_log.termination = f"stopped at the {MAX_EPISODE_SECONDS:.0f} s time limit"
    save_frames(out_dir / "frames.npz", episode_log)
    wall = time.perf_counter() - started
    report = _report(planner, scenario, episode_log, parts, wall, context.get_time())
    (out_dir / "report.json").write_text(json.dumps(report, indent=2))
    if visualizer is not None:
        visualizer.StopRecording()
        visualizer.PublishRecording()
        (out_dir / "replay.html").write_text(meshcat.StaticHtml())
    return EpisodeResult(log=episode_log, report=report, out_dir=out_dir, wall_seconds=wall)
