"""The cell's models in a MultibodyPlant: the robot, table and sensor mount from the scenario's
directives, and the object resting on the table. Both the simulated and the real cell, and the
motion planner's collision model, are built from these."""

from __future__ import annotations

import dataclasses as dc
import logging
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    Convex,
    GeometryInstance,
    MakePhongIllustrationProperties,
    Mesh,
    Meshcat,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import (
    LoadModelDirectives,
    ModelDirectives,
    ProcessModelDirectives,
)
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import Frame, ModelInstanceIndex
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.lcm import ApplyLcmBusConfig
from pydrake.visualization import ApplyVisualizationConfig

from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.core.robot.poses import offset_transform
from lrnbv_drake.core.robot.safety import RobotInterface
from lrnbv_drake.drivers.tof_serial import ToFSerialReader
from lrnbv_drake.station.resources import make_parser, resolve_url
from lrnbv_drake.station.scenario import MountOffset, Scenario, ScenarioError

_log = logging.getLogger(__name__)

OBJECT_RGBA = np.array([0.85, 0.55, 0.2, 1.0])


@dc.dataclass
class CellModels:
    """What `add_cell_models` put into a plant."""

    ur5e: ModelInstanceIndex
    # The object as placed; None on a bare table (commissioning).
    placed_object: objects.PlacedObject | None
    # Keeps the exported meshes (the object, the frustum) alive as long as the plant uses them.
    mesh_dir: tempfile.TemporaryDirectory = dc.field(repr=False)


@dc.dataclass
class HardwareDrivers:
    """The robot and sensor drivers a hardware cell uses, and what it must close."""

    robot: RobotInterface
    sensor: ToFSerialReader
    _to_close: list[Callable[[], None]] = dc.field(default_factory=list, repr=False)

    def close(self) -> None:
        """Closes what the cell opened itself (the simulated board, the serial driver, the
        RTDE connections), newest first; drivers passed in stay open."""
        close_all(self._to_close)


def close_all(to_close: list[Callable[[], None]]) -> None:
    """Calls each, newest first, whatever an earlier one raised, so that a sensor driver that
    fails cannot leave the robot connected. A driver's RuntimeError or OSError is logged; any
    other error is raised once all are closed (the first of them)."""
    unexpected: Exception | None = None
    while to_close:
        close = to_close.pop()
        try:
            close()
        except (RuntimeError, OSError) as e:
            _log.warning("closing a hardware driver failed: %s", e)
        except Exception as e:  # a bug in a driver: raised after the others are closed
            unexpected = unexpected or e
    if unexpected is not None:
        raise unexpected


@dc.dataclass
class Cell:
    """A built cell, simulated or real, and what its users need besides its ports."""

    # The diagram with the ports the module `station.cell` lists.
    diagram: Diagram
    # The cell's plant: registered with `scene_graph` for geometry, not part of the diagram
    # (nothing integrates it); for kinematics.
    plant: MultibodyPlant
    scene_graph: SceneGraph
    models: CellModels
    # Where the cell is drawn, if anywhere.
    meshcat: Meshcat | None = None
    # The real cell's drivers (None in simulation); `close()` them when done.
    hardware: HardwareDrivers | None = None


def apply_visualization(builder: DiagramBuilder, scenario: Scenario, plant: MultibodyPlant,
                        scene_graph: SceneGraph, meshcat: Meshcat) -> None:
    """Drake's `ApplyVisualizationConfig` with the scenario's settings. The cell is offline:
    its LCM bus is a disabled one that the diagram owns (`ApplyLcmBusConfig`)."""
    buses = ApplyLcmBusConfig({scenario.visualization.lcm_bus: None}, builder)
    ApplyVisualizationConfig(scenario.visualization, builder, lcm_buses=buses, plant=plant,
                             scene_graph=scene_graph, meshcat=meshcat)


def add_cell_models(plant: MultibodyPlant, scenario: Scenario,
                    table_offset: float | None = None, bare_table: bool = False) -> CellModels:
    """Adds the robot, table and sensor mount (from the directives) and, unless `bare_table`,
    the object to `plant`.

    With `table_offset` None the object rests on `cell.table_height`: the cell as the model
    sees it (the motion planner's, the real cell's). A number (m) builds the simulated world
    instead: the table where the directives weld it, raised by `table_offset`
    (`device.table_offset_mm`), and the object resting on it, whatever height the model
    assumes (a commissioned `cell.table_height` must not move the simulated table).

    The object is anchored to the world at its resting pose: it does not move during an episode.
    Its perception (rendered) geometry is the exact mesh; its proximity geometry, which the
    motion planner and the self filter query, is the mesh's convex hull: Drake's distance
    queries on a general mesh refuse sharp edges, open surfaces and thin parts, a hull never.
    """
    parser = make_parser(plant)
    directives_url = scenario.cell.directives
    directives_path = resolve_url(directives_url)
    if not Path(directives_path).is_file():
        raise ScenarioError(f"field 'cell.directives': no such file '{directives_url}'")
    directives = LoadModelDirectives(directives_path)
    rests_on = scenario.cell.table_height
    if table_offset is not None:
        weld = _table_weld(directives, alone=bool(table_offset))
        rests_on = weld.X_PC.translation[2] + table_offset
        weld.X_PC.translation = weld.X_PC.translation + np.array([0.0, 0.0, table_offset])
    ProcessModelDirectives(directives, plant, parser)
    ur5e = plant.GetModelInstanceByName("ur5e")
    mesh_dir = tempfile.TemporaryDirectory(prefix="lrnbv_object_")
    if bare_table:
        return CellModels(ur5e=ur5e, placed_object=None, mesh_dir=mesh_dir)

    placed = place_object(scenario, rests_on)
    obj_path = Path(mesh_dir.name) / "object.obj"
    objects.export_obj(placed.mesh, obj_path)
    world = plant.world_body()
    plant.RegisterVisualGeometry(world, RigidTransform(), Mesh(str(obj_path)), "object",
                                 OBJECT_RGBA)
    plant.RegisterCollisionGeometry(world, RigidTransform(), Convex(str(obj_path)), "object",
                                    CoulombFriction(0.5, 0.5))
    return CellModels(ur5e=ur5e, placed_object=placed, mesh_dir=mesh_dir)


