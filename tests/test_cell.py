"""make_cell: its ports, and the sensor in the cell seeing what is there."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import STATUS_VALID
from lrnbv_drake.station.cell import make_cell
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.scenario import Scenario, ScenarioError


def test_ports_have_the_stable_names():
    dut = make_cell(Scenario()).diagram
    inputs = {dut.get_input_port(i).get_name() for i in range(dut.num_input_ports())}
    outputs = {dut.get_output_port(i).get_name() for i in range(dut.num_output_ports())}
    assert inputs == {"ur5e.position"}
    assert outputs == {"ur5e.position_measured", "tof.frame", "tof.pose", "query_object"}


def test_hardware_needs_the_robot_address():
    with pytest.raises(ScenarioError, match=r"robot\.robot_ip"):
        make_cell(Scenario(), hardware=True)


def test_sensor_looking_down_sees_the_box_top():
    scenario = Scenario()
    # The horizontal box (0.12 m tall) rests at (0.5, 0): from 0.40 m above the table, looking
    # straight down, the centre zones see its top 0.28 m away.
    target = look_at([0.5, 0.0, 0.40], [0.5, 0.0, 0.0])
    q = MotionPlanner(scenario).ik(target, kinematics.HOME.copy())[0]
    dut = make_cell(scenario).diagram
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    dut.GetInputPort("ur5e.position").FixValue(context, q)
    simulator.AdvanceTo(0.1)
    frame = dut.GetOutputPort("tof.frame").Eval(context)
    assert frame.sequence >= 1
    centre = frame.distance_mm[2:6, 2:6]
    assert np.all(frame.status[2:6, 2:6] == STATUS_VALID)
    sigma = scenario.sensor.sigma0_mm
    assert np.all(np.abs(centre - 280) <= 4 * sigma + 1)
    # The view as planned, or half a turn about its axis (`robot.sensor_roll_step_deg`).
    pose = dut.GetOutputPort("tof.pose").Eval(context).GetAsMatrix4()
    np.testing.assert_allclose(pose[:3, 2:], target[:3, 2:], atol=1e-9)
    np.testing.assert_allclose(np.abs(pose[:3, :2]), np.abs(target[:3, :2]), atol=1e-9)


def test_the_scenarios_table_extent_is_the_shipped_tables_top():
    """cell.table_extent (the box fit's table) against the table model's top box in
    SceneGraph."""
    scenario = Scenario()
    cell = make_cell(scenario)
    plant, scene_graph = cell.plant, cell.scene_graph
    context = cell.diagram.CreateDefaultContext()
    query = scene_graph.get_query_output_port().Eval(
        scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    top = plant.GetBodyByName("top", plant.GetModelInstanceByName("table"))
    (gid,) = [g for g in plant.GetCollisionGeometriesForBody(top)
              if inspector.GetName(g).endswith("top_collision")]
    size = np.array([inspector.GetShape(gid).width(), inspector.GetShape(gid).depth()])
    centre = query.GetPoseInWorld(gid).translation()[:2]
    np.testing.assert_allclose(scenario.cell.table_extent, [*(centre - size / 2),
                                                            *(centre + size / 2)], atol=1e-9)
