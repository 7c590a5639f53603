"""The real cell as a Drake diagram with the simulated cell's ports, after manipulation's
`_MakeHardwareStationInterface`:

- input  `ur5e.position`           commanded joints, sent as servoJ targets after the checks;
- output `ur5e.position_measured`  the controller's actual joints;
- output `tof.frame`               the board's frames on the diagram's clock (below);
- output `tof.pose`                the sensor pose from the measured joints.

Its ports are the simulated cell's, less `query_object`: nothing here knows where the world's
geometry is. The plant is parsed from the same scenario models as in simulation but is not
part of the diagram; it is a SceneGraph source only so that Meshcat shows the measured arm
(`MultibodyPositionToGeometryPose`), and it gives `SensorPose` its kinematics.

Frames from the board carry the MCU's clock, which has nothing to do with the diagram's, and a
frame may have been integrated while the arm still moved (servoJ lags the command). The
`ToFFrameStamper` between the serial system and `tof.frame` therefore re-stamps each new frame
with the earliest diagram time its integration can have started and holds back every frame the
arm may have moved during, so the planner's "a frame captured after the stop" means the same
as in simulation.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pydrake.geometry import Meshcat, SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.safety import RobotInterface
from lrnbv_drake.drivers.playback_robot import PlaybackRobot
from lrnbv_drake.drivers.rtde_robot import RtdeRobot
from lrnbv_drake.drivers.tof_serial import ToFSerialReader
from lrnbv_drake.station.cell_models import (
    Cell,
    HardwareDrivers,
    add_cell_plant,
    apply_visualization,
    close_all,
    fixed_pose,
    sensor_on_tool0,
)
from lrnbv_drake.station.hardware_config import ROBOT_DRIVERS, SENSOR_DRIVERS
from lrnbv_drake.station.parts import safety_limits
from lrnbv_drake.station.scenario import Scenario, ScenarioError
from lrnbv_drake.station.simulated_board import SimulatedToFBoard
from lrnbv_drake.systems.sensor_pose import SensorPose
from lrnbv_drake.systems.tof_frame_stamper import ToFFrameStamper
from lrnbv_drake.systems.tof_serial_receiver import ToFSerialReceiver
from lrnbv_drake.systems.ur5e_command_sender import Ur5eCommandSender
from lrnbv_drake.systems.ur5e_status_receiver import Ur5eStatusReceiver

#: Allowance for a frame's trip from the end of its integration to the serial driver, seconds:
#: the VL53L8CX read-out over I2C (8x8 with every output enabled is about 1.4 kB, 9 bits a byte
#: at 400 kHz: 32 ms; a sketch that reads only distance, status and sigma needs far less, but
#: the host cannot tell which sketch runs), the longest `$TOF` line on the UART (1126 bytes, 10
#: bits a byte at 460800 baud: 24 ms) and USB and the OS (4 ms).
TRANSPORT_LATENCY = 0.032 + 0.024 + 0.004
#: Extra wait for the first frame, seconds: a board may reset when its port is opened (about
#: 1 s to its sketch), and the sketch's `init()` then uploads 86 kB of firmware to the sensor
#: over I2C (about 2 s at 400 kHz) before the first ranging (docs/serial-protocol.md).
BOOT_ALLOWANCE = 5.0


def check_hardware_config(scenario: Scenario, *, addresses: bool = True) -> None:
    """Raises ScenarioError naming the first `hardware` (or related) field that cannot work;
    with `addresses`, also an empty robot address or serial port the drivers would need."""
    hw = scenario.hardware
    if hw.robot_driver not in ROBOT_DRIVERS:
        raise ScenarioError(f"field 'hardware.robot_driver': expected one of {ROBOT_DRIVERS}, "
                            f"got {hw.robot_driver!r}")
    if hw.sensor_driver not in SENSOR_DRIVERS:
        raise ScenarioError(f"field 'hardware.sensor_driver': expected one of "
                            f"{SENSOR_DRIVERS}, got {hw.sensor_driver!r}")
    for name in ("status_period", "servo_period", "stop_deceleration", "max_tracking_error",
                 "rtde_timeout", "still_speed", "sensor_timeout", "watchdog_frequency",
                 "watchdog_hold"):
        if not getattr(hw, name) > 0:
            raise ScenarioError(f"field 'hardware.{name}': must be > 0, got {getattr(hw, name)}")
    if hw.commission_frames < 1:
        raise ScenarioError(f"field 'hardware.commission_frames': must be >= 1, got "
                            f"{hw.commission_frames}")
    for name in ("command_jump_tolerance", "workspace_margin", "min_table_clearance"):
        if not getattr(hw, name) >= 0:
            raise ScenarioError(f"field 'hardware.{name}': must be >= 0, got "
                                f"{getattr(hw, name)}")
    if not (hw.rtde_frequency == -1 or 125 <= hw.rtde_frequency <= 500):
        # Slower, most data packages are older than the sender's freshness limit (MAX_READING_AGE,
        # 0.05 s), which then skips its tracking check, and a live link looks dead on closing.
        raise ScenarioError(f"field 'hardware.rtde_frequency': expected -1 (the controller's "
                            f"rate) or 125 to 500 Hz, got {hw.rtde_frequency}")
    if not 0.03 <= hw.servo_lookahead_time <= 0.2:
        raise ScenarioError(f"field 'hardware.servo_lookahead_time': servoJ takes 0.03 to 0.2 "
                            f"s, got {hw.servo_lookahead_time}")
    if not 100 <= hw.servo_gain <= 2000:
        raise ScenarioError(f"field 'hardware.servo_gain': servoJ takes 100 to 2000, got "
                            f"{hw.servo_gain}")
    _check_joint_limits(hw.joint_lower, hw.joint_upper)
    for planned, cap in (("speed_fraction", "max_speed_fraction"),
                         ("acceleration_fraction", "max_acceleration_fraction")):
        p, c = getattr(scenario.robot, planned), getattr(hw, cap)
        if not 0 < c <= 1:
            raise ScenarioError(f"field 'hardware.{cap}': must be in (0, 1] (a fraction of the "
                                f"UR5e's pi rad/s and pi rad/s^2), got {c}")
        if p > c:
            raise ScenarioError(f"field 'robot.{planned}' ({p}) is above 'hardware.{cap}' "
                                f"({c}): the command sender would refuse the planned motions")
    if addresses:
        _check_robot_ip(scenario)
        _check_serial_port(scenario)


def _check_joint_limits(lower: list[float], upper: list[float]) -> None:
    """The controller's joint limits: six each, lower below upper, within the model's (the
    pendant cannot allow more than the arm does)."""
    for name, values in (("joint_lower", lower), ("joint_upper", upper)):
        if len(values) != 6 or not np.all(np.isfinite(values)):
            raise ScenarioError(f"field 'hardware.{name}': expected 6 finite angles in "
                                f"radians, got {values}")
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    if not np.all(lo < hi):
        raise ScenarioError(f"fields 'hardware.joint_lower' {lower} and 'hardware.joint_upper' "
                            f"{upper}: every lower limit must be below its upper one")
    if np.any(lo < kinematics.JOINT_LOWER) or np.any(hi > kinematics.JOINT_UPPER):
        raise ScenarioError(f"fields 'hardware.joint_lower/upper': the controller's limits "
                            f"must lie within the UR5e's {kinematics.JOINT_LOWER.tolist()} .. "
                            f"{kinematics.JOINT_UPPER.tolist()}")


def _check_robot_ip(scenario: Scenario) -> None:
    if scenario.hardware.robot_driver == "rtde" and not scenario.robot.robot_ip:
        raise ScenarioError("field 'robot.robot_ip' is empty: the real cell needs the UR "
                            "controller's address (or hardware.robot_driver: playback)")


def _check_serial_port(scenario: Scenario) -> None:
    if scenario.hardware.sensor_driver == "serial" and not scenario.sensor.serial_port:
        raise ScenarioError("field 'sensor.serial_port' is empty: the real cell needs the "
                            "sensor board's port (or hardware.sensor_driver: simulated)")


def make_robot(scenario: Scenario) -> RobotInterface:
    """The robot `hardware.robot_driver` names: RTDE (connects now) or the playback robot."""
    hw = scenario.hardware
    if hw.robot_driver == "playback":
        return PlaybackRobot(scenario.robot.initial_position)
    _check_robot_ip(scenario)
    return RtdeRobot(scenario.robot.robot_ip, frequency=hw.rtde_frequency,
                     upper_range_registers=hw.upper_range_registers,
                     watchdog_frequency=hw.watchdog_frequency, watchdog_hold=hw.watchdog_hold)


def _open_sensor(scenario: Scenario, robot: RobotInterface,
                 to_close: list[Callable[[], None]], bare_table: bool) -> ToFSerialReader:
    """Starts the sensor `hardware.sensor_driver` names; registers what to close."""
    s = scenario.sensor
    if scenario.hardware.sensor_driver == "serial":
        _check_serial_port(scenario)
        driver = ToFSerialReader(s.serial_port, s.baud).start()
        to_close.append(driver.close)
        return driver
    driver = ToFSerialReader("loop://", s.baud).start()
    to_close.append(driver.close)
    board = SimulatedToFBoard(scenario, lambda: robot.read().q, driver, bare_table).start()
    to_close.append(board.close)
    return driver


def make_hardware_cell(scenario: Scenario, meshcat: Meshcat | None = None,
                       robot: RobotInterface | None = None,
                       sensor_driver: ToFSerialReader | None = None,
                       bare_table: bool = False) -> Cell:
    """Builds the real cell (see the module docstring for its ports). Call
    `cell.hardware.close()` when done; run it in real time
    (`Simulator.set_target_realtime_rate(1.0)`).

    Args:
        scenario: the cell; `scenario.hardware` picks and tunes the drivers.
        meshcat: when given, the measured arm is drawn there.
        robot: the robot to drive; by default `make_robot(scenario)`. The caller keeps
            ownership of one passed in.
        sensor_driver: a started serial driver; by default one for `hardware.sensor_driver`.
            The caller keeps ownership of one passed in.
        bare_table: without the object (commissioning): the drawn scene, and the frames of
            the simulated sensor driver.

    Raises:
        ScenarioError: a field the hardware cannot work with.
        RobotConnectionError: the robot did not answer.
    """
    check_hardware_config(scenario, addresses=False)
    builder = DiagramBuilder()
    plant, scene_graph, models = add_cell_plant(builder, scenario, bare_table=bare_table)
    to_close: list[Callable[[], None]] = []
    try:
        if robot is None:
            robot = make_robot(scenario)
            to_close.append(robot.disconnect)
        if sensor_driver is None:
            sensor_driver = _open_sensor(scenario, robot, to_close, bare_table)
        _add_hardware_systems(builder, scenario, plant, scene_graph, robot, sensor_driver)
        if meshcat is not None:
            apply_visualization(builder, scenario, plant, scene_graph, meshcat)
        diagram = builder.Build()
    except BaseException:
        close_all(to_close)
        raise
    diagram.set_name("hardware_cell")
    return Cell(diagram, plant, scene_graph, models, meshcat,
                HardwareDrivers(robot, sensor_driver, to_close))


def _add_hardware_systems(builder: DiagramBuilder, scenario: Scenario, plant: MultibodyPlant,
                          scene_graph: SceneGraph, robot: RobotInterface,
                          sensor_driver: ToFSerialReader) -> None:
    """Adds the drivers' systems and exports the ports."""
    hw = scenario.hardware
    robot_ip = ("the playback robot" if isinstance(robot, PlaybackRobot)
                else scenario.robot.robot_ip or "the robot")
    receiver = builder.AddNamedSystem("ur5e_status", Ur5eStatusReceiver(
        robot, period=hw.status_period, rtde_timeout=hw.rtde_timeout))
    sender = builder.AddNamedSystem("ur5e_command", Ur5eCommandSender(
        robot, safety_limits(scenario, fixed_pose(plant, "world", "base").GetAsMatrix4(),
                             sensor_on_tool0(plant, scenario).GetAsMatrix4()),
        period=hw.servo_period,
        lookahead_time=hw.servo_lookahead_time, gain=hw.servo_gain,
        stop_deceleration=hw.stop_deceleration, robot_ip=robot_ip,
        watchdog_hold=hw.watchdog_hold))
    builder.Connect(receiver.GetOutputPort("status"), sender.GetInputPort("status"))
    measured = receiver.GetOutputPort("position_measured")

    to_pose = builder.AddNamedSystem("to_geometry_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(measured, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(),
                    scene_graph.get_source_pose_port(plant.get_source_id()))

    s = scenario.sensor
    poll = s.period / 2
    serial = builder.AddNamedSystem("tof_serial", ToFSerialReceiver(
        sensor_driver, period=poll, resolution=s.resolution))
    stamper = builder.AddNamedSystem("tof", ToFFrameStamper(
        period=hw.status_period,
        latency=poll + hw.status_period + s.period + TRANSPORT_LATENCY,
        still_speed=hw.still_speed, timeout=hw.sensor_timeout,
        first_timeout=hw.sensor_timeout + BOOT_ALLOWANCE, resolution=s.resolution,
        diagnose=lambda: _describe_sensor(sensor_driver)))
    builder.Connect(serial.GetOutputPort("tof_frame"), stamper.GetInputPort("tof_frame"))
    builder.Connect(receiver.GetOutputPort("velocity_estimated"),
                    stamper.GetInputPort("velocity"))
    pose = builder.AddNamedSystem("tof_pose", SensorPose(
        fixed_pose(plant, "world", "base").GetAsMatrix4(),
        sensor_on_tool0(plant, scenario).GetAsMatrix4()))
    builder.Connect(measured, pose.get_input_port())

    builder.ExportInput(sender.GetInputPort("position"), "ur5e.position")
    builder.ExportOutput(measured, "ur5e.position_measured")
    builder.ExportOutput(stamper.GetOutputPort("tof_frame"), "tof.frame")
    builder.ExportOutput(pose.get_output_port(), "tof.pose")


def _describe_sensor(driver: ToFSerialReader) -> str:
    stats = driver.stats
    return (f"{driver.port} {'open' if driver.connected else 'not open'}, {stats.frames} frames "
            f"so far, {stats.bad_crc} with a bad CRC")
