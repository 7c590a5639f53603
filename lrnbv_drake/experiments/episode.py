"""One reconstruction episode: the closed loop around the cell, and the one runner that both
the simulated episode and the session on the real cell go through.

`build_episode` wires cell -> acquisition loop -> cell with the map and the clustering;
`run_loop` simulates it until the policy ends it or a fault stops it, stops the arm and records
whatever happens; `write_outputs` leaves in the output folder:

- `frames.npz`: every captured frame with its sensor pose and joint configuration;
- `report.json`: the run's settings, the estimated box, every pose, the termination, timings;
- `replay.html`: a self-contained Meshcat replay of the whole motion (when Meshcat is allowed).

`run_episode` is the simulated episode; `experiments.session` adds the real cell's journal,
confirmation and resume around the same runner.
"""

from __future__ import annotations

import dataclasses as dc
import json
import logging
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.geometry import Box, Meshcat, MeshcatParams, Rgba, Sphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, EventStatus

from lrnbv_drake.core.acquisition import Acquisition, EpisodeLog
from lrnbv_drake.core.estimation.track import EstimateTrack
from lrnbv_drake.core.kernels import compile_kernels
from lrnbv_drake.core.planning.policy import ViewpointPolicy
from lrnbv_drake.core.planning.stop_while_moving import StopWhileMoving
from lrnbv_drake.core.robot.safety import RobotFault
from lrnbv_drake.drivers.tof_serial import SensorError
from lrnbv_drake.experiments.recording import save_frames, write_atomically
from lrnbv_drake.experiments.report import (
    accuracy_metrics,
    episode_metrics,
    episode_report,
    json_default,
    rounded,
)
from lrnbv_drake.experiments.report_page import report_page
from lrnbv_drake.station.cell import Cell, make_cell
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.parts import (
    COMMISSION,
    PLANNERS,
    SIMULATION_PLANNERS,
    check_scenario_files,
    episode_estimator,
    extraction_params,
    make_policy,
    make_self_filter,
    make_stop,
    map_system,
    packing_decision,
    zone_geometry,
)
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.station.scenario_checks import check_placement, check_ranges
from lrnbv_drake.systems.acquisition_loop import AcquisitionLoop
from lrnbv_drake.systems.box_estimation import BoxEstimation
from lrnbv_drake.systems.object_clustering import ObjectClustering
from lrnbv_drake.systems.occupancy_map import OccupancyMapSystem
from lrnbv_drake.systems.planner_visualizer import PlannerVisualizer
from lrnbv_drake.systems.tof_visualizer import ToFVisualizer

__all__ = ["PLANNERS", "SIMULATION_PLANNERS", "EpisodeDiagram", "EpisodeResult", "EpisodeRun",
           "build_episode", "final_estimates", "make_meshcat", "run_episode", "run_loop",
           "write_outputs"]

log = logging.getLogger(__name__)

#: Simulated seconds after which an episode is stopped whatever the policy says.
MAX_EPISODE_SECONDS = 1200.0


def make_meshcat(live: bool) -> Meshcat | None:
    """A Meshcat for the live view and the replay, or None where Drake may not open one.
    Live, it listens on every interface (to watch from another machine); else on localhost."""
    policy = os.environ.get("DRAKE_ALLOW_NETWORK")
    if policy is not None and "meshcat" not in policy.split(":"):
        log.warning("DRAKE_ALLOW_NETWORK=%s forbids Meshcat: no replay.html is written (set "
                    "DRAKE_ALLOW_NETWORK=meshcat to allow it)", policy)
        return None
    return Meshcat(MeshcatParams(host="localhost" if not live else "*"))


@dc.dataclass
class EpisodeDiagram:
    """The closed loop of an episode and the parts a runner reads."""

    scenario: Scenario
    diagram: Diagram
    cell: Cell
    loop: AcquisitionLoop
    map_system: OccupancyMapSystem
    # None while commissioning: the bare table has no object to estimate.
    estimation: BoxEstimation | None
    policy: ViewpointPolicy


