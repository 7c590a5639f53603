"""Motion: trapezoidal trajectories, and typed planning failures in the shipped cell."""

import logging

import numpy as np
import pytest

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.motion import MotionFailure
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.station.motion import MotionPlanner, halted, trapezoidal_trajectory
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


def test_a_move_just_past_the_triangle_keeps_increasing_breaks():
    """vmax = amax = 1 and 1 rad is exactly the triangle (2 s); a move one ulp longer has a
    ~1e-16 s cruise, which vanished into a later start time and made two equal breaks."""
    for dq in (1.0, np.nextafter(1.0, 2.0), 1.0 + 1e-12):
        traj = trapezoidal_trajectory(np.array([[0.0], [dq]]), np.array([1.0]),
                                      np.array([1.0]), start_time=123.4)
        assert traj.end_time() - 123.4 == pytest.approx(2.0)
        assert traj.value(traj.end_time())[0, 0] == pytest.approx(dq)
        _, _, v, _ = _sample(traj)
        assert np.all(np.abs(v) <= 1.0 + 1e-9)


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


@pytest.mark.parametrize("when", [0.3, 0.5, 0.9])  # ramping up, cruising, braking
def test_a_halted_move_stops_on_its_segment_within_the_limits_no_later_than_its_end(when):
    """Halted part way, the arm brakes along the segment it was on (collinear with its two
    waypoints, short of the second), at the joints' limits: its duration is the limiting
    joint's speed over its acceleration, by hand, and it ends at rest."""
    rng = np.random.default_rng(3)
    waypoints = rng.uniform(-2, 2, size=(2, 6))
    vmax = np.array([1.0, 1.0, 1.5, 2.0, 2.0, 3.0])
    amax = np.array([0.5, 0.5, 1.0, 1.0, 2.0, 2.0])
    move = trapezoidal_trajectory(waypoints, vmax, amax, start_time=2.0)
    t = move.start_time() + when * (move.end_time() - move.start_time())
    dut = halted(move, t, amax)
    v0 = move.EvalDerivative(t, 1).ravel()
    assert dut.start_time() == t
    assert dut.end_time() - t == pytest.approx(np.max(np.abs(v0) / amax))
    assert dut.end_time() <= move.end_time() + 1e-12
    _, q, v, a = _sample(dut)
    np.testing.assert_allclose(q[0], move.value(t).ravel(), atol=1e-12)
    np.testing.assert_allclose(v[-1], 0.0, atol=1e-9)
    assert np.all(np.abs(a) <= amax * (1 + 1e-9))
    d = waypoints[1] - waypoints[0]
    s = (q - waypoints[0]) @ d / (d @ d)
    np.testing.assert_allclose(q, waypoints[0] + s[:, None] * d, atol=1e-9)
    assert np.all(np.diff(s) >= -1e-12) and s[-1] <= 1.0 + 1e-12


@pytest.mark.parametrize("offset", [-1.5, -0.05, 0.0, 0.05])
def test_a_detour_halted_about_its_waypoint_stays_on_the_segment_it_was_on(offset):
    """A path through a via point stops there (its first segment a 2 s triangle by hand):
    halted while it speeds up, the arm stops a quarter of the way, 0.25 rad; while it brakes
    for the via point, at the via point, no further; at it, it holds; after it, it is on the
    second segment."""
    waypoints = np.array([[0.0] * 6, [1.0, 0.5, 0, 0, 0, 0], [1.0, 0.5, 1.0, 0, 0, 0]])
    move = trapezoidal_trajectory(waypoints, np.ones(6), np.ones(6))
    t_via = next(t for t in move.get_segment_times()
                 if np.allclose(move.value(t).ravel(), waypoints[1], atol=1e-12))
    dut = halted(move, t_via + offset, np.ones(6))
    end = dut.value(dut.end_time()).ravel()
    if offset < 0:  # on the first segment, short of the via point
        np.testing.assert_allclose(end[2:], 0.0, atol=1e-12)
        assert end[0] == pytest.approx(0.25 if offset == -1.5 else 1.0)
        assert end[1] == pytest.approx(end[0] / 2)
    elif offset == 0:  # at the via point, at rest
        np.testing.assert_allclose(end, waypoints[1], atol=1e-12)
        assert dut.end_time() - dut.start_time() < 0.01
    else:  # on the second segment: only joint 2 moves
        np.testing.assert_allclose(end[:2], [1.0, 0.5], atol=1e-12)
        assert 0 < end[2] < 1.0


