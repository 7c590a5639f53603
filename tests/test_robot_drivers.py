"""The RTDE driver: `RtdeRobot` against fake ur_rtde modules, `read_status`, the safety checks,
and the receiver and sender systems each alone. The URSim test runs only with URSIM_HOST set."""

from __future__ import annotations

import os
import time

import fake_rtde
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydrake.systems.analysis import Simulator

from lrnbv_drake.core import kinematics
from lrnbv_drake.core.robot_safety import (
    RobotConnectionError,
    RobotFault,
    SafetyLimits,
    Ur5eStatus,
    read_status,
    tcp_pose_error,
)
from lrnbv_drake.drivers.playback_robot import PlaybackRobot
from lrnbv_drake.drivers.rtde_robot import (
    FLAG_UPLOAD_SCRIPT,
    FLAG_UPPER_RANGE_REGISTERS,
    RtdeRobot,
)
from lrnbv_drake.station.motion import trapezoidal_trajectory
from lrnbv_drake.systems.ur5e_command_sender import Ur5eCommandSender
from lrnbv_drake.systems.ur5e_status_receiver import Ur5eStatusReceiver

HOME = kinematics.HOME.copy()
PERIOD = 0.008
# tool0 -> sensor and world -> base of the shipped cell are not needed to test the joint
# checks: identity frames and a box that holds every reachable sensor position.
WIDE_OPEN = dict(X_W_base=np.eye(4), X_tool0_S=np.eye(4), workspace_lower=np.full(3, -2.0),
                 workspace_upper=np.full(3, 2.0), min_sensor_z=-2.0)


def _limits(speed=0.6, acceleration=0.6, jump=0.002, **overrides) -> SafetyLimits:
    args = dict(joint_lower=np.asarray(kinematics.JOINT_LOWER),
                joint_upper=np.asarray(kinematics.JOINT_UPPER),
                max_velocity=kinematics.VELOCITY_LIMIT * speed,
                max_acceleration=kinematics.ACCELERATION_LIMIT * acceleration,
                jump_tolerance=jump, max_tracking_error=0.3, **WIDE_OPEN)
    args.update(overrides)
    return SafetyLimits(**args)


def _ok_status(q=HOME, **changes) -> Ur5eStatus:
    fields = dict(q=np.asarray(q, float), connected=True, program_running=True, robot_mode=7,
                  safety_mode=1, controller_time=1.0)
    fields.update(changes)
    return Ur5eStatus(**fields)


class RecordingRobot(PlaybackRobot):
    """The playback robot, recording every command."""

    def __init__(self, q=HOME):
        super().__init__(q)
        self.commands: list[tuple[str, tuple]] = []

    def servo_j(self, q, speed, acceleration, time, lookahead_time, gain):
        self.commands.append(("servo_j", (np.array(q), speed, acceleration, time,
                                          lookahead_time, gain)))
        return super().servo_j(q, speed, acceleration, time, lookahead_time, gain)

    def servo_stop(self, deceleration):
        self.commands.append(("servo_stop", (deceleration,)))
        return super().servo_stop(deceleration)

    def targets(self) -> list[np.ndarray]:
        return [args[0] for name, args in self.commands if name == "servo_j"]


# --- RtdeRobot ------------------------------------------------------------------------------


