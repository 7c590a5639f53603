"""Scenario: everything that describes one cell and one episode, loaded from YAML.

The dataclasses follow Drake's `hardware_sim` and manipulation's `station.py`: a comment above
each field, defaults that run out of the box, and `yaml_load_typed` for loading. Before Drake
parses a file, `check_against_schema` walks it against the dataclasses so that a bad file fails
with the file, the field path and what was expected, instead of a bare conversion error.
"""

# No `from __future__ import annotations` here: Drake's YAML loader reads `Field.type`, which
# postponed annotations would turn into strings.
import dataclasses as dc
import typing
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.visualization import VisualizationConfig

from lrnbv_drake.core.estimation.params import EstimationParams
from lrnbv_drake.core.planning.config import HeuParams, PlannerParams
from lrnbv_drake.core.robot.kinematics import HOME
from lrnbv_drake.station.hardware_config import HardwareConfig
from lrnbv_drake.station.resources import package_url
from lrnbv_drake.station.scenario_checks import (
    ScenarioError,
    check_against_schema,
    check_ranges,
    parse_yaml,
)

__all__ = ["Scenario", "ScenarioError", "load_scenario", "override", "recorded_scenario"]


@dc.dataclass
class RobotConfig:
    """The UR5e and how fast planned motions may move it."""

    # Joint configuration at the start of an episode, radians.
    initial_position: list[float] = dc.field(default_factory=lambda: HOME.tolist())
    # Fraction of the joint velocity limits (pi rad/s) used by planned motions.
    speed_fraction: float = 0.5
    # Fraction of the joint acceleration limits (pi rad/s^2) used by planned motions.
    acceleration_fraction: float = 0.5
    # Joint-space step for checking a motion for collisions, radians.
    collision_check_step: float = 0.05
    # Clearance kept between the robot (with the sensor mount) and the table or object, metres.
    collision_padding: float = 0.01
    # A reading within this of the robot's own collision geometry at capture is the arm seen
    # by its sensor, not the scene: its zone is dropped (status 254, core/robot/self_filter.py),
    # metres; 0 keeps every reading.
    self_filter_padding: float = 0.03
    # The sensor may be rolled about its optical axis by a multiple of this, in degrees, when
    # that moves the arm less: its 8x8 zones are square, so a rolled view covers the same
    # zones in another order. 180 keeps even the emitter's 43 x 58 degree illumination where
    # it was; 90 does not; 0: every view exactly as planned (also 0 with a calibrated
    # zone-direction table that is not symmetric: the planner scores the view as planned).
    sensor_roll_step_deg: float = 180.0
    # Hardware only: the controller's IP address.
    robot_ip: str = ""


@dc.dataclass
class CellConfig:
    """The table, the robot's place on it and the workspace the sensor may move in."""

    # Drake model directives that add the robot, the table and the sensor mount.
    directives: str = package_url("cell/cell.dmd.yaml")
    # Height of the table top in the world frame, metres.
    table_height: float = 0.0
    # Reflectance of the table top at 940 nm; only a simulated device with
    # `device.reflectance` (the datasheet profile) reads it.
    table_reflectance: float = 0.3
    # The table top's footprint in the world, [x_min, y_min, x_max, y_max], metres (the
    # shipped table: 1.2 x 0.8 m centred at (0.30, 0)): the box fit's scene model sees the
    # table only there.
    table_extent: list[float] = dc.field(default_factory=lambda: [-0.30, -0.40, 0.90, 0.40])
    # Axis-aligned box (world frame, metres) the sensor origin must stay in.
    workspace_lower: list[float] = dc.field(default_factory=lambda: [0.0, -0.6, 0.05])
    workspace_upper: list[float] = dc.field(default_factory=lambda: [1.0, 0.6, 1.0])
    # Where items are put on the table (by the conveyor or the operator), [x_min, y_min,
    # x_max, y_max], metres: the product's first view frames it (`planner.first_view`). The
    # default is where the campaigns place objects' centres.
    drop_zone: list[float] = dc.field(default_factory=lambda: [0.42, -0.12, 0.58, 0.12])
    # The tallest item the cell takes, metres: the first view is taken above it plus
    # `planner.tree.roi_clearance`, as the item is not known yet.
    max_item_height: float = 0.35