@pytest.fixture(scope="module")
def planner():
    return MotionPlanner(Scenario())


def test_plan_reaches_the_pose_without_collision(planner):
    target = look_at([0.35, 0.10, 0.40], [0.5, 0.0, 0.05])
    plan = planner.plan(kinematics.HOME.copy(), target)
    assert plan.ok, plan.reason
    # The view as planned, or half a turn about its axis (`robot.sensor_roll_step_deg`).
    reached = planner.sensor_pose(plan.q_target)
    np.testing.assert_allclose(reached[:3, 2:], target[:3, 2:], atol=1e-9)
    np.testing.assert_allclose(np.abs(reached[:3, :2]), np.abs(target[:3, :2]), atol=1e-9)
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


def _farthest_outside(planner, trajectory, n=400):
    """How far (m) the sensor gets outside the workspace along a trajectory (< 0: inside)."""
    t = np.linspace(trajectory.start_time(), trajectory.end_time(), n)
    q = np.array([trajectory.value(ti).ravel() for ti in t])
    p = planner.sensor_pose(q)[:, :3, 3]
    lower, upper = planner.workspace
    return max(np.max(lower - p), np.max(p - upper))


# Starts and targets from a random walk of plans in which the straight (or via-home) joint
# path left the workspace by 0.09 to 0.26 m: the hardware's safety box, 0.05 m wider, refused
# such a command mid-motion in a dry run.
@pytest.mark.parametrize(("q_start", "position"), [
    ([-1.585, -0.415, -1.186, -2.723, 1.127, 0.81], [0.143, -0.584, 0.547]),
    ([-3.711, -3.159, 1.64, -3.362, 2.262, -1.831], [0.028, 0.199, 0.376]),
    ([-1.587, -1.988, -1.278, -2.472, 1.093, -3.414], [0.467, 0.396, 0.619]),
])
def test_a_planned_path_keeps_the_sensor_in_the_workspace_or_is_refused(planner, q_start,
                                                                       position):
    target = look_at(position, [0.5, 0.0, 0.05])
    plan = planner.plan(np.array(q_start), target)
    if plan.ok:
        assert _farthest_outside(planner, plan.trajectory) <= 0.0
    else:
        assert plan.failure is MotionFailure.PATH_OUTSIDE_WORKSPACE
        assert "outside the workspace" in plan.reason


def test_path_in_workspace_sees_a_swing_between_two_inside_poses(planner):
    # The base joint turned the long way round, from -1.2 to 2 pi - 0.5 rad: both ends in
    # front of the robot (x > 0), the middle (pi) behind it.
    a = kinematics.HOME.copy()
    a[0] = -1.2
    b = a.copy()
    b[0] = 2 * np.pi - 0.5
    ends = planner.sensor_pose(np.array([a, b]))[:, :3, 3]
    lower, upper = planner.workspace
    mid = planner.sensor_pose((a + b) / 2)[:3, 3]
    assert np.all((ends >= lower) & (ends <= upper)) and mid[0] < lower[0]  # the premise
    assert not planner.path_in_workspace(np.array([a, b]))
    assert planner.path_in_workspace(np.array([a, a]))


def test_building_a_planner_logs_nothing_below_warning_and_restores_the_level(caplog):
    drake_log = logging.getLogger("drake")
    drake_log.setLevel(logging.INFO)
    try:
        with caplog.at_level(logging.INFO, logger="drake"):
            MotionPlanner(Scenario())
        assert not [r for r in caplog.records if r.name == "drake" and r.levelno < logging.WARNING]
        assert drake_log.level == logging.INFO
    finally:
        drake_log.setLevel(logging.NOTSET)


def test_travel_time_is_the_direct_trajectorys_duration(planner):
    rng = np.random.default_rng(3)
    q = kinematics.HOME.copy()
    Q = q + rng.uniform(-2.0, 2.0, (6, 6))
    Q[0] = q  # no motion at all
    Q[1] = q + 0.01  # a short triangle
    expected = [0.0] + [trapezoidal_trajectory(np.array([q, qi]), planner.max_velocity,
                                               planner.max_acceleration).end_time()
                        for qi in Q[1:]]
    np.testing.assert_allclose(planner.travel_time(q, Q), expected, rtol=1e-12)


