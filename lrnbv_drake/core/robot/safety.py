"""The UR5e's safety logic, free of Drake and of the network: what a controller reading means
(`Ur5eStatus`, `read_status`), which faults stop the arm and what to do about each
(`RobotFault`), and the checks every joint command must pass before it is sent
(`SafetyLimits`). The drivers (`lrnbv_drake.drivers`) implement `RobotInterface`; the systems
(`Ur5eStatusReceiver`, `Ur5eCommandSender`) call what is here.

Frames (docs/hardware.md): `getActualTCPPose()` is `tool0` in the controller's `base` frame,
which is `base_link * Rz(pi)` of the model, with a zero TCP offset on the pendant.
"""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Sequence
from typing import NamedTuple, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from lrnbv_drake.core.robot import kinematics

ROBOT_MODES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING",
               3: "POWER_OFF", 4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING",
               8: "UPDATING_FIRMWARE"}
ROBOT_MODE_RUNNING = 7
#: RTDE `safety_mode` values (ur_dashboard_msgs/SafetyMode).
SAFETY_MODES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY",
                5: "SAFEGUARD_STOP", 6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP",
                8: "VIOLATION", 9: "FAULT", 10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE",
                12: "AUTOMATIC_MODE_SAFEGUARD_STOP", 13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
#: Safety modes in which the arm may move: NORMAL only. REDUCED is refused (docs/hardware.md,
#: 5): the controller enforces its reduced limits by speed scaling, under which streamed servoJ
#: targets are skipped, and a cell switches to it when someone enters (a safety input) or the
#: tool crosses a trigger plane.
SAFETY_MODES_OK = (1,)
SAFETY_MODE_REDUCED = 2
#: Speed scaling (the slider times what the controller's limits allow) below this stops the
#: arm: 1.0 is what the controller reports when nothing scales, the margin is rounding.
MIN_SPEED_SCALING = 0.999
#: A reading whose controller clock has not advanced for this long (diagram time, seconds; 25
#: packages on e-Series, 6 on CB3) is not compared with the command: the arm may have moved
#: since. `read_status`'s `rtde_timeout` decides whether the link is lost.
MAX_READING_AGE = 0.05
RESUME_HINT = "then continue the episode with `lrnbv hardware --resume OUT_DIR`"


class RobotConnectionError(RuntimeError):
    """ur_rtde could not connect; the message lists the usual causes."""


