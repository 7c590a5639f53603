"""The status and command checks alone (core/robot/safety.py): what a controller reading
means and which fault it is, with what to do; and what a joint command must satisfy (the
controller's joint limits, the caps, the servo's lag, the workspace)."""

from __future__ import annotations

import dataclasses as dc

import numpy as np
import pytest
from fake_rtde import PERIOD, ok_status, open_limits
from hypothesis import given, settings
from hypothesis import strategies as st

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.safety import Ur5eStatus, read_status, tcp_pose_error
from lrnbv_drake.drivers.playback_robot import PlaybackRobot
from lrnbv_drake.station.motion import trapezoidal_trajectory

HOME = kinematics.HOME.copy()


# --- Status ---------------------------------------------------------------------------------


def test_read_status_reads_everything_and_the_fake_tcp_pose_is_our_tool0():
    robot = PlaybackRobot(HOME)
    status = read_status(robot, 1.5, Ur5eStatus())
    np.testing.assert_allclose(status.q, HOME)
    assert status.time == 1.5 and status.connected and status.fault() is None
    assert tcp_pose_error(status.q, status.tcp_pose) == pytest.approx((0.0, 0.0), abs=1e-9)


def test_tcp_pose_error_sees_a_tcp_offset():
    pose = PlaybackRobot(HOME).read().tcp_pose
    pose[2] += 0.05
    dp, dr = tcp_pose_error(HOME, pose)
    assert dp == pytest.approx(0.05) and dr == pytest.approx(0.0, abs=1e-9)


class _Broken(PlaybackRobot):
    def read(self):
        raise RuntimeError("RTDE receive thread stopped")


def test_a_failing_read_keeps_the_joints_and_reports_the_link_lost():
    previous = read_status(PlaybackRobot(HOME + 0.1), 0.0, Ur5eStatus())
    status = read_status(_Broken(HOME), 0.1, previous)
    assert not status.connected and "receive thread stopped" in status.error
    np.testing.assert_allclose(status.q, HOME + 0.1)
    fault = status.fault("10.0.0.5")
    assert fault.kind == "disconnected" and "--resume" in str(fault)
    assert "watchdog" in str(fault)


@pytest.mark.parametrize("field", ["q", "qd", "tcp_pose", "controller_time", "speed_scaling",
                                   "target_speed_fraction"])
def test_a_non_finite_reading_is_no_reading(field):
    """A NaN passes every comparison (a NaN clock is never stale, a NaN speed scaling no
    fault): a reading holding one counts as failed, the joints kept from the last good one."""
    good = PlaybackRobot(HOME).read()
    value = getattr(good, field)
    bad = np.where(np.arange(np.size(value)) == 0, np.nan, value) if np.ndim(value) \
        else np.nan

    class _Nan(PlaybackRobot):
        def read(self):
            return dc.replace(good, **{field: bad})
    previous = read_status(PlaybackRobot(HOME + 0.1), 0.0, Ur5eStatus())
    status = read_status(_Nan(HOME), 0.1, previous)
    assert not status.connected and f"non-finite {field}" in status.error
    np.testing.assert_allclose(status.q, HOME + 0.1)
    assert status.fault("10.0.0.5").kind == "disconnected"


class _Frozen(PlaybackRobot):
    def read(self):
        return dc.replace(super().read(), controller_time=42.0)


def test_a_controller_clock_that_stops_means_a_lost_link():
    status = read_status(_Frozen(HOME), 0.0, Ur5eStatus())
    assert status.connected
    status = read_status(_Frozen(HOME), 0.3, status, rtde_timeout=0.5)
    assert status.connected
    status = read_status(_Frozen(HOME), 0.6, status, rtde_timeout=0.5)
    assert not status.connected and "no new RTDE data" in status.error


@pytest.mark.parametrize("changes, kind, words", [
    (dict(protective_stop=True, safety_mode=3), "protective_stop", "clear the stop"),
    (dict(emergency_stop=True, safety_mode=7), "emergency_stop", "release the emergency"),
    (dict(safety_mode=5), "safeguard_stop", "safety input"),
    (dict(safety_mode=9), "safety_mode", "FAULT"),
    (dict(safety_mode=2), "reduced_mode", "REDUCED"),
    (dict(robot_mode=3), "not_running", "POWER_OFF"),
    (dict(target_speed_fraction=0.5, speed_scaling=0.5), "speed_scaling", "slider at 50%"),
    (dict(speed_scaling=0.8), "speed_scaling", "80% of the commanded speed"),
    # the read-only probe has no script: the scaling must show before that
    (dict(speed_scaling=0.8, program_running=False), "speed_scaling", "skips"),
    (dict(program_running=False), "script_stopped", "control script"),
    (dict(connected=False), "disconnected", "lost the RTDE connection"),
])
def test_every_fault_says_what_happened_and_how_to_go_on(changes, kind, words):
    fault = ok_status(**changes).fault("10.0.0.5")
    assert fault.kind == kind
    assert words in str(fault) and "lrnbv hardware --resume" in str(fault)