def build_episode(scenario: Scenario, planner: str, meshcat: Meshcat | None = None,
                  hardware: bool = False, history: EpisodeLog | None = None) -> EpisodeDiagram:
    """The closed-loop diagram of an episode: cell, map, clustering and the acquisition loop.

    With `hardware`, the cell is the real one (`make_cell(..., hardware=True)`); everything
    else is the same diagram. The `COMMISSION` planner's cell is the bare table. `history`
    goes to the loop (an episode to carry on); `run_loop` restores the map and the policy to
    match it.

    Raises:
        ScenarioError: a field out of range or not one of its choices (a scenario built in
            code, not loaded), before anything is made or connected.
    """
    check_ranges(scenario)
    cell = make_cell(scenario, meshcat, hardware=hardware, bare_table=planner == COMMISSION)
    try:
        return _around_cell(cell, scenario, planner, meshcat, history)
    except BaseException:
        # On hardware the robot is connected and the control script uploaded: a failure (or
        # Ctrl-C) while building the rest must not leave them, nor the watchdog's keeper.
        if cell.hardware is not None:
            cell.hardware.close()
        raise


def _around_cell(cell: Cell, scenario: Scenario, planner: str, meshcat: Meshcat | None,
                 history: EpisodeLog | None) -> EpisodeDiagram:
    """`build_episode`'s diagram around a cell already made."""
    builder = DiagramBuilder()
    builder.AddNamedSystem("cell", cell.diagram)
    motion = MotionPlanner(scenario, bare_table=cell.models.placed_object is None)
    policy = make_policy(planner, scenario, motion, cell.models.placed_object)
    period = scenario.sensor.period / 2
    stop = make_stop(planner, scenario)
    estimator = episode_estimator(scenario) if planner != COMMISSION else None
    # The real cell checks the stop in a thread beside the move; the simulated one models it
    # (core/planning/stop_while_moving.py).
    beside = None if estimator is None or not scenario.planner.stop.while_moving else \
        StopWhileMoving(estimator, stop, threaded=cell.hardware is not None)
    loop = builder.AddNamedSystem("acquisition_loop", AcquisitionLoop(
        policy, motion, scenario.robot.initial_position, period=period,
        frame_period=scenario.sensor.period, settle_frames=scenario.sensor.settle_frames,
        max_poses=scenario.max_poses, history=history, stop=stop,
        self_filter=make_self_filter(scenario, motion), stop_while_moving=beside))
    estimation = None
    if estimator is not None:
        estimation = builder.AddNamedSystem("estimation", BoxEstimation(estimator))
        builder.Connect(loop.GetOutputPort("log"), estimation.GetInputPort("log"))
        builder.Connect(estimation.GetOutputPort("box_estimate"),
                        loop.GetInputPort("box_estimate"))
    occupancy = builder.AddNamedSystem("map", map_system(scenario, period))
    clustering = builder.AddNamedSystem("clustering",
                                        ObjectClustering(extraction_params(scenario)))
    builder.Connect(loop.GetOutputPort("acquired_frame"), occupancy.GetInputPort("tof_frame"))
    builder.Connect(loop.GetOutputPort("acquired_pose"), occupancy.GetInputPort("X_WS"))
    builder.Connect(occupancy.GetOutputPort("map"), loop.GetInputPort("map"))
    builder.Connect(occupancy.GetOutputPort("occupied_points"),
                    clustering.GetInputPort("occupied_points"))
    builder.Connect(clustering.GetOutputPort("object"), loop.GetInputPort("object"))
    builder.Connect(cell.diagram.GetOutputPort("ur5e.position_measured"),
                    loop.GetInputPort("position_measured"))
    builder.Connect(cell.diagram.GetOutputPort("tof.frame"), loop.GetInputPort("tof_frame"))
    builder.Connect(cell.diagram.GetOutputPort("tof.pose"), loop.GetInputPort("X_WS"))
    builder.Connect(loop.GetOutputPort("position_command"),
                    cell.diagram.GetInputPort("ur5e.position"))
    if meshcat is not None:
        vis = builder.AddNamedSystem("tof_visualizer", ToFVisualizer(
            meshcat, zone_geometry(scenario), publish_period=period,
            show_rays=scenario.tof_view.show_rays, show_points=scenario.tof_view.show_points))
        builder.Connect(loop.GetOutputPort("acquired_frame"), vis.GetInputPort("acquired_frame"))
        builder.Connect(loop.GetOutputPort("acquired_pose"), vis.GetInputPort("acquired_pose"))
        view = builder.AddNamedSystem("planner_visualizer", PlannerVisualizer(
            meshcat, publish_period=period, cell_size=scenario.mapping.resolution))
        builder.Connect(loop.GetOutputPort("plan"), view.GetInputPort("plan"))
        builder.Connect(clustering.GetOutputPort("object"), view.GetInputPort("object"))
        builder.Connect(occupancy.GetOutputPort("occupied_points"),
                        view.GetInputPort("occupied_points"))
    diagram = builder.Build()
    diagram.set_name("episode")
    return EpisodeDiagram(scenario, diagram, cell, loop, occupancy, estimation, policy)


