"""SensorPose: the sensor's pose in world from the arm's joint positions."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame
from pydrake.systems.framework import LeafSystem


class SensorPose(LeafSystem):
    """Computes X_WS of `frame` from joint positions with the plant's kinematics.

    It uses the measured joints, so the same system serves the simulated and the real cell.

    Input port `position` (plant positions); output port `X_WS` (RigidTransform).
    """

    def __init__(self, plant: MultibodyPlant, frame: Frame):
        super().__init__()
        self._plant = plant
        self._frame = frame
        self._plant_context = plant.CreateDefaultContext()
        self.DeclareVectorInputPort("position", plant.num_positions())
        self.DeclareAbstractOutputPort("X_WS", lambda: AbstractValue.Make(RigidTransform()),
                                       self._CalcPose)

    def _CalcPose(self, context, output) -> None:
        q = self.get_input_port().Eval(context)
        self._plant.SetPositions(self._plant_context, q)
        output.set_value(self._frame.CalcPoseInWorld(self._plant_context))
