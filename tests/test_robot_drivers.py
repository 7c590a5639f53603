"""The RTDE driver: `RtdeRobot` against fake ur_rtde modules (tests/fake_rtde.py), and the
receiver and sender systems each alone; the status and command checks are in
test_hardware_faults_checks.py. The URSim test runs only with URSIM_HOST set."""

from __future__ import annotations

import dataclasses as dc
import json
import os
import subprocess
import sys
import time

import fake_rtde
import numpy as np
import pytest
from fake_rtde import PERIOD, ok_status, open_limits
from pydrake.systems.analysis import Simulator

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.safety import (
    RobotConnectionError,
    RobotFault,
    Ur5eStatus,
    read_status,
    tcp_pose_error,
)
from lrnbv_drake.drivers import rtde_client
from lrnbv_drake.drivers.playback_robot import PlaybackRobot
from lrnbv_drake.drivers.rtde_client import FLAG_UPLOAD_SCRIPT, FLAG_UPPER_RANGE_REGISTERS
from lrnbv_drake.drivers.rtde_robot import CLOSE_TIMEOUT, RtdeRobot
from lrnbv_drake.systems.ur5e_command_sender import (
    SERVOJ_ACCELERATION,
    SERVOJ_SPEED,
    Ur5eCommandSender,
)
from lrnbv_drake.systems.ur5e_status_receiver import Ur5eStatusReceiver

HOME = kinematics.HOME.copy()


class RecordingRobot(PlaybackRobot):
    """The playback robot, recording every command."""

    def __init__(self, q=HOME):
        super().__init__(q)
        self.commands: list[tuple[str, tuple]] = []

    def kick_watchdog(self):
        self.commands.append(("kick", ()))

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


def test_rtde_robot_connects_sets_the_watchdog_and_sends_servoj_positionally(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5", frequency=500.0, upper_range_registers=True,
                      watchdog_frequency=12.5)
    assert arm.connections == [
        ("receive", ("10.0.0.5", 500.0, True)),
        ("control", ("10.0.0.5", 500.0, FLAG_UPLOAD_SCRIPT | FLAG_UPPER_RANGE_REGISTERS))]
    assert [c.args for c in arm.calls if c.name == "setWatchdog"] == [(12.5,)]
    q = HOME + 0.01
    # The fake's servoJ is positional-only, as the wheel's: keywords would raise TypeError.
    assert robot.servo_j(q, 1.0, 2.0, PERIOD, 0.1, 300.0)
    (call,) = [c for c in arm.calls if c.name == "servoJ"]
    np.testing.assert_allclose(call.args[0], q)
    assert call.args[1:] == (1.0, 2.0, PERIOD, 0.1, 300.0)
    reading = robot.read()
    # The lagging arm is on its way from HOME to q, as far along as the time since servoJ.
    assert np.all((HOME - 1e-9 <= reading.q) & (reading.q <= q + 1e-9))
    assert reading.connected and reading.program_running and reading.speed_scaling == 1.0
    robot.disconnect()
    names = arm.names()
    assert names[-3] == "stopScript"  # then both disconnects, in parallel
    assert sorted(names[-2:]) == ["disconnect-control", "disconnect-receive"]


