"""The UR5e through ur_rtde: the one driver that talks to a real controller."""

from __future__ import annotations

from collections.abc import Sequence

from lrnbv_drake.core.robot_safety import RobotConnectionError, RobotFault

#: ur_rtde's RTDEControlInterface flags (rtde_control.RTDEControlInterface.FLAG_*).
FLAG_UPLOAD_SCRIPT = 1
FLAG_UPPER_RANGE_REGISTERS = 8


class RtdeRobot:
    """The UR5e through ur_rtde's `RTDEReceiveInterface` and `RTDEControlInterface`.

    Constructing it connects; with `control`, it also uploads ur_rtde's control script, which
    needs the robot in Remote Control mode. The modules are imported here, not at import time,
    so that everything else works where the wheel is missing.

    Raises:
        RobotConnectionError: ur_rtde's RuntimeError, with the usual causes appended.
    """

    def __init__(self, robot_ip: str, *, frequency: float = -1.0,
                 upper_range_registers: bool = False, control: bool = True) -> None:
        import rtde_control
        import rtde_receive

        self.robot_ip = robot_ip
        self._control = None
        try:
            self._receive = rtde_receive.RTDEReceiveInterface(
                robot_ip, frequency, [], False, upper_range_registers)
        except RuntimeError as e:
            raise _connection_error(robot_ip, e) from e
        if control:
            flags = FLAG_UPLOAD_SCRIPT | (FLAG_UPPER_RANGE_REGISTERS if upper_range_registers
                                          else 0)
            try:
                self._control = rtde_control.RTDEControlInterface(robot_ip, frequency, flags)
            except RuntimeError as e:
                self._receive.disconnect()
                raise _connection_error(robot_ip, e) from e

    def _require_control(self):
        if self._control is None:
            raise RobotFault("refused", f"the connection to {self.robot_ip} is read-only")
        return self._control

    def get_actual_q(self) -> list[float]:
        return self._receive.getActualQ()

    def get_actual_qd(self) -> list[float]:
        return self._receive.getActualQd()

    def get_actual_tcp_pose(self) -> list[float]:
        return self._receive.getActualTCPPose()

    def get_timestamp(self) -> float:
        return self._receive.getTimestamp()

    def get_robot_mode(self) -> int:
        return self._receive.getRobotMode()

    def get_safety_mode(self) -> int:
        return self._receive.getSafetyMode()

    def is_protective_stopped(self) -> bool:
        return self._receive.isProtectiveStopped()

    def is_emergency_stopped(self) -> bool:
        return self._receive.isEmergencyStopped()

    def is_connected(self) -> bool:
        return self._receive.isConnected() and (self._control is None
                                                 or self._control.isConnected())

    def is_program_running(self) -> bool:
        return self._control is not None and self._control.isProgramRunning()

    def servo_j(self, q: Sequence[float], speed: float, acceleration: float, time: float,
                lookahead_time: float, gain: float) -> bool:
        # The binding takes positional arguments only (arg0..arg5).
        return self._require_control().servoJ(list(map(float, q)), speed, acceleration, time,
                                              lookahead_time, gain)

    def servo_stop(self, deceleration: float) -> bool:
        return self._require_control().servoStop(deceleration)

    def disconnect(self) -> None:
        """Stops the control script and closes both connections."""
        if self._control is not None:
            self._control.stopScript()
            self._control.disconnect()
        self._receive.disconnect()


def _connection_error(robot_ip: str, error: RuntimeError) -> RobotConnectionError:
    return RobotConnectionError(
        f"cannot connect to the UR controller at {robot_ip} over RTDE: {error}. Check that the "
        f"address is right and reachable (ping it), that the robot is in Remote Control mode "
        f"(pendant: Settings > System > Remote Control, then the Local/Remote switch at the "
        f"top right), and that no other RTDE client, EtherNet/IP, PROFINET or MODBUS unit "
        f"holds the RTDE input registers (or set hardware.upper_range_registers)")
