"""SensorPose alone, against the analytic kinematics and the mount offset worked by hand."""

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.core import kinematics
from lrnbv_drake.station.cell_models import add_cell_plant
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.systems.sensor_pose import SensorPose


def test_sensor_pose_is_base_fk_and_the_mount_offset():
    plant, _, _ = add_cell_plant(DiagramBuilder(), Scenario())
    dut = SensorPose(plant, plant.GetFrameByName("tof"))
    context = dut.CreateDefaultContext()
    # World = base_link on the table; UR's `base` is base_link turned by pi about z; the sensor
    # is 25 mm along tool0's z (models/cell/tof_mount.sdf).
    X_W_base = np.diag([-1.0, -1.0, 1.0, 1.0])
    X_tool0_S = np.eye(4)
    X_tool0_S[2, 3] = 0.025
    rng = np.random.default_rng(7)
    for _ in range(10):
        q = rng.uniform(-np.pi, np.pi, 6)
        dut.get_input_port().FixValue(context, q)
        X_WS = dut.get_output_port().Eval(context).GetAsMatrix4()
        expected = X_W_base @ kinematics.forward_kinematics(q) @ X_tool0_S
        np.testing.assert_allclose(X_WS, expected, atol=1e-12)
