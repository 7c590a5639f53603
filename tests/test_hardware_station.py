"""The hardware cell: the simulated cell's ports, its kinematics, the frame stamper alone, the
configuration checks, and `make_cell(hardware=True)` streaming simulated frames through the
real serial driver. Every wait is bounded; nothing asserts on how long anything took."""

from __future__ import annotations

import dataclasses as dc
import time

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.core.sensing.tof_device import _targets_kernel
from lrnbv_drake.core.sensing.tof_protocol import MAX_LINE_BYTES
from lrnbv_drake.drivers.playback_robot import PlaybackRobot
from lrnbv_drake.drivers.tof_serial import SensorTimeout, ToFSerialReader
from lrnbv_drake.station.cell import make_cell
from lrnbv_drake.station.cell_models import close_all
from lrnbv_drake.station.hardware_cell import (
    TRANSPORT_LATENCY,
    check_hardware_config,
    make_hardware_cell,
)
from lrnbv_drake.station.parts import safety_limits
from lrnbv_drake.station.scenario import Scenario, ScenarioError, load_scenario
from lrnbv_drake.station.simulated_board import SimulatedToFBoard
from lrnbv_drake.systems.tof_frame_stamper import ToFFrameStamper

HOME = kinematics.HOME.copy()
DRY = "hardware: {robot_driver: playback, sensor_driver: simulated}"


def _dry(fields: str) -> str:
    """The dry run's hardware section with more fields."""
    return DRY[:-1] + ", " + fields + "}"


def _ports(diagram):
    inputs = {diagram.get_input_port(i).get_name() for i in range(diagram.num_input_ports())}
    outputs = {diagram.get_output_port(i).get_name() for i in range(diagram.num_output_ports())}
    return inputs, outputs


@pytest.fixture
def loop_driver():
    with ToFSerialReader("loop://") as driver:
        yield driver


def test_the_hardware_cell_has_the_simulated_ports_but_query_object(loop_driver):
    scenario = Scenario()
    dut = make_hardware_cell(scenario, robot=PlaybackRobot(HOME), sensor_driver=loop_driver)
    sim_inputs, sim_outputs = _ports(make_cell(scenario).diagram)
    inputs, outputs = _ports(dut.diagram)
    assert inputs == sim_inputs == {"ur5e.position"}
    assert outputs == sim_outputs - {"query_object"}
    assert {"ur5e.position_measured", "tof.frame", "tof.pose"} <= outputs
    # Built from the scenario, so the episode can read the object and the plant.
    assert dut.models.placed_object is not None and dut.plant.num_positions() == 6
    dut.hardware.close()  # closes nothing it was given
    assert loop_driver.connected


def test_tof_pose_is_the_simulated_cells_at_the_measured_joints(loop_driver):
    scenario = Scenario()
    q = HOME + np.array([0.3, -0.2, 0.1, 0.2, -0.1, 0.4])
    dut = make_hardware_cell(scenario, robot=PlaybackRobot(q), sensor_driver=loop_driver,
                             meshcat=Meshcat(MeshcatParams(host="localhost"))).diagram
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    dut.GetInputPort("ur5e.position").FixValue(context, q)
    simulator.Initialize()
    np.testing.assert_allclose(dut.GetOutputPort("ur5e.position_measured").Eval(context), q)
    sim = make_cell(scenario).diagram
    sim_context = sim.CreateDefaultContext()
    sim.GetInputPort("ur5e.position").FixValue(sim_context, q)
    np.testing.assert_allclose(dut.GetOutputPort("tof.pose").Eval(context).GetAsMatrix4(),
                               sim.GetOutputPort("tof.pose").Eval(sim_context).GetAsMatrix4(),
                               atol=1e-12)


def test_make_cell_hardware_streams_simulated_frames_through_the_serial_driver():
    scenario = load_scenario(data=DRY)
    station = make_cell(scenario, hardware=True)
    cell = station.diagram
    try:
        simulator = Simulator(cell)
        simulator.set_target_realtime_rate(1.0)
        context = simulator.get_mutable_context()
        cell.GetInputPort("ur5e.position").FixValue(context, HOME)
        simulator.Initialize()
        deadline = time.monotonic() + 10.0
        frame = cell.GetOutputPort("tof.frame").Eval(context)
        while frame.sequence == 0:
            assert time.monotonic() < deadline, "no frame on tof.frame within 10 s"
            simulator.AdvanceTo(context.get_time() + 0.1)
            frame = cell.GetOutputPort("tof.frame").Eval(context)
        # The frame is the simulated cell's at those joints, and stamped on the diagram clock.
        sim = make_cell(scenario).diagram
        sim_context = sim.CreateDefaultContext()
        sim.GetInputPort("ur5e.position").FixValue(sim_context, HOME)
        tof = sim.GetSubsystemByName("tof")
        expected = tof.CaptureFrame(tof.GetMyContextFromRoot(sim_context),
                                    sequence=frame.sequence)
        np.testing.assert_array_equal(frame.distance_mm, expected.distance_mm)
        np.testing.assert_array_equal(frame.status, expected.status)
        # Seen at t, stamped t - latency (clipped at 0): the diagram clock, not the board's.
        assert 0 <= frame.timestamp_us <= context.get_time() * 1e6
    finally:
        station.hardware.close()


