"""Motion: trapezoidal trajectories, and typed planning failures in the shipped cell."""

import numpy as np
import pytest

from lrnbv_drake.core import kinematics
from lrnbv_drake.core.motion import MotionFailure
from lrnbv_drake.core.poses import look_at
from lrnbv_drake.station.motion import MotionPlanner, trapezoidal_trajectory
from lrnbv_drake.station.scenario import Scenario


def _sample(traj, n=2001):
    t = np.linspace(traj.start_time(), traj.end_time(), n)
    q = np.array([traj.value(ti).ravel() for ti in t])
    v = np.array([traj.EvalDerivative(ti, 1).ravel() for ti in t])
    a = np.array([traj.EvalDerivative(ti, 2).ravel() for ti in t])
    return t, q, v, a


@pytest.mark.parametrize(("dq", "duration"), [(1.0, 2.0), (3.0, 4.0), (0.25, 1.0)])
def test_trapezoid_durations_worked_by_hand(dq, duration):
    # vmax = amax = 1: a 1 rad move is a triangle of 2 s; 3 rad ramps 1 s, cruises 2 s, ramps 1 s;
    # 0.25 rad is a triangle with t_acc = sqrt(0.25) = 0.5 s.
    traj = trapezoidal_trajectory(np.array([[0.0], [dq]]), np.array([1.0]), np.array([1.0]))
    assert traj.end_time() == pytest.approx(duration)
    assert traj.value(traj.end_time())[0, 0] == pytest.approx(dq)


def test_trapezoid_respects_limits_and_synchronises():
    rng = np.random.default_rng(0)
    waypoints = rng.uniform(-2, 2, size=(3, 6))
    vmax = np.array([1.0, 1.0, 1.5, 2.0, 2.0, 3.0])
    amax = np.array([0.5, 0.5, 1.0, 1.0, 2.0, 2.0])
    traj = trapezoidal_trajectory(waypoints, vmax, amax, start_time=5.0)
    t, q, v, a = _sample(traj)
    assert traj.start_time() == 5.0
    assert np.all(np.abs(v) <= vmax * (1 + 1e-9))
    assert np.all(np.abs(a) <= amax * (1 + 1e-6))
    np.testing.assert_allclose(q[0], waypoints[0], atol=1e-12)
    np.testing.assert_allclose(q[-1], waypoints[-1], atol=1e-12)
    np.testing.assert_allclose(v[[0, -1]], 0.0, atol=1e-12)
    # On the first segment every joint is on the straight line from the first to the second
    # waypoint (synchronised), and at least one joint hits its velocity or acceleration limit.
    first = t <= t[np.argmin(np.linalg.norm(q - waypoints[1], axis=1))]
    d = waypoints[1] - waypoints[0]
    s = (q[first] - waypoints[0]) @ d / (d @ d)
    np.testing.assert_allclose(q[first], waypoints[0] + s[:, None] * d, atol=1e-9)
    assert np.max(np.abs(v) / vmax) > 0.999 or np.max(np.abs(a) / amax) > 0.999


@pytest.fixture(scope="module")
def planner():
    return MotionPlanner(Scenario())


def test_plan_reaches_the_pose_without_collision(planner):
    target = look_at([0.35, 0.10, 0.40], [0.5, 0.0, 0.05])
    plan = planner.plan(kinematics.HOME.copy(), target)
    assert plan.ok, plan.reason
    np.testing.assert_allclose(planner.sensor_pose(plan.q_target), target, atol=1e-9)
    traj = plan.trajectory
    np.testing.assert_allclose(traj.value(traj.end_time()).ravel(), plan.q_target, atol=1e-12)
    for t in np.linspace(traj.start_time(), traj.end_time(), 50):
        assert planner.collision_free(traj.value(t).ravel())


@pytest.mark.parametrize(("position", "failure"), [
    ([0.5, 0.0, 1.5], MotionFailure.OUTSIDE_WORKSPACE),
    ([0.95, 0.55, 0.95], MotionFailure.UNREACHABLE),
    ([0.5, 0.0, 0.07], MotionFailure.TARGET_IN_COLLISION),  # inside the horizontal box
])
def test_failures_are_typed_and_explained(planner, position, failure):
    target = look_at(position, np.add(position, [0.0, 0.0, -1.0]))
    plan = planner.plan(kinematics.HOME.copy(), target)
    assert plan.failure is failure
    assert plan.trajectory is None
    assert plan.reason


def test_sensor_pose_matches_drake_kinematics(planner):
    from lrnbv_drake.station.cell import make_cell

    dut = make_cell(Scenario()).diagram
    context = dut.CreateDefaultContext()
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = rng.uniform(-np.pi, np.pi, 6)
        dut.GetInputPort("ur5e.position").FixValue(context, q)
        X_drake = dut.GetOutputPort("tof.pose").Eval(context).GetAsMatrix4()
        np.testing.assert_allclose(planner.sensor_pose(q), X_drake, atol=1e-9)
        np.testing.assert_allclose(dut.GetOutputPort("ur5e.position_measured").Eval(context), q)
