"""The one place a `Scenario` becomes the core's parameter objects and the episode's parts, so
every field is read in one place and a new field has one home. The scenario is checked
(`scenario_checks.check_ranges`) where an episode or a refit starts, not here again."""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lrnbv_drake.core.acquisition import SelfFilter, seconds_at_a_view
from lrnbv_drake.core.boxes import AlignedBox
from lrnbv_drake.core.calibration.commissioning import TableViews, table_view_poses
from lrnbv_drake.core.estimation.estimator import BoxEstimate, ShapeEstimator
from lrnbv_drake.core.estimation.track import EpisodeEstimator
from lrnbv_drake.core.evaluation.metrics import true_box
from lrnbv_drake.core.evaluation.objects import PlacedObject
from lrnbv_drake.core.evaluation.oracle import ORACLE, oracle_policy
from lrnbv_drake.core.evaluation.packing import (
    CatalogueError,
    Container,
    PackingDecision,
    container_for,
    load_catalogue,
)
from lrnbv_drake.core.mapping.extraction import ExtractionParams
from lrnbv_drake.core.planning.first_view import drop_zone_view
from lrnbv_drake.core.planning.heu import HeuPolicy
from lrnbv_drake.core.planning.lrnbv import LrNbvPolicy
from lrnbv_drake.core.planning.policy import ViewpointPolicy
from lrnbv_drake.core.planning.stop import BoxStop
from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.safety import SafetyLimits
from lrnbv_drake.core.robot.self_filter import drop_robot_zones
from lrnbv_drake.core.sensing.sensor import NoiseModel, SensorModelParams, ToFFrame, ZoneGeometry
from lrnbv_drake.core.sensing.tof_device import (
    PROFILES,
    DeviceBehaviour,
    DeviceProfile,
    st_zone_centres_deg,
)
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.resources import resolve_url
from lrnbv_drake.station.scenario import Scenario, ScenarioError
from lrnbv_drake.systems.occupancy_map import OccupancyMapSystem

#: The viewpoint policies of a cell, simulated or real.
PLANNERS = ("lrnbv", "nbv", "heu")
#: The policies `make_policy` knows in the simulated cell: also the oracle, which knows the
#: true object (`core.evaluation.oracle`).
SIMULATION_PLANNERS = (*PLANNERS, ORACLE)
#: The policy of `lrnbv hardware commission`: the planned views of the bare table
#: (`core.calibration.commissioning.TableViews`); its cell has no object.
COMMISSION = TableViews.name


def zone_geometry(scenario: Scenario) -> ZoneGeometry:
    """The sensor's zone geometry."""
    s = scenario.sensor
    return ZoneGeometry(resolution=s.resolution, fov_deg=s.fov_deg, flip_x=s.flip_x,
                        flip_y=s.flip_y, transpose=s.transpose,
                        centres_deg=_zone_centres(s.zone_directions, s.resolution,
                                                  "sensor.zone_directions"))


def sensor_behaviour(scenario: Scenario) -> DeviceBehaviour:
    """How the model assumes a zone picks its reading among the surfaces it sees."""
    s = scenario.sensor
    return DeviceBehaviour(target_order=s.target_order, merge_mm=s.merge_mm,
                           merged_depth=s.merged_depth)


def sensor_params(scenario: Scenario) -> SensorModelParams:
    """The sensor model the software assumes (`sensor:`): what the estimator predicts with."""
    s = scenario.sensor
    return SensorModelParams(
        geometry=zone_geometry(scenario),
        subsamples=s.subsamples,
        min_share=s.min_share,
        cluster_gap_mm=s.cluster_gap_mm,
        noise=NoiseModel(sigma0_mm=s.sigma0_mm, k=s.noise_k),
    )


def device_profile(scenario: Scenario) -> DeviceProfile:
    """The simulated device's profile with `device:`'s knobs where set."""
    d = scenario.device
    profile = PROFILES[d.profile]
    knobs = {f.name: getattr(d, f.name) for f in dc.fields(DeviceBehaviour)
             if getattr(d, f.name) is not None}
    return DeviceProfile(
        dc.replace(profile.behaviour or sensor_behaviour(scenario), **knobs),
        zone_directions=(d.zone_directions or profile.zone_directions
                         or scenario.sensor.zone_directions),
        integration_steps=d.integration_steps or profile.integration_steps)


def device_params(scenario: Scenario) -> SensorModelParams:
    """How the simulated device behaves: the model with `device:`'s fields where set, and
    the profile's zone directions. The board's own zone order is row-major, whatever order
    the model assumes (`sensor.flip_x` ...); `device.zone_order` moves it. Only the simulated
    sensor may use it (tests/test_device_section.py checks)."""
    model, d = sensor_params(scenario), scenario.device
    noise = NoiseModel(sigma0_mm=model.noise.sigma0_mm if d.sigma0_mm is None else d.sigma0_mm,
                       k=model.noise.k if d.noise_k is None else d.noise_k)
    geometry = dc.replace(model.geometry, flip_x=False, flip_y=False, transpose=False,
                          centres_deg=_zone_centres(
        device_profile(scenario).zone_directions, model.geometry.resolution,
        "device.zone_directions"))
    return dc.replace(model, noise=noise, geometry=geometry,
                      min_share=model.min_share if d.min_share is None else d.min_share,
                      cluster_gap_mm=(model.cluster_gap_mm if d.cluster_gap_mm is None
                                      else d.cluster_gap_mm))


