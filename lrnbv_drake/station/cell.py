"""The packing cell as a Drake diagram: UR5e, table, sensor mount, the object and the ToF sensor.

`make_cell(scenario, meshcat, hardware)` is the one builder. Its exported ports are the same in
simulation and on hardware, so whatever drives the cell does not know which one it has:

- input  `ur5e.position`           commanded joint positions (6,), radians;
- output `ur5e.position_measured`  measured joint positions (6,);
- output `tof.frame`               the latest `ToFFrame`;
- output `tof.pose`                the sensor pose in world (`RigidTransform`), from the measured
                                   joints;
- output `query_object`            SceneGraph's query object (simulation only).

The simulation is kinematic: the plant is not integrated. Commanded positions move the arm
exactly (`MultibodyPositionToGeometryPose` feeds SceneGraph), which is what a position-controlled
UR5e following a slow, limited trajectory does to within a millimetre, and it costs nothing.
"""

from __future__ import annotations

import dataclasses as dc
import tempfile
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    GeometryInstance,
    MakePhongIllustrationProperties,
    Mesh,
    Meshcat,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Role,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import LoadModelDirectives, ProcessModelDirectives
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import PassThrough
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from lrnbv_drake.core import objects
from lrnbv_drake.core.sensor import NoiseModel, SensorModelParams, ZoneGeometry
from lrnbv_drake.station.resources import make_parser
from lrnbv_drake.station.scenario import Scenario, ScenarioError, load_scenario
from lrnbv_drake.systems.sensor_pose import SensorPose
from lrnbv_drake.systems.tof_sensor import ToFSensor, add_tof_renderer

__all__ = ["CellModels", "Scenario", "add_cell_models", "add_cell_plant", "fixed_pose",
           "load_scenario", "make_cell", "place_object", "sensor_params", "zone_geometry"]

OBJECT_RGBA = np.array([0.85, 0.55, 0.2, 1.0])


@dc.dataclass
class CellModels:
    """What `add_cell_models` put into a plant."""

    ur5e: ModelInstanceIndex
    placed_object: objects.PlacedObject
    # Keeps the object's exported OBJ alive as long as the plant uses it.
    _mesh_dir: tempfile.TemporaryDirectory = dc.field(repr=False)


def add_cell_models(plant: MultibodyPlant, scenario: Scenario) -> CellModels:
    """Adds the robot, table and sensor mount (from the directives) and the object to `plant`.

    The object is anchored to the world at its resting pose: it does not move during an episode.
    """
    parser = make_parser(plant)
    directives_url = scenario.cell.directives
    directives_path = parser.package_map().ResolveUrl(directives_url) \
        if directives_url.startswith("package://") else directives_url
    if not Path(directives_path).is_file():
        raise ScenarioError(f"field 'cell.directives': no such file '{directives_url}'")
    ProcessModelDirectives(LoadModelDirectives(directives_path), plant, parser)
    ur5e = plant.GetModelInstanceByName("ur5e")

    placed = place_object(scenario)
    mesh_dir = tempfile.TemporaryDirectory(prefix="lrnbv_object_")
    obj_path = Path(mesh_dir.name) / "object.obj"
    objects.export_obj(placed.mesh, obj_path)
    shape = Mesh(str(obj_path), 1.0)
    world = plant.world_body()
    plant.RegisterVisualGeometry(world, RigidTransform(), shape, "object", OBJECT_RGBA)
    plant.RegisterCollisionGeometry(world, RigidTransform(), shape, "object",
                                    CoulombFriction(0.5, 0.5))
    return CellModels(ur5e=ur5e, placed_object=placed, _mesh_dir=mesh_dir)


def place_object(scenario: Scenario) -> objects.PlacedObject:
    """The scenario's object, loaded and resting on the table at its placement."""
    cfg = scenario.object
    mesh = objects.load_object_mesh(cfg.name, cfg.scale)
    placement = objects.ObjectPlacement(x=cfg.x, y=cfg.y, yaw=np.deg2rad(cfg.yaw_deg))
    return objects.place_on_table(mesh, placement, table_height=scenario.cell.table_height)


def sensor_params(scenario: Scenario) -> SensorModelParams:
    """The simulated sensor's model from the scenario."""
    s = scenario.sensor
    return SensorModelParams(
        geometry=zone_geometry(scenario),
        subsamples=s.subsamples,
        min_share=s.min_share,
        cluster_gap_mm=s.cluster_gap_mm,
        noise=NoiseModel(sigma0_mm=s.sigma0_mm, k=s.noise_k),
    )


def zone_geometry(scenario: Scenario) -> ZoneGeometry:
    """The sensor's zone geometry from the scenario."""
    s = scenario.sensor
    return ZoneGeometry(resolution=s.resolution, fov_deg=s.fov_deg, flip_x=s.flip_x,
                        flip_y=s.flip_y, transpose=s.transpose)


