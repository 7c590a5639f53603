"""The UR5e over RTDE (ur_rtde) as a pair of Drake systems, after Drake's LCM subscriber and
publisher pair: `Ur5eStatusReceiver` reads the controller in periodic state updates and
`Ur5eCommandSender` commands it from periodic publish events. No output calculation ever
touches the network.

Commands are paced `servoJ` targets sampled from the `ur5e.position` input every
`servo_period`. servoJ, not moveJ, because the planner's trajectory is what was checked for
collisions: servoJ follows it point by point (waypoints through home included) at the
planner's speed, so the arm stops when the planner thinks it does (plus the servo's lag). A
moveJ to each held position would start only once the whole trajectory has been played,
would cut straight to the last waypoint of a multi-segment path, and could not be stopped
part way by a blocking call.

Before each command the sender checks it (`SafetyLimits`): joint limits, the sensor origin in
the workspace box and above the table, joint speed and acceleration caps on the step from the
previous command, and the distance to the measured joints. It also checks the status the
receiver read: protective stop, emergency stop, safeguard stop, a robot that is not running,
a stopped control script or a lost connection. Any of these stops the arm (when the
controller still listens) and raises `RobotFault`, whose message says what happened and what
to do; the Simulator passes the exception on to whoever called `AdvanceTo`.

Frames (docs/hardware.md): `getActualTCPPose()` is `tool0` in the controller's `base` frame,
which is `base_link * Rz(pi)` of the model, with a zero TCP offset on the pendant.
"""

from __future__ import annotations

import dataclasses as dc
import logging
import threading
import time
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, DiscreteValues, LeafSystem, State
from scipy.spatial.transform import Rotation

from lrnbv_drake import kinematics

_log = logging.getLogger(__name__)

#: RTDE `robot_mode` values (UR's RTDE guide; ur_dashboard_msgs/RobotMode).
ROBOT_MODES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING",
               3: "POWER_OFF", 4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING",
               8: "UPDATING_FIRMWARE"}
ROBOT_MODE_RUNNING = 7
#: RTDE `safety_mode` values (ur_dashboard_msgs/SafetyMode).
SAFETY_MODES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY",
                5: "SAFEGUARD_STOP", 6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP",
                8: "VIOLATION", 9: "FAULT", 10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE",
                12: "AUTOMATIC_MODE_SAFEGUARD_STOP", 13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
#: Safety modes in which the arm may move.
SAFETY_MODES_OK = (1, 2)
#: ur_rtde's RTDEControlInterface flags (rtde_control.RTDEControlInterface.FLAG_*).
FLAG_UPLOAD_SCRIPT = 1
FLAG_UPPER_RANGE_REGISTERS = 8

_RESUME_HINT = "then continue the episode with `lrnbv hardware --resume OUT_DIR`"


class RobotConnectionError(RuntimeError):
    """ur_rtde could not connect; the message lists the usual causes."""


