"""The simulated device on a calibration bench: the scenario's `device:` fixed at the world
origin, looking along +z, in front of the three scenes a user records on the real cell to
calibrate the model (`experiments.sensor_recording.simulate_recordings` says which):

- a flat board filling the field of view at a perpendicular distance;
- a near board whose vertical edge stands at an angle in the field of view, over a far board;
- a small square target at a direction and distance, nothing else within range.

The scenes move, not the sensor, so the known geometry is exact in the sensor frame. Like the
simulated cell, the bench is kinematic: the boards are bodies whose poses are fed to SceneGraph,
and the sensor captures on its own period. A scene changes only between frames, so no frame
mixes two scenes, and each frame renders once: a frame that integrates n renders of a still
scene reduces the same samples n times over, which changes nothing but the cost.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.geometry import Box, SceneGraph
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.station.parts import device_params, device_profile
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.systems.tof_sensor import ToFSensor, add_tof_renderer

#: Side of the boards, metres: they fill the field of view out to beyond the device's range.
_BOARD_M = 8.0
_THICKNESS_M = 0.002
#: Where a body not in the scene waits: behind the sensor, never rendered.
_PARKED = RigidTransform([0.0, 0.0, -50.0])


class CalibrationBench:
    """The scenario's simulated device in front of the bench's movable boards.

    Args:
        scenario: its `device:` (with the `sensor:` fields the device takes from the model),
            its frame period and its seed make the frames.
        target_side_mm: side of the small square target.
        board_reflectance, target_reflectance: of the boards and of the target (0.54: the
            datasheet's grey; 0.88 its white).
    """

    def __init__(self, scenario: Scenario, target_side_mm: float = 7.0,
                 board_reflectance: float = 0.54, target_reflectance: float = 0.88) -> None:
        self._reflectance = {"board": board_reflectance, "target": target_reflectance}
        self._rho = board_reflectance  # of the scene in front of the sensor
        builder = DiagramBuilder()
        scene_graph = builder.AddSystem(SceneGraph())
        plant = MultibodyPlant(time_step=0.0)
        plant.RegisterAsSourceForSceneGraph(scene_graph)
        self._bodies = {}
        for name in ("board", "near", "far", "target"):
            side = target_side_mm / 1000.0 if name == "target" else _BOARD_M
            body = plant.AddRigidBody(name, SpatialInertia.SolidBoxWithMass(1, 1, 1, 1))
            # The body's origin is the middle of the box's front face (its -z face).
            plant.RegisterVisualGeometry(body, RigidTransform([0, 0, _THICKNESS_M / 2]),
                                         Box(side, side, _THICKNESS_M), name, [1, 1, 1, 1])
            self._bodies[name] = body
        plant.Finalize()
        to_pose = builder.AddSystem(MultibodyPositionToGeometryPose(plant))
        builder.Connect(to_pose.get_output_port(),
                        scene_graph.get_source_pose_port(plant.get_source_id()))
        add_tof_renderer(scene_graph)
        self._sensor = builder.AddSystem(ToFSensor(
            scene_graph.world_frame_id(), RigidTransform(), device_params(scenario),
            seed=scenario.seed, period=scenario.sensor.period,
            behaviour=device_profile(scenario).behaviour,
            reflectance=lambda p_W: np.full(len(p_W), self._rho)))
        builder.Connect(scene_graph.get_query_output_port(), self._sensor.get_input_port())
        positions = builder.ExportInput(to_pose.get_input_port(), "positions")
        diagram = builder.Build()
        self._plant, self._plant_context = plant, plant.CreateDefaultContext()
        self._period = scenario.sensor.period
        self._simulator = Simulator(diagram)
        self._context = self._simulator.get_mutable_context()
        self._positions = diagram.get_input_port(positions)
        self._sensor_context = self._sensor.GetMyContextFromRoot(self._context)
        self._place({})

    def _place(self, poses: dict[str, RigidTransform]) -> None:
        """Puts the bodies in `poses` (body origin in the sensor frame) and parks the rest."""
        for name, body in self._bodies.items():
            self._plant.SetFreeBodyPose(self._plant_context, body, poses.get(name, _PARKED))
        self._positions.FixValue(self._context, self._plant.GetPositions(self._plant_context))

    def _record(self, poses: dict[str, RigidTransform], material: str, frames: int
                ) -> list[ToFFrame]:
        """`frames` frames of the scene `poses`, all of whose surfaces are `material`
        ("board" or "target"). The scene changes just after a frame, before the next render."""
        self._place(poses)
        self._rho = self._reflectance[material]
        port = self._sensor.get_tof_frame_output_port()
        out = []
        for _ in range(frames):
            previous = port.Eval(self._sensor_context).sequence
            self._simulator.AdvanceTo(previous * self._period + 1e-9)
            out.append(port.Eval(self._sensor_context))
        return out

    def flat(self, board_mm: float, frames: int) -> list[ToFFrame]:
        """Frames of the board filling the field of view at `board_mm`."""
        return self._record({"board": RigidTransform([0, 0, board_mm / 1000.0])}, "board",
                            frames)

    def edge(self, edge_deg: float, near_mm: float, far_mm: float, frames: int
             ) -> list[ToFFrame]:
        """Frames of the near board covering the field of view at angles x >= `edge_deg`
        (its vertical edge at x = near tan(edge_deg)), in front of the far board."""
        near = near_mm / 1000.0
        x_edge = near * math.tan(math.radians(edge_deg))
        return self._record({"near": RigidTransform([x_edge + _BOARD_M / 2, 0, near]),
                             "far": RigidTransform([0, 0, far_mm / 1000.0])}, "board", frames)

    def target(self, direction_deg: tuple[float, float], distance_mm: float, frames: int
               ) -> list[ToFFrame]:
        """Frames of the target's centre at `direction_deg` (atan(x/z), atan(y/z)), degrees,
        its face at the perpendicular distance `distance_mm`."""
        z = distance_mm / 1000.0
        x, y = (z * math.tan(math.radians(a)) for a in direction_deg)
        return self._record({"target": RigidTransform([x, y, z])}, "target", frames)