def test_rtde_robot_connects_both_interfaces_and_sends_servoj_positionally(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5", frequency=500.0, upper_range_registers=True)
    assert arm.connections == [
        ("receive", ("10.0.0.5", 500.0, True)),
        ("control", ("10.0.0.5", 500.0, FLAG_UPLOAD_SCRIPT | FLAG_UPPER_RANGE_REGISTERS))]
    q = HOME + 0.01
    # The fake's servoJ is positional-only, as the wheel's: keywords would raise TypeError.
    assert robot.servo_j(q, 1.0, 2.0, PERIOD, 0.1, 300.0)
    (call,) = [c for c in arm.calls if c.name == "servoJ"]
    np.testing.assert_allclose(call.args[0], q)
    assert call.args[1:] == (1.0, 2.0, PERIOD, 0.1, 300.0)
    np.testing.assert_allclose(robot.get_actual_q(), HOME, atol=1e-2)
    assert robot.is_connected() and robot.is_program_running()
    robot.disconnect()
    assert [c.name for c in arm.calls[-3:]] == ["stopScript", "disconnect-control",
                                                 "disconnect-receive"]


def test_a_read_only_connection_uploads_no_script_and_refuses_commands(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5", control=False)
    assert [kind for kind, _ in arm.connections] == ["receive"]
    assert not robot.is_program_running()
    with pytest.raises(RobotFault, match="read-only"):
        robot.servo_j(HOME, 1.0, 1.0, PERIOD, 0.1, 300.0)


def test_a_failed_connection_says_what_to_check_and_closes_what_was_open(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    arm.unreachable.add("10.0.0.9")
    with pytest.raises(RobotConnectionError, match="Could not connect") as info:
        RtdeRobot("10.0.0.9")
    assert "Remote Control" in str(info.value) and "10.0.0.9" in str(info.value)


# --- Status ---------------------------------------------------------------------------------


def test_read_status_reads_everything_and_the_fake_tcp_pose_is_our_tool0():
    robot = PlaybackRobot(HOME)
    status = read_status(robot, 1.5, Ur5eStatus())
    np.testing.assert_allclose(status.q, HOME)
    assert status.time == 1.5 and status.connected and status.fault() is None
    assert tcp_pose_error(status.q, status.tcp_pose) == pytest.approx((0.0, 0.0), abs=1e-9)


def test_tcp_pose_error_sees_a_tcp_offset():
    pose = PlaybackRobot(HOME).get_actual_tcp_pose()
    pose[2] += 0.05
    dp, dr = tcp_pose_error(HOME, pose)
    assert dp == pytest.approx(0.05) and dr == pytest.approx(0.0, abs=1e-9)


class _Broken(PlaybackRobot):
    def get_actual_qd(self):
        raise RuntimeError("RTDE receive thread stopped")


def test_a_failing_read_keeps_the_joints_and_reports_the_link_lost():
    previous = read_status(PlaybackRobot(HOME + 0.1), 0.0, Ur5eStatus())
    status = read_status(_Broken(HOME), 0.1, previous)
    assert not status.connected and "receive thread stopped" in status.error
    np.testing.assert_allclose(status.q, HOME + 0.1)
    fault = status.fault("10.0.0.5")
    assert fault.kind == "disconnected" and "--resume" in str(fault)


class _Frozen(PlaybackRobot):
    def get_timestamp(self):
        return 42.0


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
    (dict(robot_mode=3), "not_running", "POWER_OFF"),
    (dict(program_running=False), "script_stopped", "control script"),
    (dict(connected=False), "disconnected", "lost the RTDE connection"),
])
def test_every_fault_says_what_happened_and_how_to_go_on(changes, kind, words):
    fault = _ok_status(**changes).fault("10.0.0.5")
    assert fault.kind == kind
    assert words in str(fault) and "lrnbv hardware --resume" in str(fault)


# --- Safety limits --------------------------------------------------------------------------


def test_the_sensor_must_stay_in_the_box_and_above_the_table():
    X = kinematics.forward_kinematics(HOME)
    p = X[:3, 3]
    inside = _limits(workspace_lower=p - 0.01, workspace_upper=p + 0.01, min_sensor_z=p[2] - 0.1)
    assert inside.check(HOME, HOME, np.zeros(6), HOME, PERIOD) is None
    box = _limits(workspace_lower=p + 0.005, workspace_upper=p + 0.1, min_sensor_z=-1.0)
    assert "outside the safety box" in box.check(HOME, HOME, np.zeros(6), HOME, PERIOD)
    table = _limits(min_sensor_z=p[2] + 0.01)
    assert "table clearance" in table.check(HOME, HOME, np.zeros(6), HOME, PERIOD)


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
    limits = _limits(speed=speed, acceleration=acceleration, jump=1e-9,
                     max_tracking_error=10.0)
    times = np.arange(0.0, trajectory.end_time() + 3 * PERIOD, PERIOD)
    samples = [trajectory.value(min(max(t, phase), trajectory.end_time())).ravel()
               for t in times]
    q_previous, v_previous = samples[0], np.zeros(6)
    for q in samples[1:]:
        assert limits.check(q, q_previous, v_previous, q, PERIOD) is None
        q_previous, v_previous = q, (q - q_previous) / PERIOD


# --- The systems alone ----------------------------------------------------------------------


def test_receiver_outputs_what_the_robot_reports():
    robot = PlaybackRobot(HOME)
    dut = Ur5eStatusReceiver(robot, period=PERIOD)
    simulator = Simulator(dut)
    simulator.Initialize()
    context = simulator.get_context()
    np.testing.assert_allclose(dut.GetOutputPort("position_measured").Eval(context), HOME)
    robot.servo_j(HOME + 0.004, 0, 0, PERIOD, 0.1, 300)  # the arm moves
    simulator.AdvanceTo(2.5 * PERIOD)
    np.testing.assert_allclose(dut.GetOutputPort("position_measured").Eval(context),
                               HOME + 0.004)
    np.testing.assert_allclose(dut.GetOutputPort("velocity_estimated").Eval(context),
                               np.full(6, 0.004 / PERIOD))
    status = dut.GetOutputPort("status").Eval(context)
    assert status.connected and status.fault() is None and status.time == 2 * PERIOD


def test_receiver_reports_a_lost_connection_and_holds_the_last_joints():
    robot = PlaybackRobot(HOME)
    dut = Ur5eStatusReceiver(robot, period=PERIOD)
    simulator = Simulator(dut)
    simulator.Initialize()
    robot.is_connected = lambda: False
    simulator.AdvanceTo(0.5 * PERIOD)
    context = simulator.get_context()
    assert dut.GetOutputPort("status").Eval(context).fault().kind == "disconnected"

    def dead_link():
        raise RuntimeError("receive thread stopped")
    robot.get_actual_q = dead_link
    simulator.AdvanceTo(1.5 * PERIOD)
    status = dut.GetOutputPort("status").Eval(context)
    assert not status.connected and "receive thread stopped" in status.error
    np.testing.assert_allclose(dut.GetOutputPort("position_measured").Eval(context), HOME)


def _sender(robot, status=None, limits=None):
    dut = Ur5eCommandSender(robot, limits or _limits(), period=PERIOD, lookahead_time=0.1,
                            gain=300.0, stop_deceleration=2.0, robot_ip="10.0.0.5")
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    dut.GetInputPort("status").FixValue(context, status or _ok_status())
    dut.GetInputPort("position").FixValue(context, HOME)
    return dut, simulator, context


def test_sender_sends_the_commands_in_order_with_the_servo_settings():
    robot = RecordingRobot()
    dut, simulator, context = _sender(robot)
    simulator.Initialize()
    simulator.AdvanceTo(2.5 * PERIOD)  # publishes at 0, 1 and 2 periods
    step = np.array([0.001, -0.001, 0.0, 0.0005, 0.0, 0.0])
    dut.GetInputPort("position").FixValue(context, HOME + step)
    simulator.AdvanceTo(3.5 * PERIOD)
    dut.GetInputPort("position").FixValue(context, HOME + 2 * step)
    simulator.AdvanceTo(4.5 * PERIOD)
    targets = robot.targets()
    np.testing.assert_allclose(targets, [HOME, HOME, HOME, HOME + step, HOME + 2 * step])
    _, settings_ = robot.commands[0]
    assert settings_[3:] == (PERIOD, 0.1, 300.0)
    assert not any(name == "servo_stop" for name, _ in robot.commands)


@pytest.mark.parametrize("command, words", [
    (HOME + np.array([0, 0, 2.0, 0, 0, 0]), "elbow_joint command 3.571 rad is outside"),
    (HOME + np.array([0.05, 0, 0, 0, 0, 0]), "above the 1.88 rad/s cap"),
    (HOME + np.array([0, 0.003, 0, 0, 0, 0]), "rad/s^2 cap"),
    (np.full(6, np.nan), "not finite"),
])
def test_sender_refuses_a_command_that_breaks_a_limit_and_stops_the_arm(command, words):
    robot = RecordingRobot()
    dut, simulator, context = _sender(robot)
    simulator.Initialize()
    simulator.AdvanceTo(1.5 * PERIOD)
    dut.GetInputPort("position").FixValue(context, command)
    with pytest.raises(RobotFault, match="refused the command") as info:
        simulator.AdvanceTo(2.5 * PERIOD)
    assert info.value.kind == "refused" and words in str(info.value)
    assert robot.commands[-1] == ("servo_stop", (2.0,))
    assert len(robot.targets()) == 2  # nothing sent after the good ones


def test_sender_refuses_a_command_far_from_the_measured_joints():
    robot = RecordingRobot()
    dut, simulator, context = _sender(robot)
    simulator.Initialize()
    simulator.AdvanceTo(1.5 * PERIOD)
    dut.GetInputPort("status").FixValue(context, _ok_status(q=HOME + 0.4))
    with pytest.raises(RobotFault, match="from the measured joint"):
        simulator.AdvanceTo(2.5 * PERIOD)


@pytest.mark.parametrize("changes, kind, stops", [
    (dict(protective_stop=True, safety_mode=3), "protective_stop", True),
    (dict(emergency_stop=True, safety_mode=7), "emergency_stop", True),
    (dict(connected=False), "disconnected", False),
])
def test_sender_stops_on_a_robot_fault_and_says_so(changes, kind, stops):
    robot = RecordingRobot()
    dut, simulator, context = _sender(robot)
    simulator.Initialize()
    simulator.AdvanceTo(1.5 * PERIOD)
    dut.GetInputPort("status").FixValue(context, _ok_status(**changes))
    with pytest.raises(RobotFault) as info:
        simulator.AdvanceTo(2.5 * PERIOD)
    assert info.value.kind == kind and "10.0.0.5" in str(info.value)
    assert len(robot.targets()) == 2
    assert (robot.commands[-1][0] == "servo_stop") == stops


def test_sender_reports_a_servoj_the_controller_did_not_take(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")
    arm.program_running = False  # the status still says running: servoJ's answer tells
    _, simulator, _ = _sender(robot)
    with pytest.raises(RobotFault, match="did not accept servoJ") as info:
        simulator.Initialize()
    assert info.value.kind == "script_stopped"


# --- URSim (only with URSIM_HOST) -------------------------------------------------------------


@pytest.mark.skipif("URSIM_HOST" not in os.environ,
                    reason="set URSIM_HOST to a URSim (e-Series) with the arm powered on, "
                           "brakes released and Remote Control on")
def test_ursim_reads_and_servos_the_wrist_a_little():
    robot = RtdeRobot(os.environ["URSIM_HOST"])
    try:
        status = read_status(robot, 0.0, Ur5eStatus())
        assert status.fault() is None, status.fault()
        q0 = status.q.copy()
        dp, dr = tcp_pose_error(q0, status.tcp_pose)
        assert dp < 0.002 and dr < 0.01, "the controller's TCP is not our tool0"
        target = q0 + np.array([0, 0, 0, 0, 0, 0.05])
        for i in range(1, 126):  # 1 s at 125 Hz, a linear ramp to the target
            robot.servo_j((q0 + (target - q0) * i / 125).tolist(), 0.5, 0.5, PERIOD, 0.1, 300)
            time.sleep(PERIOD)
        deadline = time.monotonic() + 3.0
        while np.abs(np.array(robot.get_actual_q()) - target).max() > 2e-3:
            assert time.monotonic() < deadline, "URSim did not follow the servoJ targets"
            robot.servo_j(target.tolist(), 0.5, 0.5, PERIOD, 0.1, 300)
            time.sleep(PERIOD)
        robot.servo_stop(2.0)
    finally:
        robot.disconnect()