class RobotFault(RuntimeError):
    """The robot cannot or must not go on.

    Attributes:
        kind: "protective_stop", "emergency_stop", "safeguard_stop", "safety_mode",
            "not_running", "script_stopped", "disconnected" or "refused" (a command failed a
            safety check).
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


class RobotInterface(Protocol):
    """The ur_rtde calls the drivers use, in snake case (`get_actual_q` is `getActualQ`)."""

    def get_actual_q(self) -> Sequence[float]: ...
    def get_actual_qd(self) -> Sequence[float]: ...
    def get_actual_tcp_pose(self) -> Sequence[float]: ...
    def get_timestamp(self) -> float: ...
    def get_robot_mode(self) -> int: ...
    def get_safety_mode(self) -> int: ...
    def is_protective_stopped(self) -> bool: ...
    def is_emergency_stopped(self) -> bool: ...
    def is_connected(self) -> bool: ...
    def is_program_running(self) -> bool: ...
    def servo_j(self, q: Sequence[float], speed: float, acceleration: float, time: float,
                lookahead_time: float, gain: float) -> bool: ...
    def servo_stop(self, deceleration: float) -> bool: ...
    def disconnect(self) -> None: ...


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


class PlaybackRobot:
    """A robot that is not there: each servoJ target becomes the measured position at once.

    The dry run drives the hardware diagram with it, so every command still goes through the
    sender's checks and Meshcat shows exactly the commanded motion. The velocity is the last
    step over servoJ's `time`; the TCP pose is the forward kinematics of `tool0` in `base`.
    Thread-safe: the simulated sensor board reads the joints from its own thread.
    """

    def __init__(self, q: Sequence[float]) -> None:
        self._lock = threading.Lock()
        self._q = np.array(q, float)
        self._qd = np.zeros(6)
        self._started = time.monotonic()

    def get_actual_q(self) -> list[float]:
        with self._lock:
            return self._q.tolist()

    def get_actual_qd(self) -> list[float]:
        with self._lock:
            return self._qd.tolist()

    def get_actual_tcp_pose(self) -> list[float]:
        return tcp_pose_from_q(self.get_actual_q()).tolist()

    def get_timestamp(self) -> float:
        return time.monotonic() - self._started

    def get_robot_mode(self) -> int:
        return ROBOT_MODE_RUNNING

    def get_safety_mode(self) -> int:
        return 1

    def is_protective_stopped(self) -> bool:
        return False

    def is_emergency_stopped(self) -> bool:
        return False

    def is_connected(self) -> bool:
        return True

    def is_program_running(self) -> bool:
        return True

    def servo_j(self, q: Sequence[float], speed: float, acceleration: float, time: float,
                lookahead_time: float, gain: float) -> bool:
        with self._lock:
            q = np.array(q, float)
            self._qd = (q - self._q) / time
            self._q = q
        return True

    def servo_stop(self, deceleration: float) -> bool:
        with self._lock:
            self._qd = np.zeros(6)
        return True

    def disconnect(self) -> None:
        """Nothing to close."""


def tcp_pose_from_q(q: Sequence[float]) -> np.ndarray:
    """`tool0` in `base` as the controller reports it: [x, y, z, rx, ry, rz] (rotation vector)."""
    X = kinematics.forward_kinematics(np.asarray(q, float))
    return np.r_[X[:3, 3], Rotation.from_matrix(X[:3, :3]).as_rotvec()]


def tcp_pose_error(q: Sequence[float], tcp_pose: Sequence[float]) -> tuple[float, float]:
    """(metres, radians) between the controller's TCP pose and our `tool0` at the same joints.

    Anything beyond noise means the pendant has a TCP offset set or the model's frames do not
    match the controller's (docs/hardware.md, frames)."""
    expected = kinematics.forward_kinematics(np.asarray(q, float))
    tcp_pose = np.asarray(tcp_pose, float)
    R_error = Rotation.from_matrix(expected[:3, :3]).inv() * Rotation.from_rotvec(tcp_pose[3:])
    return (float(np.linalg.norm(tcp_pose[:3] - expected[:3, 3])),
            float(R_error.magnitude()))


# --- Status ----------------------------------------------------------------------------------


@dc.dataclass(frozen=True)
class Ur5eStatus:
    """One reading of the controller.

    Attributes:
        time: diagram time of the reading, seconds.
        q, qd: actual joint positions (rad) and speeds (rad/s).
        tcp_pose: `getActualTCPPose()`, [x, y, z, rx, ry, rz] in the controller's `base`.
        controller_time: `getTimestamp()`, seconds since the controller started.
        fresh_since: diagram time at which `controller_time` last advanced.
        robot_mode, safety_mode: RTDE's codes (`ROBOT_MODES`, `SAFETY_MODES`).
        protective_stop, emergency_stop: the controller's flags.
        connected: the RTDE link is up and delivering new data.
        program_running: ur_rtde's control script runs (it executes the servoJ targets).
        error: why the reading failed, if it did.
    """

    time: float = 0.0
    q: np.ndarray = dc.field(default_factory=lambda: np.zeros(6))
    qd: np.ndarray = dc.field(default_factory=lambda: np.zeros(6))
    tcp_pose: np.ndarray = dc.field(default_factory=lambda: np.zeros(6))
    controller_time: float = 0.0
    fresh_since: float = 0.0
    robot_mode: int = -1
    safety_mode: int = 11
    protective_stop: bool = False
    emergency_stop: bool = False
    connected: bool = False
    program_running: bool = False
    error: str = ""

    def fault(self, robot_ip: str = "the robot") -> RobotFault | None:
        """What stops the robot, with what to do about it; None if it may move."""
        if not self.connected:
            return RobotFault("disconnected", (
                f"lost the RTDE connection to {robot_ip}"
                + (f" ({self.error})" if self.error else "")
                + f". The robot stops by itself when the control script loses its client. "
                f"Check the network cable and the controller, {_RESUME_HINT}"))
        if self.emergency_stop or self.safety_mode in (6, 7):
            return RobotFault("emergency_stop", (
                f"emergency stop on {robot_ip} (safety mode "
                f"{SAFETY_MODES.get(self.safety_mode, self.safety_mode)}). Make the cell safe, "
                f"release the emergency stop button, power the arm on and release the brakes "
                f"on the pendant, {_RESUME_HINT}"))
        if self.protective_stop or self.safety_mode == 3:
            return RobotFault("protective_stop", (
                f"protective stop on {robot_ip}: the arm hit something or exceeded a safety "
                f"limit. Look at the cell and the pendant's log, clear the stop on the pendant "
                f"(or the dashboard's `unlock protective stop`), {_RESUME_HINT}"))
        if self.safety_mode in (5, 12, 13):
            return RobotFault("safeguard_stop", (
                f"safeguard stop on {robot_ip} ({SAFETY_MODES[self.safety_mode]}): a safety "
                f"input (door, light curtain, enabling device) stopped the arm. Clear the "
                f"input, {_RESUME_HINT}"))
        if self.safety_mode not in SAFETY_MODES_OK:
            return RobotFault("safety_mode", (
                f"{robot_ip} is in safety mode "
                f"{SAFETY_MODES.get(self.safety_mode, self.safety_mode)}, in which the arm "
                f"must not move. Resolve it on the pendant, {_RESUME_HINT}"))
        if self.robot_mode != ROBOT_MODE_RUNNING:
            return RobotFault("not_running", (
                f"{robot_ip} is not running (robot mode "
                f"{ROBOT_MODES.get(self.robot_mode, self.robot_mode)}). Power the arm on and "
                f"release the brakes on the pendant, {_RESUME_HINT}"))
        if not self.program_running:
            return RobotFault("script_stopped", (
                f"ur_rtde's control script is not running on {robot_ip} (stopped from the "
                f"pendant, or ended by a stop), so servoJ commands would be ignored. "
                f"Check the pendant, {_RESUME_HINT} (a new connection uploads the script)"))
        return None