@dc.dataclass
class EpisodeRun:
    """How a run of the loop ended."""

    log: EpisodeLog
    # Why it ended, as a sentence (the fault's message after a fault).
    termination: str
    # None when the policy ended it; else "interrupted", "sensor", "error" (an unexpected
    # exception, raised again by `write_outputs`'s caller) or a `RobotFault.kind`.
    fault: str | None
    error: Exception | None
    sim_seconds: float
    wall_seconds: float
    context: Context


def episode_log(parts: EpisodeDiagram, root_context: Context) -> EpisodeLog:
    """The acquisition loop's log in a context of the episode diagram."""
    return parts.loop.GetOutputPort("log").Eval(parts.loop.GetMyContextFromRoot(root_context))


def final_estimates(parts: EpisodeDiagram, root_context: Context) -> tuple[EstimateTrack,
                                                                           float]:
    """The episode's estimate track with every acquisition in (`BoxEstimation.final_track`),
    and the seconds of the estimates that only this folded in (the loop timed the others
    in its planning); an empty track where nothing is estimated (commissioning)."""
    if parts.estimation is None:
        return EstimateTrack(), 0.0
    context = parts.estimation.GetMyContextFromRoot(root_context)
    before = len(parts.estimation.made.estimates)
    track = parts.estimation.final_track(context)
    return track, float(sum(track.seconds[before:]))


def run_loop(parts: EpisodeDiagram, *, realtime_rate: float = 0.0,
             recorded: Sequence[Acquisition] = (),
             make_monitor: Callable[[Simulator], Callable[[Context], EventStatus]] | None
             = None,
             on_stop: Callable[[Context, str | None], None] = lambda context, fault: None,
             interrupt_hint: str = "") -> EpisodeRun:
    """Simulates the episode until the policy ends it, a fault stops it, or Ctrl-C.

    `recorded` acquisitions (the loop's history) are re-inserted into the map and replayed
    into the policy first, and diagram time carries on after the last one. The monitor that
    `make_monitor(simulator)` returns runs after every step. `on_stop(context, fault)` runs
    whatever happened (the real cell stops the arm and writes its journal there), before this
    returns.
    """
    started = time.perf_counter()
    simulator = Simulator(parts.diagram)
    context = simulator.get_mutable_context()
    if recorded:
        context.SetTime(recorded[-1].time + 1.0)
        parts.map_system.insert_recorded(
            parts.map_system.GetMyMutableContextFromRoot(context),
            [(a.frame, a.X_WS) for a in recorded])
        parts.policy.restore(list(recorded))
    if make_monitor is not None:
        simulator.set_monitor(make_monitor(simulator))
    simulator.set_target_realtime_rate(realtime_rate)
    meshcat = parts.cell.meshcat
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=1.0 / parts.scenario.visualization.publish_period,
                               set_visualizations_while_recording=True)
    fault, termination, error = None, "", None
    try:
        simulator.Initialize()
        simulator.AdvanceTo(context.get_time() + MAX_EPISODE_SECONDS)
    except RobotFault as e:
        fault, termination = e.kind, str(e)
    except SensorError as e:
        fault, termination = "sensor", str(e)
    except KeyboardInterrupt:
        fault, termination = "interrupted", "interrupted by the operator (Ctrl-C)" + (
            f"; {interrupt_hint}" if interrupt_hint else "")
    except Exception as e:  # recorded like any fault; the caller raises it again
        fault, termination, error = "error", f"{type(e).__name__}: {e}", e
    finally:
        on_stop(context, fault)
    the_log = episode_log(parts, context)
    termination = termination or the_log.termination or (
        f"stopped at the {MAX_EPISODE_SECONDS:.0f} s time limit")
    return EpisodeRun(the_log, termination, fault, error, context.get_time(),
                      time.perf_counter() - started, context)