@dc.dataclass
class ObjectConfig:
    """The unknown object: a built-in name or a mesh file, resting on the table."""

    # A built-in object (`lrnbv objects` lists them) or a path to an OBJ, STL or PLY file.
    name: str = "horizontal_box"
    # Uniform scale applied to the mesh (mesh units to metres).
    scale: float = 1.0
    # Position of the footprint centre on the table, metres, and yaw about z, degrees.
    x: float = 0.50
    y: float = 0.0
    yaw_deg: float = 0.0
    # Reflectance at 940 nm (0.54: the datasheet's grey); only a simulated device with
    # `device.reflectance` (the datasheet profile) reads it.
    reflectance: float = 0.54


@dc.dataclass
class MountOffset:
    """The sensor's pose against the CAD mount's `tof` frame (models/cell/tof_mount.sdf): a
    bracket bolted by hand is off by a degree or two and a few millimetres."""

    # Offset along the CAD tof's x, y, z (z: the optical axis), mm.
    xyz_mm: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])
    # Turn about the CAD tof's x, y, z (Drake's roll-pitch-yaw), degrees.
    rpy_deg: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])


@dc.dataclass
class SensorConfig:
    """The VL53L8CX: zone geometry, the simulated sensor's model and the serial link."""

    # Zones per side and the square field of view, degrees.
    resolution: int = 8
    fov_deg: float = 45.0
    # How the board's raw zone order maps to row-major (calibrate on a real board).
    flip_x: bool = False
    flip_y: bool = False
    transpose: bool = False
    # Sub-samples per zone side used to render each zone's footprint.
    subsamples: int = 8
    # Share of a zone a surface must cover to be reported.
    min_share: float = 0.25
    # Depth gap (mm) that separates two surfaces within one zone.
    cluster_gap_mm: float = 25.0
    # Noise: sigma = max(sigma0_mm, noise_k * distance).
    sigma0_mm: float = 5.0
    noise_k: float = 0.015
    # Zone centre directions: "uniform" (45 degrees / resolution apart) or a CSV file of
    # resolution^2 rows "x_deg, y_deg", row-major (`lrnbv sensor characterize` writes one).
    zone_directions: str = "uniform"
    # Which target a zone reports, "closest" or "strongest", and surfaces closer than
    # merge_mm in depth reported as one at a "signal"-weighted, "nearest" or "farthest" depth
    # (0: no merging; with "closest", the nearest surface holding min_share, with "strongest"
    # the surface of the most signal). The default is ST's (strongest, 600 mm), under which a
    # zone that sees an object's edge and the table reads their signal-weighted depth, as
    # real frames do (docs/sensor-model.md). The estimator predicts readings with these.
    target_order: str = "strongest"
    merge_mm: float = 600.0
    merged_depth: str = "signal"
    # Frame period, seconds (15 Hz in 8x8 mode).
    period: float = 0.0666666666666666
    # Frames discarded after the arm stops before one is used.
    settle_frames: int = 1
    # The sensor's pose against the CAD mount that the model assumes, as `lrnbv hardware
    # commission` measures it (docs/hardware.md).
    mount: MountOffset = dc.field(default_factory=MountOffset)
    # When and how the mount, zone order and table were commissioned; `lrnbv hardware`
    # refuses to move an arm whose sensor was never commissioned (empty).
    commissioned: str = ""
    # Hardware only: serial port and baud rate of the sensor board.
    serial_port: str = ""
    baud: int = 460800


@dc.dataclass
class DeviceZoneOrder:
    """The order the simulated board reports its zones in against the model's
    (core/sensing/zone_order.py): the model's grid flipped, then turned."""

    # Counter-clockwise turn of the grid as printed, degrees: 0, 90, 180 or 270.
    rotate: int = 0
    # Mirror before the turn: "none", "rows" (upside down) or "cols".
    flip: str = "none"