def _zone_centres(directions: str, resolution: int, field: str) -> np.ndarray | None:
    """Zone centres (`ZoneGeometry.centres_deg`) for "uniform" (None), "st" or a CSV file
    of resolution^2 rows "x_deg, y_deg"; errors name `field`."""
    if directions == "uniform":
        return None
    if directions == "st":
        return st_zone_centres_deg(resolution)
    try:
        table = np.loadtxt(resolve_url(directions), delimiter=",", ndmin=2)
    except (OSError, ValueError) as e:
        raise ScenarioError(f"field '{field}': cannot read {directions!r} as 'uniform', "
                            f"'st' or a CSV of x_deg, y_deg rows: {e}") from e
    if table.shape != (resolution**2, 2):
        raise ScenarioError(f"field '{field}': {directions} has shape "
                            f"{table.shape}; expected {(resolution**2, 2)} (x_deg, y_deg "
                            f"per zone, row-major)")
    return table.reshape(-1)


def scene_reflectance(scenario: Scenario) -> Callable[[np.ndarray], np.ndarray]:
    """Reflectance at world points (n, 3): the table's within 3 mm of its top, the object's
    elsewhere (the cell has nothing else in the sensor's view)."""
    table, rho_table, rho_object = (scenario.cell.table_height, scenario.cell.table_reflectance,
                                    scenario.object.reflectance)

    def reflectance(p_W: np.ndarray) -> np.ndarray:
        return np.where(np.abs(p_W[:, 2] - table) < 0.003, rho_table, rho_object)
    return reflectance


def episode_estimator(scenario: Scenario) -> EpisodeEstimator:
    """The estimator `extraction.estimator` names, pose by pose: the shape fitted to the
    readings through the sensor model (`estimation:`), or the cell boxes themselves."""
    if scenario.extraction.estimator == "cells":
        return EpisodeEstimator(None)
    return EpisodeEstimator(ShapeEstimator(
        sensor_params(scenario), sensor_behaviour(scenario), scenario.cell.table_height,
        tuple(scenario.cell.table_extent), scenario.estimation))


def extraction_params(scenario: Scenario) -> ExtractionParams:
    """The object extraction's parameters."""
    e, m = scenario.extraction, scenario.mapping
    return ExtractionParams(
        table_height=scenario.cell.table_height, table_tolerance=e.table_tolerance,
        dbscan_eps=e.dbscan_eps, dbscan_min_samples=e.dbscan_min_samples,
        min_cluster_points=e.min_cluster_points,
        workspace=AlignedBox(np.asarray(m.lower, float), np.asarray(m.upper, float)),
        workspace_center=np.asarray(e.center, float),
        max_center_distance=e.max_center_distance, roi_margin=e.roi_margin,
        cell_size=m.resolution, enclose_cells=e.enclose_cells, seed=scenario.seed)


def map_system(scenario: Scenario, period: float | None) -> OccupancyMapSystem:
    """The occupancy map system, updated every `period` seconds (None: only when forced, or
    filled directly with `insert_recorded`)."""
    m = scenario.mapping
    return OccupancyMapSystem(
        bounds=(m.lower, m.upper), resolution=m.resolution, mode=m.insertion,
        geometry=zone_geometry(scenario), max_range=m.max_range if m.max_range > 0 else None,
        period=period, cone_k=m.cone_subrays, free_no_target=m.free_no_target)


def make_policy(planner: str, scenario: Scenario, motion: MotionPlanner,
                placed: PlacedObject | None) -> ViewpointPolicy:
    """The viewpoint policy called `planner` (`SIMULATION_PLANNERS`, or `COMMISSION`).

    Raises:
        ValueError: an unknown planner, or the oracle without a simulated object.
    """
    if planner == COMMISSION:
        return TableViews(table_view_poses(np.asarray(scenario.extraction.center, float),
                                           scenario.cell.table_height),
                          scenario.hardware.commission_frames)
    if planner == "heu":
        # The object's true centre is given to the HEU baseline only, as in the paper.
        return HeuPolicy(placed.mesh.bounds.mean(axis=0), scenario.heu)
    workspace = AlignedBox(*(np.asarray(v, float) for v in motion.workspace))
    if planner == ORACLE:
        if placed is None:
            raise ValueError("planner 'oracle' knows the true object: it runs only in the "
                             "simulated cell, with an object")
        return oracle_policy(placed.mesh, true_box(placed.mesh.vertices, placed.table_height),
                             placed.table_height, zone_geometry(scenario), workspace,
                             motion.ik_batch, motion.collision_free, motion.travel_time,
                             np.asarray(scenario.robot.initial_position, float))
    if planner in ("lrnbv", "nbv"):
        geometry, cell = zone_geometry(scenario), scenario.cell
        first = None if scenario.planner.first_view == "home" else drop_zone_view(
            cell.drop_zone, cell.table_height, geometry,
            cell.max_item_height + scenario.planner.tree.roi_clearance)
        return LrNbvPolicy(
            scenario.planner, geometry,
            workspace=workspace, ik=motion.ik_batch, collision_free=motion.collision_free,
            table_height=cell.table_height, seed=scenario.seed, variant=planner,
            travel_time=motion.travel_time, first_view=first,
            capture_seconds=seconds_at_a_view(scenario.sensor.period,
                                              scenario.sensor.settle_frames),
            first_free=motion.first_free)
    raise ValueError(f"unknown planner '{planner}': expected one of "
                     f"{', '.join(SIMULATION_PLANNERS)}")


