"""`HardwareConfig`: how the real cell is driven and what its drivers refuse to do.

It is the `hardware` field of a `Scenario`; the robot's address is `robot.robot_ip` and the
sensor's port `sensor.serial_port`, next to the rest of what describes them. The defaults are
the ones docs/hardware.md argues for; a scenario file overrides them like any other field:

    hardware: {servo_lookahead_time: 0.1, max_speed_fraction: 0.6}
"""

# No `from __future__ import annotations` here: Drake's YAML loader reads `Field.type`, which
# postponed annotations would turn into strings.
import dataclasses as dc

from lrnbv_drake.core.robot import kinematics

#: The robot drivers `HardwareConfig.robot_driver` names.
ROBOT_DRIVERS = ("rtde", "playback")
#: The sensor drivers `HardwareConfig.sensor_driver` names.
SENSOR_DRIVERS = ("serial", "simulated")


@dc.dataclass
class HardwareConfig:
    """The real cell's drivers, their timing and the safety checks on every command."""

    # "rtde": the UR5e at robot.robot_ip. "playback": no robot; every command is played back
    # as the measured joints (the dry run).
    robot_driver: str = "rtde"
    # "serial": the sensor board at sensor.serial_port. "simulated": frames rendered from the
    # scenario's cell at the measured joints and sent as `$TOF` lines through a pyserial
    # loop:// port, so the real serial driver reads them (the dry run).
    sensor_driver: str = "serial"
    # RTDE rate, Hz; -1 lets ur_rtde pick the controller's (500 e-Series, 125 CB3).
    rtde_frequency: float = -1.0
    # Use RTDE input registers 24-47 (FLAG_UPPER_RANGE_REGISTERS) when a fieldbus adapter or
    # another RTDE client holds the lower ones.
    upper_range_registers: bool = False
    # Period of the status reads (joints, modes, stops), seconds.
    status_period: float = 0.008
    # Period of the servoJ commands, seconds; also servoJ's `time` argument.
    servo_period: float = 0.008
    # servoJ smoothing: lookahead time in [0.03, 0.2] s (longer is smoother and lags more)
    # and proportional gain in [100, 2000].
    servo_lookahead_time: float = 0.1
    servo_gain: float = 300.0
    # Deceleration of the stop a refused command or a fault orders, m/s^2 at the tool: ur_rtde's
    # servoStop(a) runs the script's stopl(a), a tool-space stop (not a joint one).
    stop_deceleration: float = 2.0
    # The control script's RTDE watchdog, Hz: the controller stops the script (and the arm)
    # when the client has not written for 1/f s. A dead client stops the arm 0.2 s later; the
    # diagram writes every status_period (8 ms, 25 times per 0.2 s), and 0.2 s is twice the
    # longest scheduling gap seen with several sessions sharing two cores, which made 10 Hz
    # trip spuriously (docs/hardware.md, 2). It cannot be turned off: without it, a client
    # that dies mid-motion leaves the script servoing its last target.
    watchdog_frequency: float = 5.0
    # While the diagram is held (a planning step, or the box estimate after a frame: seconds,
    # and up to 14 s on a PC shared with other jobs), the driver keeps the watchdog fed for
    # at most this long, seconds; a diagram stalled longer lets the watchdog stop the script.
    # The arm holds its last target meanwhile (docs/hardware.md, "Watchdog").
    watchdog_hold: float = 60.0
    # The controller's configured joint position limits (pendant: Safety > Joint Limits),
    # radians, which every command must stay within; the model's by default (+-2 pi, elbow
    # +-pi), which is wider than any real cell's configuration.
    joint_lower: list[float] = dc.field(
        default_factory=lambda: kinematics.JOINT_LOWER.tolist())
    joint_upper: list[float] = dc.field(
        default_factory=lambda: kinematics.JOINT_UPPER.tolist())
    # Caps on the commanded joint speed and acceleration, as fractions of the UR5e limits
    # (pi rad/s, pi rad/s^2), in (0, 1]; they must allow robot.speed_fraction and
    # acceleration_fraction. servoJ is not given them (it ignores speed and acceleration).
    max_speed_fraction: float = 0.6
    max_acceleration_fraction: float = 0.6
    # A command may step this much further than the caps allow, radians: a motion starts from
    # the last command when the measured joints are within 5 mrad of it (AcquisitionLoop), else
    # from the measured joints, which differ from the last command by the servo's residual.
    command_jump_tolerance: float = 0.002
    # Largest distance between a command and the measured joints beyond the servo's lag,
    # radians. servoJ lags a moving command by about its speed x lookahead time; the check
    # allows the command's speed x (1.5 x lookahead + both periods + one RTDE package) plus
    # this, which covers the lag's tail after a stop (lookahead^2 x acceleration, 0.02 rad).
    # At rest that is 0.05 rad, 4 cm at the UR5e's 0.85 m reach.
    max_tracking_error: float = 0.05
    # Along a motion the sensor origin may leave cell.workspace by this much, metres.
    workspace_margin: float = 0.05
    # The sensor origin must stay this far above the table top, metres.
    min_table_clearance: float = 0.05
    # No new RTDE data for this long means the connection is lost, seconds.
    rtde_timeout: float = 0.5
    # Joint speeds below this count as still, rad/s: frames are kept only while the arm is.
    still_speed: float = 0.01
    # No new frame from the sensor for this long stops the run, seconds.
    sensor_timeout: float = 2.0
    # Frames averaged at each view of the bare table while commissioning (`lrnbv hardware
    # commission`): two thirds of a second at 15 Hz.
    commission_frames: int = 10