@dc.dataclass
class DeviceConfig:
    """Simulation only: how the simulated VL53L8CX behaves where it should differ from the model
    the software assumes (`sensor:`, what a calibration produces). An unset field takes the
    model's value. Perception and planning never read this section, so an estimator can be
    scored on a device that is not its own model."""

    # Share of a zone a surface must cover to be reported.
    min_share: float | None = None
    # Depth gap (mm) that separates two surfaces within one zone.
    cluster_gap_mm: float | None = None
    # Noise: sigma = max(sigma0_mm, noise_k * distance).
    sigma0_mm: float | None = None
    noise_k: float | None = None
    # The device as a whole: "ideal" (the model's rule above, Gaussian noise, status 5),
    # "nearest" (the nearest surface holding min_share, not merged: the rule the model
    # assumed before real frames showed merging) or "datasheet" (ST's documented behaviour,
    # docs/sensor-model.md section 8). The fields below override one knob of the profile.
    profile: str = "ideal"
    # Which target a zone reports: "closest" or "strongest" (ST's default).
    target_order: str | None = None
    # Surfaces closer than this in depth merge into one target with status 9, mm (ST: 600;
    # 0 keeps the model's rule).
    merge_mm: float | None = None
    # Where a merged target lies: "signal" (signal-weighted mean), "nearest" or "farthest".
    merged_depth: str | None = None
    # Share of each neighbouring zone's samples the sharpener lets into a zone.
    sharpener_bleed: float | None = None
    # Weight samples by the emitter's fall-off towards the edges of the field.
    illumination: bool | None = None
    # Noise law: "model" (sigma0_mm, noise_k) or "datasheet" (by reflectance and ambient).
    accuracy: str | None = None
    # Ambient light, klux (5 is the datasheet's bright case).
    ambient_klux: float | None = None
    # Log-normal spread of the reported sigma around the true one.
    reported_sigma_spread: float | None = None
    # Status 6 on the first frame, 10 where a zone has just acquired a target.
    startup_statuses: bool | None = None
    # Weigh each surface's signal by its reflectance (object.reflectance,
    # cell.table_reflectance); the model assumes every surface reflects alike.
    reflectance: bool | None = None
    # Rms of a fixed range offset per zone, the same in every frame (real frames: 3 mm), mm,
    # and the seed that draws them (one device unit).
    zone_offset_mm: float | None = None
    zone_offset_seed: int | None = None
    # Zone centre directions: "uniform", "st" (the shape of ST's table) or a CSV file of
    # resolution^2 rows "x_deg, y_deg", row-major.
    zone_directions: str | None = None
    # Renders a frame integrates over its period (a moving sensor blurs), >= 1.
    integration_steps: int | None = None
    # The simulated sensor's true pose against the CAD mount.
    mount: MountOffset = dc.field(default_factory=MountOffset)
    # The board's zone order against the model's.
    zone_order: DeviceZoneOrder = dc.field(default_factory=DeviceZoneOrder)
    # The table top (and the object resting on it) above `cell.table_height`, mm.
    table_offset_mm: float = 0.0


@dc.dataclass
class PackingConfig:
    """The packing decision after the episode (core/evaluation/packing.py)."""

    # The container catalogue: a package URL or a file (models/containers/ has the default).
    containers: str = package_url("containers/shipping_boxes.yaml")
    # Added to every dimension on top of the estimate's margin, metres (room to pack).
    clearance: float = 0.005
    # The estimate's margin when it has no interval (the cell box), metres per dimension.
    fixed_margin: float = 0.01


@dc.dataclass
class MappingConfig:
    """The occupancy map (OctoMap semantics, docs/mapping.md)."""

    # Cell size, metres (Table 1's Octomap resolution).
    resolution: float = 0.01
    # World box the map covers, metres.
    lower: list[float] = dc.field(default_factory=lambda: [-0.2, -0.6, -0.05])
    upper: list[float] = dc.field(default_factory=lambda: [1.0, 0.6, 0.9])
    # "ray": one ray per zone, like OctoMap's insertPointCloud of 64 points; "cone": each
    # zone's whole footprint frees space up to the surface and marks it.
    insertion: str = "ray"
    # Sub-rays per zone side in cone mode.
    cone_subrays: int = 5
    # Points farther than this only free space up to it (OctoMap's maxrange); <= 0: no limit.
    max_range: float = 2.0
    # Zones with no target free space along their ray up to max_range.
    free_no_target: bool = False