def test_a_read_only_connection_uploads_no_script_and_refuses_commands(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5", control=False)
    assert [kind for kind, _ in arm.connections] == ["receive"]
    assert not robot.read().program_running
    robot.kick_watchdog()
    with pytest.raises(RobotFault, match="read-only"):
        robot.servo_j(HOME, 1.0, 1.0, PERIOD, 0.1, 300.0)
    robot.disconnect()
    assert "setWatchdog" not in arm.names() and "kickWatchdog" not in arm.names()


def test_a_failed_connection_says_what_to_check_and_closes_what_was_open(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    arm.unreachable.add("10.0.0.9")
    with pytest.raises(RobotConnectionError, match="Could not connect") as info:
        RtdeRobot("10.0.0.9")
    assert "Remote Control" in str(info.value) and "10.0.0.9" in str(info.value)


def test_control_without_a_watchdog_is_refused_before_connecting(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    with pytest.raises(ValueError, match="watchdog_frequency must be > 0 Hz"):
        RtdeRobot("10.0.0.5", watchdog_frequency=0.0)
    assert arm.connections == []


def test_a_watchdog_the_controller_refuses_fails_the_connection(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    arm.program_running = False  # the uploaded script stopped at once (a stopped program)
    with pytest.raises(RobotConnectionError, match=r"refused setWatchdog\(5.0\)"):
        RtdeRobot("10.0.0.5")
    assert [c.args for c in arm.calls if c.name == "setWatchdog"] == [(5.0,)]


def test_the_client_feeds_the_watchdog_while_the_diagram_is_held_and_not_longer(monkeypatch):
    """Between commands (a planning step holds the diagram) the client kicks the watchdog
    for `watchdog_hold` seconds after the diagram's last sign of life, then lets it trip."""
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5", watchdog_frequency=10.0, watchdog_hold=0.3)
    robot.kick_watchdog()
    time.sleep(0.2)
    held = arm.names().count("kickWatchdog")
    assert held >= 3  # the diagram's kick and the client's, every 20 ms (10 if unhurried)
    time.sleep(0.4)  # past the hold: nothing more
    stalled = arm.names().count("kickWatchdog")
    time.sleep(0.2)
    assert arm.names().count("kickWatchdog") == stalled
    robot.kick_watchdog()  # the diagram is back
    time.sleep(0.2)
    assert arm.names().count("kickWatchdog") >= stalled + 2
    robot.disconnect()


def test_servoj_range_errors_and_a_dead_client_reach_the_caller(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")
    with pytest.raises(ValueError, match=r"not within \[0;3\.14\]"):
        robot.servo_j(HOME, np.pi, 1.0, PERIOD, 0.1, 300.0)  # pi * 1.0 > 3.14
    robot.disconnect()
    with pytest.raises(RuntimeError, match="ur_rtde client"):
        robot.read()


def test_on_a_silent_link_nothing_blocks_and_no_stop_is_tried_when_closing(monkeypatch):
    """ur_rtde's getters go stale, isConnected is late and servoJ says True; servoStop and
    stopScript would block. The driver bounds servoStop and closes without either."""
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")
    arm.block_seconds = 4.0
    arm.drop_link()
    first, second = robot.read(), robot.read()
    assert first.controller_time == second.controller_time and second.connected
    assert robot.servo_j(HOME, 0.5, 0.5, PERIOD, 0.1, 300.0)  # "accepted"
    started = time.monotonic()
    robot.disconnect()
    assert time.monotonic() - started < 3.0  # the bound for a lost link
    assert "stopScript" not in arm.names()
    robot = RtdeRobot("10.0.0.5")
    with pytest.raises(RuntimeError, match="did not answer servo_stop"):
        robot.servo_stop(2.0)  # blocked in the client: abandoned after STOP_TIMEOUT
    started = time.monotonic()
    robot.disconnect()  # the client is stuck: killed, not asked to close and waited for
    assert time.monotonic() - started < CLOSE_TIMEOUT  # the dashboard's 0.75 s


def test_a_crashed_client_is_a_lost_link(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")
    arm.crash_client()
    status = read_status(robot, 0.1, ok_status())
    assert status.fault().kind == "disconnected" and "client" in status.error
    # ur_rtde may have uploaded its script again before crashing: a fresh client stops it
    robot.disconnect()
    assert arm.names()[-2:] == ["dashboard-stop", "disconnect-dashboard"]
    assert not arm.program_running


def test_a_getter_that_raises_while_closing_counts_as_a_broken_link(monkeypatch):
    """ur_rtde's receive getters can raise on a broken link: closing then asks the dashboard
    to stop the program instead of taking the error for an answer."""
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")

    def broken():
        raise RuntimeError("RTDEReceiveInterface: not connected")
    monkeypatch.setattr(arm, "timestamp", broken)
    robot.disconnect()
    assert "dashboard-stop" in arm.names() and not arm.program_running


def test_a_close_that_fails_in_the_client_still_stops_the_program(monkeypatch):
    """The client answers `close` with an error (it may have skipped stopScript): a fresh
    client asks the dashboard to stop, as for a crashed one."""
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)

    def broken_close(self):
        self.closing.set()  # as the real close does first: the watchdog's keeper stops
        raise RuntimeError("the close failed half-way")
    monkeypatch.setattr(rtde_client.Clients, "close", broken_close)
    robot = RtdeRobot("10.0.0.5")
    robot.disconnect()
    assert "dashboard-stop" in arm.names() and not arm.program_running


#: ur_rtde's receive interface, as a module for a child process: its destructor notes that
#: it ran.
FAKE_RTDE_RECEIVE = """
import os


class RTDEReceiveInterface:
    def __init__(self, *args):
        pass

    def __del__(self):
        with open(os.environ["FAKE_UR_RTDE_DESTROYED"], "a") as f:
            f.write("RTDEReceiveInterface\\n")

    def isConnected(self):
        return False

    def disconnect(self):
        pass
"""


CONNECT = {"id": 1, "op": "connect", "args": ["10.0.0.5", -1.0, False, False, 5.0, 10.0]}


@pytest.mark.parametrize("lines, answered, code", [
    ([CONNECT], [1], 0),
    ([CONNECT, {"id": 2, "op": "close"}], [1, 2], 0),
    ([CONNECT, "not a request"], [1], 1),
], ids=["the session died", "closed", "a bad request"])
def test_the_client_process_exits_without_running_ur_rtde_destructors(lines, answered, code,
                                                                      tmp_path):
    """ur_rtde's destructors disconnect (0.5 s per interface, and they can block on a dead
    link): the client process never runs them, neither when its stdin ends (the session is
    gone), nor after `close`, nor when it fails. Read-only, so that no watchdog keeper holds
    the clients: when they are freed, they are freed before the exit, as ur_rtde's were
    (seen with strace)."""
    (tmp_path / "rtde_receive.py").write_text(FAKE_RTDE_RECEIVE)
    destroyed = tmp_path / "destroyed.txt"
    env = {**os.environ, "FAKE_UR_RTDE_DESTROYED": str(destroyed),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    child = subprocess.run([sys.executable, "-m", "lrnbv_drake.drivers.rtde_client"],
                           input=b"".join((line if isinstance(line, str) else json.dumps(line))
                                          .encode() + b"\n" for line in lines),
                           capture_output=True, env=env, timeout=30)
    answers = [json.loads(line) for line in child.stdout.splitlines()]
    assert [(a["id"], a["ok"]) for a in answers] == [(i, True) for i in answered]
    assert child.returncode == code and not destroyed.exists()


# --- The systems alone ----------------------------------------------------------------------


def test_receiver_outputs_what_the_robot_reports_and_kicks_the_watchdog_every_read():
    robot = RecordingRobot(HOME)
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
    assert robot.commands.count(("kick", ())) == 4  # initialization and 0, 1, 2 periods


def test_receiver_reports_a_lost_connection_and_holds_the_last_joints():
    robot = PlaybackRobot(HOME)
    dut = Ur5eStatusReceiver(robot, period=PERIOD)
    simulator = Simulator(dut)
    simulator.Initialize()
    robot.read = lambda: dc.replace(PlaybackRobot.read(robot), connected=False)
    simulator.AdvanceTo(0.5 * PERIOD)
    context = simulator.get_context()
    assert dut.GetOutputPort("status").Eval(context).fault().kind == "disconnected"

    def dead_link():
        raise RuntimeError("receive thread stopped")
    robot.read = dead_link
    simulator.AdvanceTo(1.5 * PERIOD)
    status = dut.GetOutputPort("status").Eval(context)
    assert not status.connected and "receive thread stopped" in status.error
    np.testing.assert_allclose(dut.GetOutputPort("position_measured").Eval(context), HOME)


def _sender(robot, status=None, limits=None):
    dut = Ur5eCommandSender(robot, limits or open_limits(), period=PERIOD, lookahead_time=0.1,
                            gain=300.0, stop_deceleration=2.0, robot_ip="10.0.0.5")
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    dut.GetInputPort("status").FixValue(context, status or ok_status())
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
    dut.GetInputPort("status").FixValue(context, ok_status(q=HOME + 0.4))
    with pytest.raises(RobotFault, match="from its command") as info:
        simulator.AdvanceTo(2.5 * PERIOD)
    assert info.value.kind == "tracking" and "does not follow the commands" in str(info.value)
    assert "planner" not in str(info.value)  # the command is fine: the arm is not
    assert robot.commands[-1] == ("servo_stop", (2.0,))


@pytest.mark.parametrize("changes, kind, stops", [
    (dict(protective_stop=True, safety_mode=3), "protective_stop", True),
    (dict(emergency_stop=True, safety_mode=7), "emergency_stop", True),
    (dict(speed_scaling=0.6), "speed_scaling", True),
    (dict(safety_mode=2), "reduced_mode", True),
    (dict(connected=False), "disconnected", False),
])
def test_sender_stops_on_a_robot_fault_and_says_so(changes, kind, stops):
    robot = RecordingRobot()
    dut, simulator, context = _sender(robot)
    simulator.Initialize()
    simulator.AdvanceTo(1.5 * PERIOD)
    dut.GetInputPort("status").FixValue(context, ok_status(**changes))
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


def test_a_servoj_refused_after_a_silence_longer_than_the_hold_names_the_watchdog(monkeypatch):
    """The diagram held 1 s (a long step) with a 0.5 s hold: the watchdog stopped the
    script, and the refusal says the silence was longer than hardware.watchdog_hold. A
    refusal at once after an accepted servoJ does not blame the watchdog."""
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")
    for silence, blamed in [(1.0, True), (0.0, False)]:
        dut = Ur5eCommandSender(robot, open_limits(), period=PERIOD, robot_ip="10.0.0.5",
                                watchdog_hold=0.5)
        simulator = Simulator(dut)
        context = simulator.get_mutable_context()
        dut.GetInputPort("status").FixValue(context, ok_status())
        dut.GetInputPort("position").FixValue(context, HOME)
        arm.program_running = True
        simulator.Initialize()
        simulator.AdvanceTo(1.5 * PERIOD)  # two servoJ accepted
        time.sleep(silence)
        arm.program_running = False
        with pytest.raises(RobotFault, match="did not accept servoJ") as info:
            simulator.AdvanceTo(2.5 * PERIOD)
        assert info.value.kind == "script_stopped"
        assert ("longer than hardware.watchdog_hold (0.5 s)" in str(info.value)) == blamed
    robot.disconnect()


def test_sender_gives_servoj_valid_constants_whatever_the_caps(monkeypatch):
    """max_speed_fraction 1.0 caps at pi rad/s, above ur_rtde's 3.14 for servoJ's speed:
    the sender passes servoJ's ignored speed and acceleration as valid constants."""
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")
    _, simulator, _ = _sender(robot, limits=open_limits(speed=1.0, acceleration=1.0))
    simulator.Initialize()
    simulator.AdvanceTo(2.5 * PERIOD)
    servos = [c.args for c in arm.calls if c.name == "servoJ"]
    assert len(servos) == 3
    assert {args[1:3] for args in servos} == {(SERVOJ_SPEED, SERVOJ_ACCELERATION)}
    robot.disconnect()


def test_sender_turns_ur_rtde_range_errors_into_a_fault(monkeypatch):
    arm = fake_rtde.FakeArm(HOME)
    fake_rtde.install(monkeypatch, arm)
    robot = RtdeRobot("10.0.0.5")
    dut = Ur5eCommandSender(robot, open_limits(), period=PERIOD, lookahead_time=0.25, gain=300.0,
                            stop_deceleration=2.0, robot_ip="10.0.0.5")
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    dut.GetInputPort("status").FixValue(context, ok_status())
    dut.GetInputPort("position").FixValue(context, HOME)
    with pytest.raises(RobotFault, match=r"ur_rtde refused servoJ.*\[0\.03;0\.2\]") as info:
        simulator.Initialize()
    assert info.value.kind == "driver_error" and "servo_lookahead_time" in str(info.value)
    assert arm.names()[-1] == "servoStop"
    robot.disconnect()


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
        while np.abs(robot.read().q - target).max() > 2e-3:
            assert time.monotonic() < deadline, "URSim did not follow the servoJ targets"
            robot.servo_j(target.tolist(), 0.5, 0.5, PERIOD, 0.1, 300)
            time.sleep(PERIOD)
        robot.servo_stop(2.0)
    finally:
        robot.disconnect()