def make_self_filter(scenario: Scenario, motion: MotionPlanner) -> SelfFilter | None:
    """The acquisition's self filter (`robot.self_filter_padding`; None at 0): a reading
    within the padding of the arm's collision geometry at the captured joints is the arm."""
    padding = scenario.robot.self_filter_padding
    if padding <= 0:
        return None
    geometry = zone_geometry(scenario)

    def self_filter(frame: ToFFrame, X_WS: np.ndarray, q: np.ndarray
                    ) -> tuple[ToFFrame, np.ndarray]:
        return drop_robot_zones(frame, geometry, X_WS,
                                lambda points: motion.near_robot(q, points, padding))
    return self_filter


def make_stop(planner: str, scenario: Scenario) -> BoxStop | None:
    """The stop rule `planner.stop.rule` names for LR-NBV and NBV (HEU's sweep and the
    commissioning views are fixed; the oracle stops on the truth):
    None for the paper's line 24 alone."""
    stop = scenario.planner.stop
    if stop.rule == "paper" or planner in ("heu", ORACLE, COMMISSION):
        return None
    return BoxStop(stop)


def container_catalogue(scenario: Scenario) -> list[Container]:
    """The containers `packing.containers` names (a package URL or a file).

    Raises:
        ScenarioError: the file is missing or not a catalogue, naming the field.
    """
    url = scenario.packing.containers
    path = Path(resolve_url(url))
    try:
        text = path.read_text()
    except OSError as e:
        raise ScenarioError(f"field 'packing.containers': cannot read {url} ({e.strerror})") \
            from e
    try:
        return load_catalogue(text, source=str(url))
    except CatalogueError as e:
        raise ScenarioError(f"field 'packing.containers': {e}") from e


def packing_decision(scenario: Scenario, estimate: BoxEstimate | None
                     ) -> PackingDecision | None:
    """The container `packing:` and its catalogue choose for `estimate`; None without one."""
    if estimate is None:
        return None
    return container_for(estimate, scenario.packing.fixed_margin, scenario.packing.clearance,
                         container_catalogue(scenario))


def check_scenario_files(scenario: Scenario, simulated_sensor: bool = True) -> None:
    """Reads every file the scenario names that an episode reads only at its end or while
    it is built (the container catalogue, the zone-direction tables; the simulated device's
    only with `simulated_sensor`: a real board never reads `device:`), so that a bad one is
    refused before anything runs or moves, not after the data is captured.

    Raises:
        ScenarioError: naming the field.
    """
    container_catalogue(scenario)
    zone_geometry(scenario)
    if simulated_sensor:
        device_params(scenario)


def safety_limits(scenario: Scenario, X_W_base: np.ndarray, X_tool0_S: np.ndarray
                  ) -> SafetyLimits:
    """The command checks for this scenario's cell, whose controller `base` frame is X_W_base
    (4x4) and whose sensor sits at X_tool0_S (4x4) on the flange.

    The tracking lag is the servo's (about its lookahead time, taken 1.5 times as it is not
    measured on a real arm) plus the age of what is compared: the reading (one status period
    and one RTDE package, 8 ms at CB3's 125 Hz) and the command (one servo period)."""
    hw, cell = scenario.hardware, scenario.cell
    margin = hw.workspace_margin
    return SafetyLimits(
        joint_lower=np.asarray(hw.joint_lower, float),
        joint_upper=np.asarray(hw.joint_upper, float),
        max_velocity=kinematics.VELOCITY_LIMIT * hw.max_speed_fraction,
        max_acceleration=kinematics.ACCELERATION_LIMIT * hw.max_acceleration_fraction,
        jump_tolerance=hw.command_jump_tolerance,
        tracking_lag=1.5 * hw.servo_lookahead_time + hw.status_period + hw.servo_period + 0.008,
        max_tracking_error=hw.max_tracking_error,
        X_W_base=np.asarray(X_W_base, float),
        X_tool0_S=np.asarray(X_tool0_S, float),
        workspace_lower=np.asarray(cell.workspace_lower, float) - margin,
        workspace_upper=np.asarray(cell.workspace_upper, float) + margin,
        min_sensor_z=cell.table_height + hw.min_table_clearance,
    )