@dc.dataclass
class ExtractionConfig:
    """Finding the object among the occupied cells (extraction.ExtractionParams)."""

    # Cells below the table top plus this are the table, metres. Two cell layers: range noise
    # (sigma 5-7.5 mm at working range) lifts table points into the second layer, and those
    # cells, chained by DBSCAN, would grow the object along the table with every pose.
    table_tolerance: float = 0.025
    # DBSCAN radius (metres) and core-point neighbour count. One frame's zone points lie
    # d * tan(5.625 deg), 3-5 cm, apart at 0.3-0.5 m: the radius must bridge that.
    dbscan_eps: float = 0.05
    dbscan_min_samples: int = 3
    # Smaller clusters are noise.
    min_cluster_points: int = 10
    # The object is the largest cluster within this xy distance of `center`, metres.
    center: list[float] = dc.field(default_factory=lambda: [0.5, 0.0])
    max_center_distance: float = 0.35
    # The ROI is the object's box grown by this, metres.
    roi_margin: float = 0.05
    # Boxes enclose the occupied cells (True) or their centres (False). Edge zones already put
    # points up to half a zone beyond an edge; enclosing the cells adds a cell more.
    enclose_cells: bool = False
    # The reported box: "shape" (the product's default), the box of the shape fitted to the
    # raw zone readings through the sensor model (core/estimation/, the `estimation:`
    # section), or "cells", the box around the occupied cells of the cluster (the paper's).
    estimator: str = "shape"


def default_visualization() -> VisualizationConfig:
    """Drake's visualization settings for the cell: the illustration geometry only (the plant
    is not part of the diagram, so it has no contact results or inertia to show)."""
    return VisualizationConfig(publish_period=0.03125, publish_proximity=False,
                               publish_contacts=False, publish_inertia=False)


@dc.dataclass
class ToFViewConfig:
    """What Meshcat shows of the sensor's frames."""

    # Draw the 64 zone rays of each frame, coloured by status.
    show_rays: bool = True
    # Draw the measured points.
    show_points: bool = True


@dc.dataclass
class Scenario:
    """One cell and one episode."""

    # Seed of every random choice in the run (sensor noise, planner sampling).
    seed: int = 0
    robot: RobotConfig = dc.field(default_factory=RobotConfig)
    cell: CellConfig = dc.field(default_factory=CellConfig)
    object: ObjectConfig = dc.field(default_factory=ObjectConfig)
    sensor: SensorConfig = dc.field(default_factory=SensorConfig)
    device: DeviceConfig = dc.field(default_factory=DeviceConfig)
    packing: PackingConfig = dc.field(default_factory=PackingConfig)
    mapping: MappingConfig = dc.field(default_factory=MappingConfig)
    extraction: ExtractionConfig = dc.field(default_factory=ExtractionConfig)
    # The box estimator's settings (docs/box-estimation.md); `lrnbv refit` can vary them.
    estimation: EstimationParams = dc.field(default_factory=EstimationParams)
    planner: PlannerParams = dc.field(default_factory=PlannerParams)
    # The HEU baseline's ellipse of viewpoints (the paper's 13 views by default).
    heu: HeuParams = dc.field(default_factory=HeuParams)
    # Hard cap on acquisitions in one episode, whatever the planner.
    max_poses: int = 40
    # Drake's Meshcat settings (ApplyVisualizationConfig).
    visualization: VisualizationConfig = dc.field(default_factory=default_visualization)
    tof_view: ToFViewConfig = dc.field(default_factory=ToFViewConfig)
    # The real cell's drivers and safety checks (docs/hardware.md); unused in simulation.
    hardware: HardwareConfig = dc.field(default_factory=HardwareConfig)

    def __reduce__(self):
        # Drake's VisualizationConfig does not pickle; campaign workers receive scenarios as
        # their YAML, which round-trips every field exactly.
        return (_from_yaml, (yaml_dump_typed(self),))


