"""A simulated cell off its model (`device.mount`, `device.zone_order`,
`device.table_offset_mm`): the sensor sees from where it really is, the board reports its zones
in its own order, the table stands where it really is, and the model's sensor pose knows none
of it."""

import itertools

import numpy as np
import pytest

from lrnbv_drake.core.evaluation.metrics import true_box
from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import ZoneGeometry
from lrnbv_drake.core.sensing.zone_order import (
    ZONE_FLIPS,
    ZONE_ROTATIONS,
    model_flips,
    reorder_zones,
    restore_zones,
)
from lrnbv_drake.station.cell import make_cell
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.scenario import ScenarioError, load_scenario
from lrnbv_drake.station.scenario_checks import check_ranges

NOISE_FREE = "sigma0_mm: 0.0, noise_k: 0.0"
#: Straight down onto the horizontal box's top, 0.28 m below (test_cell.py).
ABOVE_BOX = look_at([0.5, 0.0, 0.40], [0.5, 0.0, 0.0])


def capture(device: str, X_WS_target: np.ndarray = ABOVE_BOX, scenario_text: str = ""
            ) -> tuple:
    """The frame, the model's sensor pose and the true object from the cell with `device:`
    fields `device`, the arm at the model's pose `X_WS_target`."""
    # The view exactly as planned, not rolled half a turn about its axis.
    scenario = load_scenario(data=f"robot: {{sensor_roll_step_deg: 0.0}}\n{scenario_text}\n"
                                  f"device: {{{device}}}")
    check_ranges(scenario)
    q = MotionPlanner(scenario).ik(X_WS_target, kinematics.HOME.copy())[0]
    cell = make_cell(scenario)
    context = cell.diagram.CreateDefaultContext()
    cell.diagram.GetInputPort("ur5e.position").FixValue(context, q)
    tof = cell.diagram.GetSubsystemByName("tof")
    frame = tof.CaptureFrame(tof.GetMyContextFromRoot(context), sequence=1)
    pose = cell.diagram.GetOutputPort("tof.pose").Eval(context).GetAsMatrix4()
    return frame, pose, cell.models.placed_object


def test_zone_orders_are_the_eight_turns_and_mirrors_of_the_grid():
    # Hand-worked on a 2x2 grid, printed with row 0 on top.
    grid = np.array([[1, 2], [3, 4]])
    np.testing.assert_equal(reorder_zones(grid, 90), [[2, 4], [1, 3]])
    np.testing.assert_equal(reorder_zones(grid, 0, "rows"), [[3, 4], [1, 2]])
    np.testing.assert_equal(reorder_zones(grid, 0, "cols"), [[2, 1], [4, 3]])
    np.testing.assert_equal(reorder_zones(grid, 90, "rows"), [[4, 2], [3, 1]])
    # Every order is undone by restore_zones, and the twelve names give the eight orders of a
    # square grid: mirroring columns is mirroring rows and a half turn.
    zones = np.arange(64).reshape(8, 8)
    seen = set()
    for rotate, flip in itertools.product(ZONE_ROTATIONS, ZONE_FLIPS):
        moved = reorder_zones(zones, rotate, flip)
        np.testing.assert_equal(restore_zones(moved, rotate, flip), zones)
        seen.add(moved.tobytes())
    assert len(seen) == 8
    np.testing.assert_equal(reorder_zones(zones, 0, "cols"), reorder_zones(zones, 180, "rows"))
    with pytest.raises(ValueError, match="rotate"):
        reorder_zones(zones, 45)


def test_a_board_in_another_zone_order_reports_the_same_frame_reordered():
    nominal, pose, _ = capture("")
    for rotate, flip in [(90, "none"), (180, "rows"), (270, "cols")]:
        frame, moved_pose, _ = capture(f"zone_order: {{rotate: {rotate}, flip: {flip}}}")
        # Same noise draw, zones moved: the device reduces in the model's order, then reorders.
        np.testing.assert_equal(frame.distance_mm,
                                reorder_zones(nominal.distance_mm, rotate, flip))
        np.testing.assert_equal(frame.sigma_mm, reorder_zones(nominal.sigma_mm, rotate, flip))
        np.testing.assert_equal(moved_pose, pose)
    # The test can fail: a quarter turn of this view changes the frame.
    assert not np.array_equal(reorder_zones(nominal.distance_mm, 90), nominal.distance_mm)


@pytest.mark.parametrize(("rotate", "flip"), [(r, f) for r in ZONE_ROTATIONS
                                              for f in ("none", "rows")])
def test_the_model_reads_any_board_order_once_told_its_flips(rotate, flip):
    nominal, _, _ = capture("")
    flip_x, flip_y, transpose = model_flips(rotate, flip)
    frame, _, _ = capture(f"zone_order: {{rotate: {rotate}, flip: {flip}}}",
                          scenario_text=f"sensor: {{flip_x: {flip_x}, flip_y: {flip_y}, "
                                        f"transpose: {transpose}}}")
    geometry = ZoneGeometry(flip_x=flip_x, flip_y=flip_y, transpose=transpose)
    np.testing.assert_equal(geometry.to_row_major(frame.distance_mm), nominal.distance_mm)


