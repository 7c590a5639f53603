"""ToFVisualizer alone, and its ray geometry."""

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.math import RigidTransform, RollPitchYaw

from lrnbv_drake.core.sensing.sensor import STATUS_NO_TARGET, ToFFrame, ZoneGeometry
from lrnbv_drake.systems.tof_visualizer import ToFVisualizer, zone_rays


def _frame(sequence=1):
    status = np.full((8, 8), 5)
    status[0, :] = STATUS_NO_TARGET
    return ToFFrame(np.full((8, 8), 500), status, np.full((8, 8), 7), sequence=sequence)


def test_rays_end_at_the_zone_points_in_world():
    X_WS = RigidTransform(RollPitchYaw(0.3, -0.2, 1.0), [0.1, 0.2, 0.5]).GetAsMatrix4()
    geometry = ZoneGeometry()
    starts, ends, valid = zone_rays(_frame(), geometry, X_WS, stub_length=0.1)
    assert valid.sum() == 56 and not valid[:8].any()
    np.testing.assert_allclose(starts.T, np.tile(X_WS[:3, 3], (64, 1)))
    # A valid ray ends at z = 0.5 m along the optical axis in the sensor frame.
    ends_S = (ends.T - X_WS[:3, 3]) @ X_WS[:3, :3]
    np.testing.assert_allclose(ends_S[valid, 2], 0.5)
    col = np.arange(64)[valid] % 8
    np.testing.assert_allclose(ends_S[valid, 0], 0.5 * np.tan(np.deg2rad(5.625 * (col - 3.5))))
    # A no-target ray is a 10 cm stub.
    np.testing.assert_allclose(np.linalg.norm(ends_S[~valid], axis=1), 0.1)


@pytest.fixture(scope="module")
def meshcat():
    return Meshcat(MeshcatParams(host="localhost"))


def test_draws_each_new_frame_once(meshcat):
    dut = ToFVisualizer(meshcat, ZoneGeometry(), publish_period=0.1, prefix="test_tof")
    context = dut.CreateDefaultContext()
    dut.GetInputPort("acquired_pose").FixValue(context, RigidTransform([0, 0, 0.5]))
    dut.GetInputPort("acquired_frame").FixValue(context, ToFFrame.empty())
    dut.ForcedPublish(context)
    assert not meshcat.HasPath("/drake/test_tof/rays/000")  # sequence 0 is "nothing yet"
    dut.GetInputPort("acquired_frame").FixValue(context, _frame(sequence=4))
    dut.ForcedPublish(context)
    dut.ForcedPublish(context)
    assert meshcat.HasPath("/drake/test_tof/rays/000/valid")
    assert meshcat.HasPath("/drake/test_tof/rays/000/no_target")
    assert meshcat.HasPath("/drake/test_tof/points/000")
    assert not meshcat.HasPath("/drake/test_tof/rays/001")
    dut.GetInputPort("acquired_frame").FixValue(context, _frame(sequence=5))
    dut.ForcedPublish(context)
    assert meshcat.HasPath("/drake/test_tof/rays/001")