def add_cell_plant(builder: DiagramBuilder, scenario: Scenario
                   ) -> tuple[MultibodyPlant, SceneGraph, CellModels]:
    """Adds a SceneGraph to `builder` and makes the cell's finalized plant, registered with it
    but not added to the builder: nothing integrates it, positions are fed to SceneGraph."""
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    plant = MultibodyPlant(time_step=0.0)
    plant.set_name("plant")
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    models = add_cell_models(plant, scenario)
    plant.Finalize()
    if plant.num_positions() != 6:
        raise ScenarioError(
            f"field 'cell.directives': expected the UR5e's 6 joints to be the only positions, "
            f"got {plant.num_positions()}")
    return plant, scene_graph, models


def make_cell(scenario: Scenario, meshcat: Meshcat | None = None,
              hardware: bool = False) -> Diagram:
    """Builds the cell diagram (see the module docstring for its ports).

    Args:
        scenario: the cell, object and sensor.
        meshcat: when given, the scene is drawn there.
        hardware: build the real cell (UR5e over RTDE, sensor over serial) instead.
    """
    if hardware:
        # Imported here: the hardware station builds on this module.
        from lrnbv_drake.station.hardware_cell import make_hardware_cell
        return make_hardware_cell(scenario, meshcat)

    builder = DiagramBuilder()
    plant, scene_graph, models = add_cell_plant(builder, scenario)

    command = builder.AddNamedSystem("ur5e_position", PassThrough(6))
    to_pose = builder.AddNamedSystem("to_geometry_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(command.get_output_port(), to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(),
                    scene_graph.get_source_pose_port(plant.get_source_id()))

    tof_frame = plant.GetFrameByName("tof")
    add_tof_renderer(scene_graph)
    sensor = builder.AddNamedSystem("tof", ToFSensor(
        parent_frame_id=plant.GetBodyFrameIdOrThrow(tof_frame.body().index()),
        X_PS=tof_frame.GetFixedPoseInBodyFrame(),
        params=sensor_params(scenario),
        seed=scenario.seed,
        period=scenario.sensor.period,
    ))
    builder.Connect(scene_graph.get_query_output_port(), sensor.get_input_port())
    pose = builder.AddNamedSystem("tof_pose", SensorPose(plant, tof_frame))
    builder.Connect(command.get_output_port(), pose.get_input_port())

    builder.ExportInput(command.get_input_port(), "ur5e.position")
    builder.ExportOutput(command.get_output_port(), "ur5e.position_measured")
    builder.ExportOutput(sensor.get_output_port(), "tof.frame")
    builder.ExportOutput(pose.get_output_port(), "tof.pose")
    builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")

    visualizer = None
    if meshcat is not None:
        _add_frustum(plant, scene_graph, tof_frame, scenario, models)
        visualizer = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, meshcat,
            MeshcatVisualizerParams(publish_period=scenario.visualization.publish_period,
                                    role=Role.kIllustration, prefix="cell"))

    diagram = builder.Build()
    diagram.set_name("cell")
    # The plant is not part of the diagram (nothing integrates it); the diagram's users still
    # need it for kinematics, so it travels with the diagram.
    diagram.plant = plant
    diagram.models = models
    diagram.visualizer = visualizer
    return diagram


def _add_frustum(plant: MultibodyPlant, scene_graph: SceneGraph, tof_frame, scenario: Scenario,
                 models: CellModels, length: float = 0.25) -> None:
    """A translucent pyramid showing the sensor's field of view, for illustration only (with
    the perception role it would block the simulated sensor)."""
    half = length * np.tan(np.deg2rad(scenario.sensor.fov_deg) / 2)
    corners = [(-half, -half), (half, -half), (half, half), (-half, half)]
    lines = ["v 0 0 0", *(f"v {x} {y} {length}" for x, y in corners),
             "f 1 3 2", "f 1 4 3", "f 1 5 4", "f 1 2 5", "f 2 3 4", "f 2 4 5"]
    path = Path(models._mesh_dir.name) / "frustum.obj"
    path.write_text("\n".join(lines) + "\n")
    instance = GeometryInstance(tof_frame.GetFixedPoseInBodyFrame(), Mesh(str(path)), "frustum")
    instance.set_illustration_properties(
        MakePhongIllustrationProperties(np.array([0.2, 0.9, 0.3, 0.25])))
    scene_graph.RegisterGeometry(plant.get_source_id(),
                                 plant.GetBodyFrameIdOrThrow(tof_frame.body().index()), instance)


def fixed_pose(plant: MultibodyPlant, frame_a: str, frame_b: str) -> RigidTransform:
    """X_AB between two frames whose relative pose does not depend on the joints."""
    context = plant.CreateDefaultContext()
    return plant.CalcRelativeTransform(context, plant.GetFrameByName(frame_a),
                                       plant.GetFrameByName(frame_b))