def test_closing_goes_on_past_a_driver_that_fails_and_raises_a_bug_last():
    """Newest first, every one: a sensor driver that raises, whatever it raises, cannot leave
    the robot connected. An OSError is only logged; a bug is raised once all are closed."""
    closed = []

    def failing(error):
        def close():
            closed.append(type(error).__name__)
            raise error
        return close
    to_close = [lambda: closed.append("robot"), failing(OSError("the port is gone")),
                failing(TypeError("a bug")), lambda: closed.append("board")]
    with pytest.raises(TypeError, match="a bug"):
        close_all(to_close)
    assert closed == ["board", "TypeError", "OSError", "robot"] and to_close == []


@pytest.mark.parametrize("data, field", [
    ("{}", "robot.robot_ip"),
    ("robot: {robot_ip: 10.0.0.5}", "sensor.serial_port"),
    ("{robot: {speed_fraction: 0.7}, hardware: {robot_driver: playback, "
     "sensor_driver: simulated}}", "robot.speed_fraction"),
    ("hardware: {robot_driver: playback, sensor_driver: simulated, servo_gain: 50}",
     "hardware.servo_gain"),
    ("hardware: {robot_driver: ros}", "hardware.robot_driver"),
    (_dry("max_speed_fraction: 1.5"), "hardware.max_speed_fraction"),
    (_dry("max_speed_fraction: 0"), "hardware.max_speed_fraction"),
    (_dry("watchdog_frequency: -1"), "hardware.watchdog_frequency"),
    (_dry("watchdog_frequency: 0"), "hardware.watchdog_frequency"),
    (_dry("rtde_frequency: 10"), "hardware.rtde_frequency"),
    (_dry("rtde_frequency: .nan"), "hardware.rtde_frequency"),
    (_dry("joint_lower: [0, 0, 0, 0, 0]"), "hardware.joint_lower"),
    (_dry("joint_upper: [7, 1, 1, 1, 1, 1]"), "hardware.joint_lower/upper"),
    (_dry("joint_lower: [1, -1, -1, -1, -1, -1], joint_upper: [0, 1, 1, 1, 1, 1]"),
     "hardware.joint_lower"),
])
def test_configuration_errors_name_the_field(data, field):
    with pytest.raises(ScenarioError, match=field.replace(".", r"\.")):
        check_hardware_config(load_scenario(data=data))


def test_the_transport_allowance_covers_a_full_read_out_and_the_longest_line():
    """The VL53L8CX's 8x8 read-out with every output on (about 1.4 kB over I2C at 400 kHz, 9
    bits a byte) and the longest `$TOF` line at the scenario's baud (10 bits a byte)."""
    i2c = 1400 * 9 / 400e3
    uart = (MAX_LINE_BYTES + 2) * 10 / Scenario().sensor.baud
    assert TRANSPORT_LATENCY >= i2c + uart


def test_the_command_checks_use_the_controllers_joint_limits():
    scenario = load_scenario(data="hardware: {joint_lower: [-3, -3, -3, -3, -3, -3], "
                                  "joint_upper: [3, 3, 3, 3, 3, 3]}")
    limits = safety_limits(scenario, np.eye(4), np.eye(4))
    np.testing.assert_array_equal(limits.joint_upper, np.full(6, 3.0))
    q = HOME + np.r_[3.2, 0, 0, 0, 0, 0]
    assert "outside the controller's limits" in limits.check(q, q, np.zeros(6), q, 0.008).reason
    np.testing.assert_array_equal(safety_limits(Scenario(), np.eye(4), np.eye(4)).joint_lower,
                                  kinematics.JOINT_LOWER)


# --- ToFFrameStamper alone ------------------------------------------------------------------

PERIOD, LATENCY = 0.01, 0.05


def _frame(sequence: int, board_us: int = 123_456_789) -> ToFFrame:
    return dc.replace(ToFFrame.empty(), sequence=sequence, timestamp_us=board_us + sequence)