def test_between_two_low_views_across_the_box_the_path_goes_over_it_not_through_home(planner):
    """From a view low on the box's +y side to one low on its -y side (two poses of `make
    run`): the straight joint path sweeps the sensor through the box, so the plan detours;
    over the box it is collision-free, stays in the workspace, reaches the view and takes
    less than half the time the detour through home does."""
    q_start = np.array([0.3501, -0.9196, 1.2756, -1.0414, 3.9415, -3.6595])
    target = look_at([0.4539, -0.3017, 0.1332], [0.5, 0.0, 0.06])
    plan = planner.plan(q_start, target)
    assert plan.ok, plan.reason
    traj = plan.trajectory
    np.testing.assert_allclose(planner.sensor_pose(plan.q_target)[:3, 3],
                               [0.4539, -0.3017, 0.1332], atol=1e-9)
    assert all(planner.collision_free(traj.value(t).ravel())
               for t in np.linspace(traj.start_time(), traj.end_time(), 200))
    assert _farthest_outside(planner, traj) <= 0.0
    via_home = trapezoidal_trajectory(np.array([q_start, planner.home, plan.q_target]),
                                      planner.max_velocity, planner.max_acceleration)
    assert traj.end_time() - traj.start_time() < 0.5 * via_home.end_time()
    # The straight joint-space move would collide: the plan went round.
    assert not all(planner.collision_free(q_start + s * (plan.q_target - q_start))
                   for s in np.linspace(0.0, 1.0, 200))


def test_a_straight_path_to_another_branch_beats_a_detour_to_the_nearest(planner):
    """From a low view on the box's -y side to one on its +y side (a move of a paper
    campaign's episode): the straight path to the nearest collision-free IK branch sweeps the
    arm through the box, and a straight path to another branch is free. The plan takes the
    quickest path: no straight path to a free branch is quicker than it, and it is not the
    nearest branch's (that one's quickest way round is a detour)."""
    q_start = np.array([-0.8108, -0.5123, 0.7019, -0.4213, -1.1284, 0.1007])
    position = np.array([0.4898, 0.3756, 0.1632])
    target = look_at(position, np.add(position, [-0.0342, -0.9686, -0.2464]))
    plan = planner.plan(q_start, target)
    assert plan.ok, plan.reason
    duration = plan.trajectory.end_time() - plan.trajectory.start_time()
    free = [q for q in planner.ik(target, q_start) if planner.collision_free(q)]

    def straight_is_clear(q):
        path = q_start + np.linspace(0.0, 1.0, 200)[:, None] * (q - q_start)
        return all(planner.collision_free(p) for p in path) and planner.path_in_workspace(
            np.array([q_start, q]))

    assert not straight_is_clear(free[0])
    clear = [q for q in free[1:] if straight_is_clear(q)]
    assert clear
    assert duration <= min(planner.travel_time(q_start, np.array(clear))) + 1e-9
    assert not np.allclose(plan.q_target, free[0])
    assert all(planner.collision_free(plan.trajectory.value(t).ravel())
               for t in np.linspace(plan.trajectory.start_time(), plan.trajectory.end_time(),
                                    200))


@pytest.mark.parametrize(("step_deg", "turn", "largest_move"), [
    (0.0, 1.5, 1.5), (90.0, 1.5, 1.5 - np.pi / 2), (180.0, 1.5, 1.5),
    (90.0, 3.0, np.pi - 3.0), (180.0, 3.0, np.pi - 3.0)])
def test_a_view_turned_about_its_axis_is_reached_by_the_nearest_allowed_roll(step_deg, turn,
                                                                           largest_move):
    """The sensor sits on the wrist-3 axis, so a view that differs from the current one by
    a turn about the optical axis is wrist 3 alone: `turn` rad as planned, or the turn less the
    nearest multiple of the allowed roll (90 degrees takes 1.5 rad to 0.071 and 3.0 to 0.142;
    180 takes 3.0 to 0.142 and leaves 1.5; without rolls a 3.0 rad turn is nearer by the
    other wrist branch, 2.6 rad). The nearest solution sees from the same point along the
    same axis."""
    scenario = Scenario()
    scenario.robot.sensor_roll_step_deg = step_deg
    dut = MotionPlanner(scenario)
    q = kinematics.HOME.copy()
    target = dut.sensor_pose(q + np.array([0, 0, 0, 0, 0, turn]))
    nearest = dut.ik(target, q)[0]
    np.testing.assert_allclose(np.max(np.abs(nearest - q)), abs(largest_move), atol=1e-6)
    reached = dut.sensor_pose(nearest)
    np.testing.assert_allclose(reached[:3, 3], target[:3, 3], atol=1e-9)
    np.testing.assert_allclose(reached[:3, 2], target[:3, 2], atol=1e-9)