class RobotFault(RuntimeError):
    """The robot cannot or must not go on.

    Attributes:
        kind: "protective_stop", "emergency_stop", "safeguard_stop", "reduced_mode",
            "safety_mode", "not_running", "speed_scaling", "script_stopped", "disconnected",
            "refused" (a command failed a safety check), "tracking" (the arm does not follow
            the commands) or "driver_error" (ur_rtde refused a call).
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dc.dataclass(frozen=True)
class RobotReading:
    """One reading of the controller, as ur_rtde reports it (`RobotInterface.read`).

    Attributes:
        q, qd: actual joint positions (rad) and speeds (rad/s).
        tcp_pose: `getActualTCPPose()`, [x, y, z, rx, ry, rz] in the controller's `base`.
        controller_time: `getTimestamp()`, seconds since the controller started.
        robot_mode, safety_mode: RTDE's codes (`ROBOT_MODES`, `SAFETY_MODES`).
        protective_stop, emergency_stop: the controller's flags.
        connected: ur_rtde's view of its connections (it notices a silent link late).
        program_running: ur_rtde's control script runs (it executes the servoJ targets).
        speed_scaling: `getSpeedScaling()`, the fraction of the commanded speed the controller
            executes now (the slider and any safety limit that slows the arm).
        target_speed_fraction: `getTargetSpeedFraction()`, the speed slider.
    """

    q: np.ndarray = dc.field(default_factory=lambda: np.zeros(6))
    qd: np.ndarray = dc.field(default_factory=lambda: np.zeros(6))
    tcp_pose: np.ndarray = dc.field(default_factory=lambda: np.zeros(6))
    controller_time: float = 0.0
    robot_mode: int = -1
    safety_mode: int = 11
    protective_stop: bool = False
    emergency_stop: bool = False
    connected: bool = False
    program_running: bool = False
    speed_scaling: float = 0.0
    target_speed_fraction: float = 0.0


class RobotInterface(Protocol):
    """What the systems need of a robot driver: ur_rtde's calls, reading in one go."""

    def read(self) -> RobotReading:
        """The controller's latest data package; never blocks for long."""

    def kick_watchdog(self) -> None:
        """Tells the control script's RTDE watchdog that the client is alive."""

    def servo_j(self, q: Sequence[float], speed: float, acceleration: float, time: float,
                lookahead_time: float, gain: float) -> bool:
        """ur_rtde's servoJ; False when the controller did not take it."""

    def servo_stop(self, deceleration: float) -> bool:
        """ur_rtde's servoStop: the script's stopl(deceleration), m/s^2 at the tool."""

    def disconnect(self) -> None:
        """Ends the control script if the link is up and closes the connections, bounded."""


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
class Ur5eStatus(RobotReading):
    """One reading of the controller on the diagram's clock (`read_status`).

    Attributes (besides `RobotReading`'s):
        time: diagram time of the reading, seconds.
        fresh_since: diagram time at which `controller_time` last advanced.
        error: why the reading failed, if it did.
        `connected` also turns false when the controller's clock stopped (a silent link).
    """

    time: float = 0.0
    fresh_since: float = 0.0
    error: str = ""

    @property
    def current(self) -> bool:
        """The controller's clock advanced within MAX_READING_AGE: `q` is where the arm is."""
        return self.time - self.fresh_since <= MAX_READING_AGE

    def fault(self, robot_ip: str = "the robot") -> RobotFault | None:
        """What stops the robot, with what to do about it; None if it may move."""
        if not self.connected:
            return RobotFault("disconnected", (
                f"lost the RTDE connection to {robot_ip}"
                + (f" ({self.error})" if self.error else "")
                + f". ur_rtde's control script stops the arm once its RTDE watchdog misses "
                f"this client (hardware.watchdog_frequency); check on the pendant that the "
                f"program has stopped, then the network cable and the controller, "
                f"{RESUME_HINT}"))
        if self.emergency_stop or self.safety_mode in (6, 7):
            return RobotFault("emergency_stop", (
                f"emergency stop on {robot_ip} (safety mode "
                f"{SAFETY_MODES.get(self.safety_mode, self.safety_mode)}). Make the cell safe, "
                f"release the emergency stop button, power the arm on and release the brakes "
                f"on the pendant, {RESUME_HINT}"))
        if self.protective_stop or self.safety_mode == 3:
            return RobotFault("protective_stop", (
                f"protective stop on {robot_ip}: the arm hit something or exceeded a safety "
                f"limit. Look at the cell and the pendant's log, clear the stop on the pendant "
                f"(or the dashboard's `unlock protective stop`; an e-Series controller allows "
                f"it only 5 s after the stop), {RESUME_HINT}"))
        if self.safety_mode in (5, 12, 13):
            return RobotFault("safeguard_stop", (
                f"safeguard stop on {robot_ip} ({SAFETY_MODES[self.safety_mode]}): a safety "
                f"input (door, light curtain, enabling device) stopped the arm. Clear the "
                f"input, {RESUME_HINT}"))
        if self.safety_mode == SAFETY_MODE_REDUCED:
            return RobotFault("reduced_mode", (
                f"{robot_ip} is in REDUCED safety mode (a safety input, such as someone in "
                f"the cell, or the tool past a reduced-mode trigger plane). The controller "
                f"slows motions to its reduced limits by speed scaling, under which streamed "
                f"servoJ targets are skipped and the arm leaves the checked path. Clear the "
                f"cause until the pendant shows NORMAL mode, {RESUME_HINT}"))
        if self.safety_mode not in SAFETY_MODES_OK:
            return RobotFault("safety_mode", (
                f"{robot_ip} is in safety mode "
                f"{SAFETY_MODES.get(self.safety_mode, self.safety_mode)}, in which the arm "
                f"must not move. Resolve it on the pendant, {RESUME_HINT}"))
        if self.robot_mode != ROBOT_MODE_RUNNING:
            return RobotFault("not_running", (
                f"{robot_ip} is not running (robot mode "
                f"{ROBOT_MODES.get(self.robot_mode, self.robot_mode)}). Power the arm on and "
                f"release the brakes on the pendant, {RESUME_HINT}"))
        if min(self.speed_scaling, self.target_speed_fraction) < MIN_SPEED_SCALING:
            return RobotFault("speed_scaling", (
                f"{robot_ip} moves at {self.speed_scaling:.0%} of the commanded speed (speed "
                f"slider at {self.target_speed_fraction:.0%}). Under speed scaling the "
                f"controller skips streamed servoJ targets, so the arm would leave the "
                f"collision-checked path. Set the speed slider on the pendant to 100 % and "
                f"check that no safety limit (joint or tool speed, momentum, power) is below "
                f"the planner's speeds, {RESUME_HINT}"))
        if not self.program_running:
            return RobotFault("script_stopped", (
                f"ur_rtde's control script is not running on {robot_ip} (stopped from the "
                f"pendant, by a stop, or by its RTDE watchdog after the diagram stalled "
                f"longer than hardware.watchdog_hold), so servoJ commands would be ignored. "
                f"Check the pendant, {RESUME_HINT} (a new connection uploads the script)"))
        return None