def _table_weld(directives: ModelDirectives, alone: bool):
    """The weld that places the model `table` in the world (its top frame at the table top);
    with `alone`, one that carries nothing else, so that it can move alone."""
    welds = [d.add_weld for d in directives.directives
             if d.add_weld is not None and d.add_weld.parent == "world"
             and d.add_weld.child.startswith("table::")]
    carried = [d.add_weld.child for d in directives.directives
               if d.add_weld is not None and d.add_weld.parent.startswith("table::")]
    if len(welds) != 1 or (alone and carried):
        raise ScenarioError(
            "field 'device.table_offset_mm': expected cell.directives to weld one model named "
            "'table' to the world and nothing to the table, so that it can move alone; got "
            f"{len(welds)} such welds and {carried or 'nothing'} welded to the table")
    return welds[0]


def place_object(scenario: Scenario, table_height: float | None = None
                 ) -> objects.PlacedObject:
    """The scenario's object, loaded and resting at its placement on a table top at
    `table_height` (m; by default `cell.table_height`)."""
    cfg = scenario.object
    mesh = objects.load_object_mesh(cfg.name, cfg.scale)
    placement = objects.ObjectPlacement(x=cfg.x, y=cfg.y, yaw=np.deg2rad(cfg.yaw_deg))
    return objects.place_on_table(mesh, placement, table_height=(
        scenario.cell.table_height if table_height is None else table_height))


def add_cell_plant(builder: DiagramBuilder, scenario: Scenario,
                   table_offset: float | None = None, bare_table: bool = False
                   ) -> tuple[MultibodyPlant, SceneGraph, CellModels]:
    """Adds a SceneGraph to `builder` and makes the cell's finalized plant, registered with it
    but not added to the builder: nothing integrates it, positions are fed to SceneGraph.
    `table_offset`, `bare_table`: as `add_cell_models`."""
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    plant = MultibodyPlant(time_step=0.0)
    plant.set_name("plant")
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    models = add_cell_models(plant, scenario, table_offset, bare_table)
    plant.Finalize()
    if plant.num_positions() != 6:
        raise ScenarioError(
            f"field 'cell.directives': expected the UR5e's 6 joints to be the only positions, "
            f"got {plant.num_positions()}")
    return plant, scene_graph, models


def add_frustum(plant: MultibodyPlant, scene_graph: SceneGraph, tof_frame: Frame,
                scenario: Scenario,
                 models: CellModels, length: float = 0.25) -> None:
    """A translucent pyramid showing the sensor's field of view, for illustration only (with
    the perception role it would block the simulated sensor)."""
    half = length * np.tan(np.deg2rad(scenario.sensor.fov_deg) / 2)
    corners = [(-half, -half), (half, -half), (half, half), (-half, half)]
    lines = ["v 0 0 0", *(f"v {x} {y} {length}" for x, y in corners),
             "f 1 3 2", "f 1 4 3", "f 1 5 4", "f 1 2 5", "f 2 3 4", "f 2 4 5"]
    path = Path(models.mesh_dir.name) / "frustum.obj"
    path.write_text("\n".join(lines) + "\n")
    instance = GeometryInstance(
        tof_frame.GetFixedPoseInBodyFrame() @ offset_pose(scenario.sensor.mount),
        Mesh(str(path)), "frustum")
    instance.set_illustration_properties(
        MakePhongIllustrationProperties(np.array([0.2, 0.9, 0.3, 0.25])))
    scene_graph.RegisterGeometry(plant.get_source_id(),
                                 plant.GetBodyFrameIdOrThrow(tof_frame.body().index()), instance)


def offset_pose(offset: MountOffset) -> RigidTransform:
    """A `MountOffset` as the pose of the sensor in the CAD mount's `tof` frame."""
    return RigidTransform(offset_transform(offset.xyz_mm, offset.rpy_deg))


def sensor_on_tool0(plant: MultibodyPlant, scenario: Scenario) -> RigidTransform:
    """X_tool0_S: the sensor's pose on the flange the model assumes, the CAD mount times the
    commissioned `sensor.mount`."""
    return fixed_pose(plant, "tool0", "tof") @ offset_pose(scenario.sensor.mount)


def fixed_pose(plant: MultibodyPlant, frame_a: str, frame_b: str) -> RigidTransform:
    """X_AB between two frames whose relative pose does not depend on the joints."""
    context = plant.CreateDefaultContext()
    return plant.CalcRelativeTransform(context, plant.GetFrameByName(frame_a),
                                       plant.GetFrameByName(frame_b))