def read_status(robot: RobotInterface, time: float, previous: Ur5eStatus,
                rtde_timeout: float = 0.5) -> Ur5eStatus:
    """Reads the controller once (ur_rtde's getters return its latest packet; none blocks).

    The link counts as lost when the robot says so, when a getter raises, or when the
    controller's timestamp has not advanced for `rtde_timeout` seconds of diagram time (a
    silent network drop keeps the last packet forever). On a failed reading the joints keep
    their previous values. Pass `Ur5eStatus()` as `previous` for the first reading.
    """
    try:
        status = Ur5eStatus(
            time=time,
            q=np.array(robot.get_actual_q(), float),
            qd=np.array(robot.get_actual_qd(), float),
            tcp_pose=np.array(robot.get_actual_tcp_pose(), float),
            controller_time=float(robot.get_timestamp()),
            robot_mode=int(robot.get_robot_mode()),
            safety_mode=int(robot.get_safety_mode()),
            protective_stop=bool(robot.is_protective_stopped()),
            emergency_stop=bool(robot.is_emergency_stopped()),
            connected=bool(robot.is_connected()),
            program_running=bool(robot.is_program_running()),
        )
    except RuntimeError as e:
        return dc.replace(previous, time=time, connected=False, qd=np.zeros(6),
                          error=f"reading the controller failed: {e}")
    if status.q.shape != (6,):
        return dc.replace(previous, time=time, connected=False, qd=np.zeros(6),
                          error=f"the controller sent {status.q.size} joint positions")
    fresh_since = time if status.controller_time != previous.controller_time \
        else previous.fresh_since
    status = dc.replace(status, fresh_since=fresh_since)
    if status.connected and time - fresh_since > rtde_timeout:
        status = dc.replace(status, connected=False, error=(
            f"no new RTDE data for {time - fresh_since:.2f} s"))
    return status


class Ur5eStatusReceiver(LeafSystem):
    """Reads the UR5e's state into the context, like Drake's LcmSubscriberSystem.

    @system
    name: Ur5eStatusReceiver
    output_ports:
    - position_measured
    - velocity_estimated
    - status
    @endsystem

    An initialization event and a periodic unrestricted update (every `period`) read the
    controller (`read_status`) into state; the outputs are that state. `position_measured` (6)
    and `velocity_estimated` (6) are the actual joints and speeds; `status` is the whole
    `Ur5eStatus`. The receiver reports faults; the command sender acts on them.
    """

    def __init__(self, robot: RobotInterface, period: float = 0.008,
                 rtde_timeout: float = 0.5) -> None:
        super().__init__()
        self._robot = robot
        self._rtde_timeout = rtde_timeout
        self._q_index = self.DeclareDiscreteState(6)
        self._qd_index = self.DeclareDiscreteState(6)
        self._status_index = self.DeclareAbstractState(AbstractValue.Make(Ur5eStatus()))
        self.DeclareInitializationUnrestrictedUpdateEvent(self._Read)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._Read)
        self.DeclareStateOutputPort("position_measured", self._q_index)
        self.DeclareStateOutputPort("velocity_estimated", self._qd_index)
        self.DeclareStateOutputPort("status", self._status_index)

    def _Read(self, context: Context, state: State) -> None:
        status = read_status(self._robot, context.get_time(),
                             context.get_abstract_state(self._status_index).get_value(),
                             self._rtde_timeout)
        state.get_mutable_abstract_state(self._status_index).set_value(status)
        discrete = state.get_mutable_discrete_state()
        discrete.set_value(self._q_index, status.q)
        discrete.set_value(self._qd_index, status.qd)


