"""The self filter (core/robot/self_filter.py) on hand-built frames, and the robot's geometry it
asks (`MotionPlanner.near_robot`) against the analytic kinematics."""

import numpy as np

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.robot.self_filter import STATUS_ROBOT, drop_robot_zones, robot_zones
from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.scenario import Scenario


def _frame(distance_mm):
    return ToFFrame(distance_mm, np.full((8, 8), 5), np.full((8, 8), 3), sequence=4)


def test_zones_whose_points_the_robot_holds_are_marked_and_the_rest_kept():
    """Straight down from 1 m: zones reading 400 mm end 0.6 m up (the 'arm'), zones reading
    1000 mm on the table. Only the former are marked, in the board's raw order (flips)."""
    distance = np.full((8, 8), 1000)
    distance[0, 1] = distance[2, 5] = 400  # no symmetry maps this pair onto itself
    distance[3, 3] = 0  # invalid: never asked about, never marked
    X_WS = look_at(np.array([0.0, 0.0, 1.0]), np.zeros(3))
    for geometry in (ZoneGeometry(), ZoneGeometry(flip_x=True, transpose=True)):
        asked = []
        dut, hit = drop_robot_zones(_frame(distance), geometry, X_WS,
                                    lambda points, asked=asked: asked.append(len(points))
                                    or points[:, 2] > 0.5)
        expected = distance == 400
        assert asked == [63]
        np.testing.assert_array_equal(hit, expected)
        np.testing.assert_array_equal(dut.status == STATUS_ROBOT, expected)
        np.testing.assert_array_equal(dut.distance_mm, distance)  # the reading is kept
        assert not dut.valid[expected].any() and dut.valid.sum() == 61


def test_a_frame_with_no_robot_in_it_is_returned_as_it_is():
    frame = _frame(np.full((8, 8), 500))
    X_WS = look_at(np.array([0.0, 0.0, 1.0]), np.zeros(3))
    dut, hit = drop_robot_zones(frame, ZoneGeometry(), X_WS, lambda p: np.zeros(len(p), bool))
    assert dut is frame and not hit.any()
    assert not robot_zones(ToFFrame.empty(), ZoneGeometry(), X_WS, lambda p: 1 / 0).any()


def _dh(theta: float, i: int) -> np.ndarray:
    """Joint i's standard DH transform Rz(theta) Tz(d) Tx(a) Rx(alpha), from UR's table."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(kinematics.DH_ALPHA[i]), np.sin(kinematics.DH_ALPHA[i])
    a, d = kinematics.DH_A[i], kinematics.DH_D[i]
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])


def test_points_on_the_arm_are_near_the_robot_and_points_on_the_table_are_not():
    """At a configuration with the upper arm level 16 cm above the table, reaching over the
    object's place: the upper arm's middle and the flange (placed by the analytic FK, the
    upper arm 0.138 m along joint 2's axis from the DH line, as UR's drawings and the URDF's
    collision origin put it) are on the robot; 5 cm above the table under the arm, a point
    30 cm beside it, the object's centre and a reading 2 cm in front of the sensor are not."""
    motion = MotionPlanner(Scenario())
    q = np.array([-0.34, 0.01, -0.64, -0.01, -1.49, -3.08])
    X_W_base = motion.X_W_base
    X_W1 = X_W_base @ _dh(q[0], 0)
    X_W2 = X_W1 @ _dh(q[1], 1)
    upper_arm = (X_W1[:3, 3] + X_W2[:3, 3]) / 2 + 0.138 * X_W1[:3, 2]
    flange = (X_W_base @ kinematics.forward_kinematics(q))[:3, 3]
    below = upper_arm * [1, 1, 0] + [0, 0, 0.05]
    beside = upper_arm + np.array([0, 0.3, 0.0])
    # 2 cm in front of the sensor: the closest valid reading, on the sensor's mount's face,
    # which is not the arm.
    in_front = (motion.sensor_pose(q) @ [0.0, 0.0, 0.02, 1.0])[:3]
    points = np.array([upper_arm, flange, below, beside, [0.5, 0.0, 0.03], in_front])
    np.testing.assert_array_equal(motion.near_robot(q, points, 0.03),
                                  [True, True, False, False, False, False])
