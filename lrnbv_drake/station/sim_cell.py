"""The simulated cell: the UR5e, table, mount and object in SceneGraph, and the simulated ToF
sensor rendering through its QueryObject.

The simulation is kinematic: the plant is not integrated. Commanded positions move the arm
exactly (`MultibodyPositionToGeometryPose` feeds SceneGraph), which is what a position-controlled
UR5e following a slow, limited trajectory does to within a millimetre, and it costs nothing.
"""

from __future__ import annotations

from pydrake.geometry import Meshcat
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import PassThrough
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from lrnbv_drake.station.cell_models import (
    Cell,
    add_cell_plant,
    add_frustum,
    apply_visualization,
    fixed_pose,
    offset_pose,
    sensor_on_tool0,
)
from lrnbv_drake.station.parts import device_params, device_profile, scene_reflectance
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.systems.sensor_pose import SensorPose
from lrnbv_drake.systems.tof_sensor import ToFSensor, add_tof_renderer


def make_sim_cell(scenario: Scenario, meshcat: Meshcat | None = None,
                  bare_table: bool = False) -> Cell:
    """Builds the simulated cell (`station.cell` lists its ports); with `bare_table`, without
    the object (commissioning)."""
    builder = DiagramBuilder()
    plant, scene_graph, models = add_cell_plant(
        builder, scenario, table_offset=scenario.device.table_offset_mm / 1000,
        bare_table=bare_table)
    command = builder.AddNamedSystem("ur5e_position", PassThrough(6))
    to_pose = builder.AddNamedSystem("to_geometry_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(command.get_output_port(), to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(),
                    scene_graph.get_source_pose_port(plant.get_source_id()))

    tof_frame = plant.GetFrameByName("tof")
    add_tof_renderer(scene_graph)
    device = device_profile(scenario)
    sensor = builder.AddNamedSystem("tof", ToFSensor(
        parent_frame_id=plant.GetBodyFrameIdOrThrow(tof_frame.body().index()),
        X_PS=tof_frame.GetFixedPoseInBodyFrame() @ offset_pose(scenario.device.mount),
        params=device_params(scenario),
        seed=scenario.seed,
        period=scenario.sensor.period,
        behaviour=device.behaviour,
        reflectance=scene_reflectance(scenario),
        integration_steps=device.integration_steps,
        zone_order=(scenario.device.zone_order.rotate, scenario.device.zone_order.flip),
    ))
    builder.Connect(scene_graph.get_query_output_port(), sensor.get_input_port())
    pose = builder.AddNamedSystem("tof_pose", SensorPose(
        fixed_pose(plant, "world", "base").GetAsMatrix4(),
        sensor_on_tool0(plant, scenario).GetAsMatrix4()))
    builder.Connect(command.get_output_port(), pose.get_input_port())

    builder.ExportInput(command.get_input_port(), "ur5e.position")
    builder.ExportOutput(command.get_output_port(), "ur5e.position_measured")
    builder.ExportOutput(sensor.get_output_port(), "tof.frame")
    builder.ExportOutput(pose.get_output_port(), "tof.pose")
    builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")

    if meshcat is not None:
        add_frustum(plant, scene_graph, tof_frame, scenario, models)
        apply_visualization(builder, scenario, plant, scene_graph, meshcat)
    diagram = builder.Build()
    diagram.set_name("cell")
    return Cell(diagram, plant, scene_graph, models, meshcat)
