"""What `lrnbv hardware` checks before the arm first moves: the controller's joints and state
over read-only RTDE, that the arm may start from them, and one frame from the sensor."""

from __future__ import annotations

import logging

import numpy as np

from lrnbv_drake.core.robot.safety import Ur5eStatus, read_status, tcp_pose_error
from lrnbv_drake.drivers.rtde_robot import RtdeRobot
from lrnbv_drake.drivers.tof_serial import ToFSerialReader, check_resolution
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.parts import safety_limits
from lrnbv_drake.station.scenario import Scenario

_log = logging.getLogger(__name__)

#: A controller TCP pose this far from our tool0 (m, rad) is reported before the first motion.
TCP_WARN = (0.002, 0.01)
#: Longest wait for a frame when checking the sensor before the first motion, seconds: a board
#: may reset when its port is opened (about 1 s), and its sketch then uploads 86 kB of firmware
#: into the sensor (about 2 s at 400 kHz) before the first ranging.
SENSOR_CHECK_TIMEOUT = 5.0


class SessionError(RuntimeError):
    """The session cannot start (or resume) as asked; nothing has moved."""


def read_robot(scenario: Scenario, must_be_ready: bool) -> np.ndarray:
    """The arm's joints now, read over read-only RTDE (no control script, nothing moves).

    With `must_be_ready`, a robot in a stop or not running raises its RobotFault."""
    hw = scenario.hardware
    probe = RtdeRobot(scenario.robot.robot_ip, frequency=hw.rtde_frequency,
                      upper_range_registers=hw.upper_range_registers, control=False)
    try:
        status = read_status(probe, 0.0, Ur5eStatus(), hw.rtde_timeout)
    finally:
        probe.disconnect()
    fault = status.fault(scenario.robot.robot_ip)
    # The read-only probe has no control script; the real connection uploads it.
    if must_be_ready and fault is not None and fault.kind != "script_stopped":
        raise fault
    dp, dr = tcp_pose_error(status.q, status.tcp_pose)
    if dp > TCP_WARN[0] or dr > TCP_WARN[1]:
        _log.warning("the controller's TCP pose is %.1f mm and %.2f deg from the model's tool0 "
                     "at the same joints: is a TCP offset set on the pendant? The planner "
                     "only uses the joints, but check the frames (docs/hardware.md)",
                     dp * 1e3, np.rad2deg(dr))
    return status.q


def preflight(scenario: Scenario, q: np.ndarray) -> None:
    """Refuses to start from joints the model says collide or the sender would refuse."""
    motion = MotionPlanner(scenario)
    if not motion.collision_free(q):
        raise SessionError(
            f"the arm's current joints {np.round(q, 3).tolist()} collide with the modelled "
            f"cell (table, object, itself): either the scenario does not describe the cell, or "
            f"the arm must first be jogged to a free pose")
    limits = safety_limits(scenario, motion.X_W_base, motion.X_tool0_S)
    refusal = limits.check(q, q, np.zeros(6), q, scenario.hardware.servo_period)
    if refusal is not None:
        raise SessionError(f"cannot start from the arm's current joints: {refusal.reason}; "
                           f"jog the arm into the workspace (and the controller's joint "
                           f"limits) first")


def check_sensor(scenario: Scenario) -> None:
    """Waits for one frame from the serial sensor, so that the arm never moves blind, and
    checks that its zones are the scenario's.

    Raises:
        SensorTimeout: naming the port and what the driver saw.
        SensorError: the board streams another resolution.
    """
    s = scenario.sensor
    with ToFSerialReader(s.serial_port, s.baud) as sensor:
        check_resolution(sensor.wait_for_frame(0, timeout=SENSOR_CHECK_TIMEOUT), s.resolution,
                         s.serial_port)