def test_a_mount_off_the_model_sees_what_the_models_sensor_sees_from_the_true_pose():
    rpy, xyz = np.deg2rad([1.5, 1.0, 3.0]), np.array([2.0, -2.0, 1.0]) / 1000
    off, pose, _ = capture(f"{NOISE_FREE}, mount: {{xyz_mm: [2, -2, 1], rpy_deg: [1.5, 1, 3]}}")
    nominal, nominal_pose, _ = capture(NOISE_FREE)
    np.testing.assert_allclose(pose, nominal_pose, atol=1e-9)  # the model's pose is unchanged
    # Drake's roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll), the mount in the model's tof.
    c, s = np.cos(rpy), np.sin(rpy)
    Rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    Ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    Rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    X_MS = np.eye(4)
    X_MS[:3, :3], X_MS[:3, 3] = Rz @ Ry @ Rx, xyz
    true, _, _ = capture(NOISE_FREE, X_WS_target=nominal_pose @ X_MS)
    # Integer millimetres, and the renderer's pixel nearest each sub-sample: within 1 mm.
    valid = off.valid & true.valid
    assert valid.sum() >= 60
    assert np.abs(off.distance_mm[valid].astype(int) - true.distance_mm[valid]).max() <= 1
    # The test can fail: the error moves readings by more than that.
    assert np.abs(off.distance_mm[valid].astype(int) - nominal.distance_mm[valid]).max() >= 3


def test_a_table_off_its_height_carries_the_object_and_the_model_does_not_know():
    nominal, pose, placed = capture(NOISE_FREE)
    high, high_pose, high_placed = capture(f"{NOISE_FREE}, table_offset_mm: 5")
    # Straight down onto the box's top, 5 mm nearer in every zone that sees only the top
    # (the first and last rows straddle its edges and the table).
    inner = slice(1, 7)
    assert nominal.valid[inner].all() and high.valid[inner].all()
    difference = nominal.distance_mm[inner].astype(int) - high.distance_mm[inner]
    assert np.all(np.abs(difference - 5) <= 1) and np.median(difference) == 5
    np.testing.assert_allclose(high_pose, pose, atol=1e-9)
    np.testing.assert_allclose(high_placed.mesh.bounds[:, 2] - placed.mesh.bounds[:, 2], 0.005,
                               atol=1e-12)
    # The truth the episode is scored against stands on the true table: the same box.
    assert high_placed.table_height == pytest.approx(0.005)
    np.testing.assert_allclose(true_box(high_placed.mesh.vertices, high_placed.table_height).dims,
                               true_box(placed.mesh.vertices, placed.table_height).dims,
                               atol=1e-12)


def test_an_unknown_zone_order_or_a_table_that_carries_the_robot_is_refused(tmp_path):
    with pytest.raises(ScenarioError, match=r"'device\.zone_order\.rotate'.*0, 90, 180, 270"):
        check_ranges(load_scenario(data="device: {zone_order: {rotate: 45}}"))
    with pytest.raises(ScenarioError, match=r"'device\.zone_order\.flip'"):
        check_ranges(load_scenario(data="device: {zone_order: {flip: diagonal}}"))
    # Directives whose robot stands on the table: the table cannot move alone.
    directives = tmp_path / "cell.dmd.yaml"
    directives.write_text("""directives:
- add_model: {name: table, file: package://lrnbv_drake_models/cell/table.sdf}
- add_weld: {parent: world, child: table::top, X_PC: {translation: [0.30, 0.0, 0.0]}}
- add_model: {name: ur5e, file: package://lrnbv_drake_models/ur5e/ur5e.urdf}
- add_weld: {parent: table::top, child: ur5e::base_link, X_PC: {translation: [-0.3, 0, 0]}}
- add_model: {name: tof_mount, file: package://lrnbv_drake_models/cell/tof_mount.sdf}
- add_weld: {parent: ur5e::tool0, child: tof_mount::bracket}
""")
    scenario = load_scenario(data=f"cell: {{directives: {directives}}}\n"
                                  "device: {table_offset_mm: 5}")
    with pytest.raises(ScenarioError, match=r"'device\.table_offset_mm'.*ur5e::base_link"):
        make_cell(scenario)


def test_the_model_takes_the_commissioned_mount_in_its_pose_and_its_inverse_kinematics():
    mount = "mount: {xyz_mm: [2, -2, 1], rpy_deg: [1.5, 1, 3]}"
    # The model told the mount the device has: the arm reaches the planned sensor pose (the
    # IK goes through the calibrated mount), tof.pose is that pose, and the frame is what
    # the CAD-mounted sensor sees from it.
    frame, pose, _ = capture(f"{NOISE_FREE}, {mount}", scenario_text=f"sensor: {{{mount}}}")
    np.testing.assert_allclose(pose, ABOVE_BOX, atol=1e-9)
    nominal, _, _ = capture(NOISE_FREE)
    valid = frame.valid & nominal.valid
    assert valid.sum() >= 60
    assert np.abs(frame.distance_mm[valid].astype(int) - nominal.distance_mm[valid]).max() <= 1
    # The test can fail: with the model left on the CAD mount the arm goes elsewhere.
    uncommissioned, _, _ = capture(f"{NOISE_FREE}, {mount}")
    assert np.abs(uncommissioned.distance_mm[valid].astype(int)
                  - nominal.distance_mm[valid]).max() >= 3


def test_the_simulated_table_stays_where_it_is_whatever_height_the_model_assumes():
    # A commissioned cell.table_height moves the model's table, not the simulated one: the
    # object rests on the table the directives weld, raised by device.table_offset_mm.
    _, _, placed = capture(f"{NOISE_FREE}, table_offset_mm: 5",
                           scenario_text="cell: {table_height: 0.004}")
    assert placed.table_height == pytest.approx(0.005)
    assert placed.mesh.bounds[0, 2] == pytest.approx(0.005)