# --- Safety limits --------------------------------------------------------------------------


def test_the_sensor_must_stay_in_the_box_and_above_the_table():
    X = kinematics.forward_kinematics(HOME)
    p = X[:3, 3]
    inside = open_limits(workspace_lower=p - 0.01, workspace_upper=p + 0.01,
                         min_sensor_z=p[2] - 0.1)
    assert inside.check(HOME, HOME, np.zeros(6), HOME, PERIOD) is None
    box = open_limits(workspace_lower=p + 0.005, workspace_upper=p + 0.1, min_sensor_z=-1.0)
    assert "outside the safety box" in box.check(HOME, HOME, np.zeros(6), HOME, PERIOD).reason
    table = open_limits(min_sensor_z=p[2] + 0.01)
    assert "table clearance" in table.check(HOME, HOME, np.zeros(6), HOME, PERIOD).reason


def test_the_tracking_check_allows_the_servo_lag_of_a_moving_command_only():
    """0.1 s of lag at the command's speed plus 0.05 rad: a moving command may lead the arm
    by its lag, a command at rest may not be far from the arm."""
    limits = open_limits(speed=1.0)
    v = np.r_[1.5, 0, 0, 0, 0, 0]
    q = HOME + v * PERIOD
    lagging = HOME - v * 0.1  # the arm 0.1 s behind
    assert limits.check(q, HOME, v, lagging + v * PERIOD * 0.5, PERIOD) is None
    refusal = limits.check(q, HOME, v, lagging - 0.1, PERIOD)
    assert refusal.kind == "tracking" and "shoulder_pan_joint is 0.262 rad" in refusal.reason
    still = limits.check(HOME, HOME, np.zeros(6), HOME + 0.06, PERIOD)
    assert still.kind == "tracking" and "0.050 rad the servo may lag at 0.00 rad/s" in \
        still.reason


def test_a_non_finite_previous_command_speed_or_measurement_refuses_the_command():
    """Compared with a NaN, a 1 rad step and a 1 rad tracking error both pass: refused."""
    limits = open_limits(speed=1.0)
    jump = HOME + np.r_[1.0, 0, 0, 0, 0, 0]
    nan = np.r_[np.nan, 0, 0, 0, 0, 0]
    assert limits.check(jump, HOME, np.zeros(6), HOME, PERIOD).kind == "refused"  # the step
    for previous, speed, measured, words in (
            (HOME + nan, np.zeros(6), HOME, "previous command"),
            (HOME, nan, HOME, "previous speed"),
            (HOME, np.zeros(6), HOME + nan, "measured position")):
        refusal = limits.check(HOME, previous, speed, measured, PERIOD)
        assert refusal.kind == "refused" and words in refusal.reason


@settings(max_examples=25, deadline=None)
@given(waypoints=st.lists(st.lists(st.floats(-2.5, 2.5), min_size=6, max_size=6), min_size=2,
                          max_size=4),
       phase=st.floats(0.0, PERIOD))
def test_a_planned_trajectory_sampled_like_the_sender_never_trips_the_caps(waypoints, phase):
    """With caps equal to the planner's limits and no jump tolerance, the backward
    differences of a limited trapezoidal profile stay within the caps at any sampling phase."""
    speed, acceleration = 0.5, 0.5
    trajectory = trapezoidal_trajectory(np.array(waypoints), kinematics.VELOCITY_LIMIT * speed,
                                        kinematics.ACCELERATION_LIMIT * acceleration, phase)
    limits = open_limits(speed=speed, acceleration=acceleration, jump=1e-9,
                     max_tracking_error=10.0)
    times = np.arange(0.0, trajectory.end_time() + 3 * PERIOD, PERIOD)
    samples = [trajectory.value(min(max(t, phase), trajectory.end_time())).ravel()
               for t in times]
    q_previous, v_previous = samples[0], np.zeros(6)
    for q in samples[1:]:
        assert limits.check(q, q_previous, v_previous, q, PERIOD) is None
        q_previous, v_previous = q, (q - q_previous) / PERIOD