def _from_yaml(text: str) -> "Scenario":
    return yaml_load_typed(schema=Scenario, data=text)


#: Named starting points for a scenario (`--preset NAME`): "paper" is the paper's
#: configuration where the product's defaults differ from it (docs/results.md measures both;
#: docs/decisions/0002 says why they differ):
#: the box around the occupied map cells, Algorithm 1's line 24 as the only stop, the
#: whole workspace's height searched before the object is found (not where a few cells stand)
#: and the first frame taken at the start pose, not over the drop zone.
PRESETS: dict[str, str] = {
    "paper": ("{extraction: {estimator: cells}, planner: {stop: {rule: paper}, "
              "travel_discount: 0.0, search_upper: [0.75, 0.3, 0.3], lead_points: 0, "
              "first_view: home}}"),
}


def preset(name: str | None) -> Scenario:
    """The scenario a preset names, or the defaults for None.

    Raises:
        ScenarioError: an unknown name, with the known ones.
    """
    if name is None:
        return Scenario()
    if name not in PRESETS:
        raise ScenarioError(f"unknown preset {name!r}: expected one of {sorted(PRESETS)}")
    return load_scenario(data=PRESETS[name])


#: Fields an earlier version wrote that this one no longer has, with what replaced them: a
#: recorded episode's scenario is read without them (`recorded_scenario`).
RETIRED: dict[tuple[str, ...], str] = {
    ("planner", "stop", "interval_cost"): "the stop rule reads the reported interval",
}
#: Values an earlier version wrote that this one reads as another.
RENAMED: dict[tuple[tuple[str, ...], str], str] = {
    (("extraction", "estimator"), "model"): "shape",
}


def recorded_scenario(text: str) -> "Scenario":
    """The scenario a report.json or session.json recorded, written by this version or an
    earlier one: `RETIRED` fields dropped, `RENAMED` values read as their successors.

    Raises:
        ScenarioError: naming the bad field.
    """
    data = parse_yaml(text, "recorded scenario") or {}
    for path in RETIRED:
        *parents, leaf = path
        node = data
        for key in parents:
            node = node.get(key, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict):
            node.pop(leaf, None)
    for (path, old), new in RENAMED.items():
        *parents, leaf = path
        node = data
        for key in parents:
            node = node.get(key, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict) and node.get(leaf) == old:
            node[leaf] = new
    return load_scenario(data=yaml.safe_dump(data))


def override(scenario: Scenario, overrides: dict[str, typing.Any]) -> Scenario:
    """`scenario` with the fields in `overrides` (nested mappings, as in a scenario file)
    replaced, checked like a file. Every command-line flag that sets a field goes through here.

    Raises:
        ScenarioError: naming the bad field.
    """
    return load_scenario(data=yaml.safe_dump(overrides), defaults=scenario)


def load_scenario(filename: str | Path | None = None, data: str | None = None,
                  defaults: "Scenario | None" = None) -> "Scenario":
    """Loads a Scenario from a YAML file and/or string; the string overrides the file.

    Raises:
        ScenarioError: naming the file and the bad field.
    """
    scenario = defaults if defaults is not None else Scenario()
    for source, text in (("file", filename), ("string", data)):
        if text is None:
            continue
        label = f"scenario {source} '{text}'" if source == "file" else "scenario string"
        try:
            raw_text = Path(text).read_text() if source == "file" else text
        except OSError as e:
            raise ScenarioError(f"{label}: cannot read it ({e.strerror})") from e
        parsed = parse_yaml(raw_text, label)
        if parsed is None:
            continue
        try:
            check_against_schema(parsed, Scenario)
            scenario = yaml_load_typed(schema=Scenario, data=raw_text, defaults=scenario)
            check_ranges(scenario, fields_only=True)  # so that the error names the source
        except ScenarioError as e:
            raise ScenarioError(f"{label}: {e}") from e
    check_ranges(scenario)
    return scenario