def read_status(robot: RobotInterface, time: float, previous: Ur5eStatus,
                rtde_timeout: float = 0.5) -> Ur5eStatus:
    """Reads the controller once (its latest data package; never blocks for long).

    The link counts as lost when the driver says so, when reading raises, or when the
    controller's timestamp has not advanced for `rtde_timeout` seconds of diagram time (a
    silent network drop keeps the last package forever, and ur_rtde notices it only about
    2.5 s later). On a failed reading the joints keep their previous values. Pass
    `Ur5eStatus()` as `previous` for the first reading.
    """
    try:
        reading = robot.read()
    except RuntimeError as e:
        return dc.replace(previous, time=time, connected=False, qd=np.zeros(6),
                          error=f"reading the controller failed: {e}")
    if np.shape(reading.q) != (6,):
        return dc.replace(previous, time=time, connected=False, qd=np.zeros(6),
                          error=f"the controller sent {np.size(reading.q)} joint positions")
    # A NaN would pass every comparison below and in `check` (a NaN clock is never stale, a
    # NaN speed scaling no fault, a NaN joint no tracking error): no reading at all instead.
    for name in ("q", "qd", "tcp_pose", "controller_time", "speed_scaling",
                 "target_speed_fraction"):
        if not np.all(np.isfinite(np.asarray(getattr(reading, name), float))):
            return dc.replace(previous, time=time, connected=False, qd=np.zeros(6),
                              error=f"the controller sent a non-finite {name}")
    fresh_since = time if reading.controller_time != previous.controller_time \
        else previous.fresh_since
    status = Ur5eStatus(time=time, fresh_since=fresh_since, **{
        f.name: getattr(reading, f.name) for f in dc.fields(RobotReading)})
    if status.connected and time - fresh_since > rtde_timeout:
        status = dc.replace(status, connected=False, error=(
            f"no new RTDE data for {time - fresh_since:.2f} s"))
    return status


# --- Commands --------------------------------------------------------------------------------


class Refusal(NamedTuple):
    """Why a command is refused. `kind`: "refused" (the command itself breaks a limit) or
    "tracking" (the arm is not where the command assumes); `reason` says which and by how
    much."""

    kind: str
    reason: str


