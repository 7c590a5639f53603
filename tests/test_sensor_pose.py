"""SensorPose alone, against Drake's own kinematics of the cell's plant and the mount offset
worked by hand."""

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.station.cell_models import add_cell_plant, fixed_pose
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.systems.sensor_pose import SensorPose


def test_sensor_pose_is_drakes_pose_of_the_tof_frame():
    plant, _, _ = add_cell_plant(DiagramBuilder(), Scenario())
    # World = base_link on the table; UR's `base` is base_link turned by pi about z; the sensor
    # is 25 mm along tool0's z (models/cell/tof_mount.sdf).
    X_W_base = np.diag([-1.0, -1.0, 1.0, 1.0])
    X_tool0_S = np.eye(4)
    X_tool0_S[2, 3] = 0.025
    np.testing.assert_allclose(fixed_pose(plant, "world", "base").GetAsMatrix4(), X_W_base,
                               atol=1e-12)
    np.testing.assert_allclose(fixed_pose(plant, "tool0", "tof").GetAsMatrix4(), X_tool0_S,
                               atol=1e-12)
    dut = SensorPose(X_W_base, X_tool0_S)
    context = dut.CreateDefaultContext()
    plant_context = plant.CreateDefaultContext()
    tof = plant.GetFrameByName("tof")
    rng = np.random.default_rng(7)
    for _ in range(10):
        q = rng.uniform(-np.pi, np.pi, 6)
        dut.get_input_port().FixValue(context, q)
        plant.SetPositions(plant_context, q)
        np.testing.assert_allclose(dut.get_output_port().Eval(context).GetAsMatrix4(),
                                   tof.CalcPoseInWorld(plant_context).GetAsMatrix4(),
                                   atol=1e-12)
