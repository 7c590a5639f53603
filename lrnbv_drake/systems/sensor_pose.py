"""SensorPose: the sensor's pose in world from the arm's joint positions
(`core.robot.kinematics.sensor_pose`)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, LeafSystem

from lrnbv_drake.core.robot import kinematics


class SensorPose(LeafSystem):
    """X_WS from joint positions, by the UR5e's analytic forward kinematics.

    @system
    name: SensorPose
    input_ports:
    - position
    output_ports:
    - X_WS
    @endsystem

    `position` (6) is the measured joints, so the same system serves the simulated and the
    real cell; `X_WS` is a RigidTransform. X_W_base and X_tool0_S (4x4) place the controller's
    `base` in world and the sensor on the flange (`station.cell_models.fixed_pose`).
    """

    def __init__(self, X_W_base: np.ndarray, X_tool0_S: np.ndarray) -> None:
        super().__init__()
        self._X_W_base = np.asarray(X_W_base, float)
        self._X_tool0_S = np.asarray(X_tool0_S, float)
        self.DeclareVectorInputPort("position", 6)
        self.DeclareAbstractOutputPort("X_WS", lambda: AbstractValue.Make(RigidTransform()),
                                       self._CalcPose)

    def _CalcPose(self, context: Context, output: AbstractValue) -> None:
        q = self.get_input_port().Eval(context)
        output.set_value(RigidTransform(kinematics.sensor_pose(q, self._X_W_base,
                                                               self._X_tool0_S)))