@dc.dataclass(frozen=True)
class SafetyLimits:
    """What a joint command must satisfy before it is sent.

    Attributes:
        joint_lower, joint_upper: (6,) joint limits, rad: the controller's configured ones.
        max_velocity, max_acceleration: (6,) caps on the commanded motion, rad/s and rad/s^2.
        jump_tolerance: how much further than the caps a single step may go, rad.
        tracking_lag: how far behind a moving command the arm may be, in seconds of the
            command's speed (the servo's lookahead plus the reading's and command's age).
        max_tracking_error: the distance a command may be from the measured joints on top of
            that lag, rad (the servo's tail after a stop, noise).
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
    tracking_lag: float
    max_tracking_error: float
    X_W_base: np.ndarray
    X_tool0_S: np.ndarray
    workspace_lower: np.ndarray
    workspace_upper: np.ndarray
    min_sensor_z: float

    def sensor_position(self, q: np.ndarray) -> np.ndarray:
        """The sensor origin in world at joints q."""
        return kinematics.sensor_pose(q, self.X_W_base, self.X_tool0_S)[:3, 3]

    def check(self, q: np.ndarray, q_previous: np.ndarray, v_previous: np.ndarray,
              q_measured: np.ndarray | None, dt: float) -> Refusal | None:
        """Why command q (sent dt after q_previous, which moved at v_previous) is refused, or
        None if it is fine. Without `q_measured` (a stale reading) the tracking is not
        checked."""
        q = np.asarray(q, float)
        names = kinematics.JOINT_NAMES
        if not np.all(np.isfinite(q)):
            return Refusal("refused", f"the command {q.tolist()} is not finite")
        for name, value in (("previous command", q_previous), ("previous speed", v_previous),
                            ("measured position", q_measured)):
            if value is not None and not np.all(np.isfinite(np.asarray(value, float))):
                # Compared with a NaN, any step passes: refuse rather than check nothing.
                return Refusal("refused", f"the {name} {np.asarray(value).tolist()} is not "
                                          f"finite")
        outside = np.flatnonzero((q < self.joint_lower) | (q > self.joint_upper))
        if outside.size:
            i = outside[0]
            return Refusal("refused", (
                f"{names[i]} command {q[i]:.3f} rad is outside the controller's limits "
                f"[{self.joint_lower[i]:.3f}, {self.joint_upper[i]:.3f}] "
                f"(hardware.joint_lower/upper)"))
        step = q - q_previous
        too_fast = np.flatnonzero(np.abs(step) > self.max_velocity * dt + self.jump_tolerance)
        if too_fast.size:
            i = too_fast[0]
            return Refusal("refused", (
                f"{names[i]} command steps {step[i]:+.4f} rad in {dt * 1e3:.1f} ms "
                f"({step[i] / dt:+.2f} rad/s), above the {self.max_velocity[i]:.2f} rad/s cap"))
        change = step - v_previous * dt
        too_sudden = np.flatnonzero(np.abs(change) > self.max_acceleration * dt ** 2
                                    + self.jump_tolerance)
        if too_sudden.size:
            i = too_sudden[0]
            return Refusal("refused", (
                f"{names[i]} command changes speed by {change[i] / dt:+.2f} rad/s in "
                f"{dt * 1e3:.1f} ms, above the {self.max_acceleration[i]:.2f} rad/s^2 cap"))
        error = np.abs(q - (q if q_measured is None else np.asarray(q_measured, float)))
        speed = np.maximum(np.abs(step) / dt, np.abs(v_previous))
        allowed = speed * self.tracking_lag + self.max_tracking_error
        behind = np.flatnonzero(error > allowed)
        if behind.size:
            i = behind[np.argmax((error - allowed)[behind])]
            return Refusal("tracking", (
                f"{names[i]} is {error[i]:.3f} rad from its command, more than the "
                f"{allowed[i]:.3f} rad the servo may lag at {speed[i]:.2f} rad/s "
                f"({self.tracking_lag * 1e3:.0f} ms of the command's speed plus "
                f"{self.max_tracking_error:.3f} rad)"))
        p = self.sensor_position(q)
        if np.any(p < self.workspace_lower) or np.any(p > self.workspace_upper):
            return Refusal("refused", (
                f"the sensor would be at {np.round(p, 3).tolist()}, outside the safety box "
                f"{np.round(self.workspace_lower, 3).tolist()} .. "
                f"{np.round(self.workspace_upper, 3).tolist()}"))
        if p[2] < self.min_sensor_z:
            return Refusal("refused", (
                f"the sensor would be {p[2]:.3f} m high, below the {self.min_sensor_z:.3f} m "
                f"the table clearance allows"))
        return None