def _stamper(**kwargs):
    dut = ToFFrameStamper(period=PERIOD, latency=LATENCY, still_speed=0.01, timeout=0.5,
                          first_timeout=0.8, diagnose=lambda: "loop:// open, 3 frames",
                          **kwargs)
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    dut.GetInputPort("tof_frame").FixValue(context, ToFFrame.empty())
    dut.GetInputPort("velocity").FixValue(context, np.zeros(6))
    simulator.Initialize()
    return dut, simulator, context


def test_stamper_puts_a_still_frame_on_the_diagram_clock():
    dut, simulator, context = _stamper()
    simulator.AdvanceTo(0.1)
    assert dut.GetOutputPort("tof_frame").Eval(context).sequence == 0
    dut.GetInputPort("tof_frame").FixValue(context, _frame(7))
    simulator.AdvanceTo(0.105)
    out = dut.GetOutputPort("tof_frame").Eval(context)
    # Seen by the update at t = 0.1, so integrated no earlier than 0.1 - latency.
    assert out.sequence == 7 and out.timestamp_us == round((0.1 - LATENCY) * 1e6)


def test_stamper_holds_back_frames_the_arm_may_have_moved_during():
    dut, simulator, context = _stamper()
    simulator.AdvanceTo(0.1)
    dut.GetInputPort("velocity").FixValue(context, np.r_[0.0, 0.5, 0, 0, 0, 0])
    simulator.AdvanceTo(0.2)
    dut.GetInputPort("velocity").FixValue(context, np.zeros(6))  # stopped at t = 0.2
    dut.GetInputPort("tof_frame").FixValue(context, _frame(1))
    simulator.AdvanceTo(0.215)
    assert dut.GetOutputPort("tof_frame").Eval(context).sequence == 0  # 0.2 + latency > t
    dut.GetInputPort("tof_frame").FixValue(context, _frame(2))
    simulator.AdvanceTo(0.245)
    assert dut.GetOutputPort("tof_frame").Eval(context).sequence == 0
    dut.GetInputPort("tof_frame").FixValue(context, _frame(3))
    simulator.AdvanceTo(0.265)
    out = dut.GetOutputPort("tof_frame").Eval(context)
    assert out.sequence == 3 and out.timestamp_us >= 0.2 * 1e6


def test_stamper_stops_the_run_when_the_sensor_falls_silent():
    dut, simulator, context = _stamper()
    simulator.AdvanceTo(0.75)  # no frame yet, but a board may still be booting
    dut.GetInputPort("tof_frame").FixValue(context, _frame(1))
    simulator.AdvanceTo(1.2)
    with pytest.raises(SensorTimeout, match=r"no new frame .* \(loop:// open, 3 frames\)"):
        simulator.AdvanceTo(1.5)


def test_stamper_gives_up_on_a_sensor_that_never_sends():
    _, simulator, _ = _stamper()
    with pytest.raises(SensorTimeout, match=r"no new frame from the ToF sensor for 0\.8 s"):
        simulator.AdvanceTo(1.0)


def test_the_dry_run_board_has_paid_its_one_time_costs_when_start_returns():
    """The session waits `sensor_timeout` plus a boot allowance for the first frame; the
    device kernels' compile (seconds on a loaded machine) must not fall into that wait.
    (Run alone: another test of the process may have compiled them already.)"""
    scenario = load_scenario(data="device: {profile: datasheet}")
    q = list(scenario.robot.initial_position)
    with ToFSerialReader("loop://", scenario.sensor.baud) as driver:
        dut = SimulatedToFBoard(scenario, lambda: q, driver).start()
        compiled = bool(_targets_kernel.signatures)
        dut.close()
    assert compiled


def test_the_dry_run_board_with_the_datasheet_device_reads_status_6_only_at_first():
    """The datasheet device marks the first frame after ranging starts status 6 (half weight,
    not a valid reading); the dry run's board must not make every frame that first one, or
    the session sees no valid zone at all."""
    scenario = load_scenario(data="device: {profile: datasheet}")
    q = list(scenario.robot.initial_position)
    with ToFSerialReader("loop://", scenario.sensor.baud) as driver:
        board = SimulatedToFBoard(scenario, lambda: q, driver).start()
        try:
            frames = {}
            deadline = time.monotonic() + 30.0
            while len(frames) < 3 and time.monotonic() < deadline:
                frame = driver.wait_for_frame(max(frames, default=0), timeout=5.0)
                frames[frame.sequence] = frame
        finally:
            board.close()
    later = [f for s, f in frames.items() if s > 1]
    assert len(later) >= 2 and all(f.valid.sum() > 32 for f in later)