def write_outputs(out_dir: Path, run: EpisodeRun, report: dict[str, Any],
                  meshcat: Meshcat | None, scenario: Scenario) -> None:
    """frames.npz, report.json, report.html and (with Meshcat) replay.html, each written
    atomically, the data first."""
    save_frames(out_dir / "frames.npz", run.log.acquisitions)
    write_atomically(out_dir / "report.json", json.dumps(rounded(report), indent=2,
                                                         default=json_default))
    if meshcat is not None:
        meshcat.StopRecording()
        _draw_results(meshcat, report)
        meshcat.PublishRecording()
        write_atomically(out_dir / "replay.html", meshcat.StaticHtml())
    write_atomically(out_dir / "report.html", report_page(
        report, run.log.acquisitions, zone_geometry(scenario), replay=meshcat is not None))


def _draw_results(meshcat: Meshcat, report: dict[str, Any]) -> None:
    """The result over the replay: the estimated box (red) and, in simulation, the true box
    (green), translucent, and a blue dot at every sensor pose; their names in Meshcat's scene
    tree are the legend. The camera starts close to the object."""
    boxes = (("estimated box (red)", report["estimated_box"], Rgba(0.9, 0.1, 0.1, 0.35)),
             ("true box (green)", report.get("metrics", {}).get("true_box"),
              Rgba(0.1, 0.8, 0.2, 0.35)))
    for name, entry, colour in boxes:
        if entry is None:
            continue
        path = f"/results/{name}"
        meshcat.SetObject(path, Box(*entry["dims"]), colour)
        meshcat.SetTransform(path, RigidTransform(RotationMatrix.MakeZRotation(entry["yaw"]),
                                                  entry["center"]))
    for pose in report["poses"]:
        path = f"/results/sensor poses (blue)/{pose['index']:03d}"
        meshcat.SetObject(path, Sphere(0.01), Rgba(0.1, 0.3, 0.9, 1.0))
        meshcat.SetTransform(path, RigidTransform(np.asarray(pose["X_WS"])[:3, 3]))
    centre = (report["estimated_box"] or {}).get("center", [0.5, 0.0, 0.1])
    meshcat.SetCameraPose(np.add(centre, [0.6, -0.6, 0.5]), centre)


@dc.dataclass
class EpisodeResult:
    """What `run_episode` produced."""

    log: EpisodeLog
    report: dict[str, Any]
    out_dir: Path
    wall_seconds: float


def run_episode(scenario: Scenario, planner: str, out_dir: str | Path,
                meshcat: Meshcat | None = None, realtime_rate: float = 0.0) -> EpisodeResult:
    """Runs one simulated episode and writes its outputs into `out_dir` (see the module doc).

    `realtime_rate` 1.0 plays the episode at the speed of the real arm (to watch it live);
    0 runs as fast as it computes.
    """
    check_placement(scenario)
    check_scenario_files(scenario)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # Before the clock starts: the episode's computation times are the loop's, not numba's
    # compiling (a cache any edit of the source leaves cold).
    compile_kernels()
    started = time.perf_counter()
    parts = build_episode(scenario, planner, meshcat)
    if meshcat is not None:
        # Look at the object area from the front-left, a little above the table.
        meshcat.SetCameraPose([1.2, -0.8, 0.8], [0.5, 0.0, 0.1])
    run = run_loop(parts, realtime_rate=realtime_rate,
                   interrupt_hint=f"what was captured is in {out_dir}")
    wall = time.perf_counter() - started
    try:
        track, report_seconds = final_estimates(parts, run.context)
        decision = packing_decision(scenario, track.latest)
        report = episode_report(planner, scenario, run.log, track, decision,
                                termination=run.termination, wall_seconds=wall,
                                sim_seconds=run.sim_seconds,
                                map_update_seconds=parts.map_system.insert_seconds,
                                report_seconds=report_seconds)
        placed = parts.cell.models.placed_object
        estimated = None if track.latest is None else track.latest.box
        report["metrics"] = {**episode_metrics(scenario, placed, run.log, estimated).to_dict(),
                             **accuracy_metrics(scenario, placed, track, decision)}
    except BaseException:
        save_frames(out_dir / "frames.npz", run.log.acquisitions)  # the captured data first
        raise
    if run.fault is not None:
        report["fault"] = run.fault
    write_outputs(out_dir, run, report, meshcat, scenario)
    if run.error is not None:
        raise run.error
    if run.fault == "interrupted":
        raise KeyboardInterrupt(run.termination)
    return EpisodeResult(log=run.log, report=report, out_dir=out_dir, wall_seconds=wall)