# --- Commands --------------------------------------------------------------------------------


@dc.dataclass(frozen=True)
class SafetyLimits:
    """What a joint command must satisfy before it is sent.

    Attributes:
        joint_lower, joint_upper: (6,) joint limits, rad.
        max_velocity, max_acceleration: (6,) caps on the commanded motion, rad/s and rad/s^2.
        jump_tolerance: how much further than the caps a single step may go, rad.
        max_tracking_error: largest |command - measured| on any joint, rad.
        X_W_base: (4, 4) the controller's `base` frame in world.
        X_tool0_S: (4, 4) the sensor frame in `tool0`.
        workspace_lower, workspace_upper: (3,) box the sensor origin must stay in, world, m.
        min_sensor_z: lowest sensor origin height, world, m (table top plus clearance).
    """

    joint_lower: np.ndarray
    joint_upper: np.ndarray
    max_velocity: np.ndarray
    max_acceleration: np.ndarray
    jump_tolerance: float
    max_tracking_error: float
    X_W_base: np.ndarray
    X_tool0_S: np.ndarray
    workspace_lower: np.ndarray
    workspace_upper: np.ndarray
    min_sensor_z: float

    def sensor_position(self, q: np.ndarray) -> np.ndarray:
        """The sensor origin in world at joints q."""
        X = self.X_W_base @ kinematics.forward_kinematics(q) @ self.X_tool0_S
        return X[:3, 3]

    def check(self, q: np.ndarray, q_previous: np.ndarray, v_previous: np.ndarray,
              q_measured: np.ndarray, dt: float) -> str | None:
        """Why command q (sent dt after q_previous, which moved at v_previous) is refused, or
        None if it is fine."""
        q = np.asarray(q, float)
        names = kinematics.JOINT_NAMES
        if not np.all(np.isfinite(q)):
            return f"the command {q.tolist()} is not finite"
        outside = np.flatnonzero((q < self.joint_lower) | (q > self.joint_upper))
        if outside.size:
            i = outside[0]
            return (f"{names[i]} command {q[i]:.3f} rad is outside its limits "
                    f"[{self.joint_lower[i]:.3f}, {self.joint_upper[i]:.3f}]")
        step = q - q_previous
        too_fast = np.flatnonzero(np.abs(step) > self.max_velocity * dt + self.jump_tolerance)
        if too_fast.size:
            i = too_fast[0]
            return (f"{names[i]} command steps {step[i]:+.4f} rad in {dt * 1e3:.1f} ms "
                    f"({step[i] / dt:+.2f} rad/s), above the {self.max_velocity[i]:.2f} rad/s "
                    f"cap")
        change = step - v_previous * dt
        too_sudden = np.flatnonzero(np.abs(change) > self.max_acceleration * dt ** 2
                                    + self.jump_tolerance)
        if too_sudden.size:
            i = too_sudden[0]
            return (f"{names[i]} command changes speed by {change[i] / dt:+.2f} rad/s in "
                    f"{dt * 1e3:.1f} ms, above the {self.max_acceleration[i]:.2f} rad/s^2 cap")
        error = np.abs(q - q_measured)
        if error.max() > self.max_tracking_error:
            i = int(np.argmax(error))
            return (f"{names[i]} command is {error[i]:.3f} rad from the measured joint (at most "
                    f"{self.max_tracking_error:.3f}): the arm is not where the plan assumes")
        p = self.sensor_position(q)
        if np.any(p < self.workspace_lower) or np.any(p > self.workspace_upper):
            return (f"the sensor would be at {np.round(p, 3).tolist()}, outside the safety box "
                    f"{np.round(self.workspace_lower, 3).tolist()} .. "
                    f"{np.round(self.workspace_upper, 3).tolist()}")
        if p[2] < self.min_sensor_z:
            return (f"the sensor would be {p[2]:.3f} m high, below the {self.min_sensor_z:.3f} m "
                    f"the table clearance allows")
        return None


class Ur5eCommandSender(LeafSystem):
    """Sends the `position` input to the UR5e as paced servoJ targets, like Drake's
    LcmPublisherSystem, after checking the robot and the command.

    @system
    name: Ur5eCommandSender
    input_ports:
    - position
    - status
    @endsystem

    A periodic publish event (every `period`) checks the `status` input (a `Ur5eStatus`) and
    the command against `limits`, then calls servoJ(q, ..., time=period, lookahead_time, gain);
    when servoJ is refused, a fresh status reading names the cause.
    A periodic discrete update at the same times stores the command just sent and its speed:
    the next publish measures its step against them (an initialization event starts them at
    the measured joints, at rest). A fault or a refused command stops the arm with
    servoStop(stop_deceleration) when the controller still listens, and raises `RobotFault`.
    """

    def __init__(self, robot: RobotInterface, limits: SafetyLimits, *, period: float = 0.008,
                 lookahead_time: float = 0.1, gain: float = 300.0,
                 stop_deceleration: float = 2.0, robot_ip: str = "the robot") -> None:
        super().__init__()
        self._robot = robot
        self._limits = limits
        self._period = period
        self._lookahead_time = lookahead_time
        self._gain = gain
        self._stop_deceleration = stop_deceleration
        self._robot_ip = robot_ip
        # servoJ ignores speed and acceleration, but ur_rtde checks them against [0, 3.14]
        # and [0, 40]: pass the caps.
        self._speed = float(np.max(limits.max_velocity))
        self._acceleration = float(np.max(limits.max_acceleration))
        self._position_port = self.DeclareVectorInputPort("position", 6)
        self._status_port = self.DeclareAbstractInputPort(
            "status", AbstractValue.Make(Ur5eStatus()))
        # The last command sent and its speed.
        self._sent_index = self.DeclareDiscreteState(12)
        self.DeclareInitializationDiscreteUpdateEvent(self._Start)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._Remember)
        self.DeclarePeriodicPublishEvent(period, 0.0, self._Send)

    def _Start(self, context: Context, discrete_state: DiscreteValues) -> None:
        status: Ur5eStatus = self._status_port.Eval(context)
        discrete_state.set_value(self._sent_index, np.r_[status.q, np.zeros(6)])

    def _Remember(self, context: Context, discrete_state: DiscreteValues) -> None:
        q = self._position_port.Eval(context)
        q_previous = context.get_discrete_state(self._sent_index).value()[:6]
        discrete_state.set_value(self._sent_index, np.r_[q, (q - q_previous) / self._period])

    def _Send(self, context: Context) -> None:
        status: Ur5eStatus = self._status_port.Eval(context)
        fault = status.fault(self._robot_ip)
        if fault is not None:
            self._stop(listening=fault.kind != "disconnected")
            raise fault
        q = np.asarray(self._position_port.Eval(context), float)
        sent = context.get_discrete_state(self._sent_index).value()
        reason = self._limits.check(q, sent[:6], sent[6:], status.q, self._period)
        if reason is not None:
            self._stop(listening=True)
            raise RobotFault("refused", (
                f"refused the command at t = {context.get_time():.3f} s: {reason}. The arm "
                f"was stopped. The planner should never produce such a command: check the "
                f"scenario (workspace, table height, speed fractions) against the cell, and "
                f"hardware.* caps against the planner's, before resuming"))
        if not self._robot.servo_j(q.tolist(), self._speed, self._acceleration, self._period,
                                   self._lookahead_time, self._gain):
            # Refused since the status was read (a stop just happened?): read it again for the
            # specific cause.
            fault = read_status(self._robot, context.get_time(), status).fault(self._robot_ip)
            if fault is not None and fault.kind != "script_stopped":
                raise fault
            raise RobotFault("script_stopped", (
                f"{self._robot_ip} did not accept servoJ: ur_rtde's control script is not "
                f"executing commands. Check the pendant, {_RESUME_HINT}"))

    def _stop(self, listening: bool) -> None:
        """Orders a stop; a stop that cannot be delivered is logged, not raised, so that the
        fault that caused it is what the caller sees."""
        if not listening:
            return
        try:
            self._robot.servo_stop(self._stop_deceleration)
        except RuntimeError as e:
            _log.warning("servoStop on %s failed: %s", self._robot_ip, e)
