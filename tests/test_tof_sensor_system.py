"""ToFSensor in a small diagram: a plant whose world body carries boxes, the sensor on a welded
mount at an arbitrary pose. Scenes are laid out in the sensor frame S and placed through X_WS,
so expected readings are hand-worked in S."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.geometry import Box
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.core.sensing.sensor import (
    STATUS_NO_TARGET,
    STATUS_VALID,
    NoiseModel,
    SensorModelParams,
    ToFFrame,
    ZoneGeometry,
)
from lrnbv_drake.core.sensing.tof_device import STATUS_NO_WRAP_CHECK, DeviceBehaviour
from lrnbv_drake.systems.tof_sensor import (
    ToFSensor,
    add_tof_renderer,
    sample_zone_depths,
    tof_depth_camera,
)

X_WB = RigidTransform(RollPitchYaw(0.3, -0.2, 0.5), [0.1, -0.2, 0.4])  # welded mount body
X_BS = RigidTransform(RollPitchYaw(np.pi / 2, 0.0, 0.1), [0.0, 0.05, 0.02])  # sensor in mount
X_WS = X_WB @ X_BS
NOISELESS = SensorModelParams(noise=NoiseModel(sigma0_mm=0.0, k=0.0))
ZONE_EDGES = ZoneGeometry().zone_edges_rad()
ZONE_CENTRES = ZoneGeometry().zone_centres_rad()

# (size, centre in S) of boxes.
WALL_AT_05 = [((4.0, 4.0, 0.1), (0.0, 0.0, 0.55))]  # front face at z = 0.5 m
WALL_AT_45 = [((20.0, 20.0, 0.1), (0.0, 0.0, 4.55))]  # beyond the 4 m range


def _edge_scene(edge_angle: float) -> list:
    """The wall at 0.5 m, and a box whose front face at 0.3 m covers x >= 0.3 tan(edge_angle).
    For a negative angle the box's side face is hidden behind its front edge."""
    x_edge = 0.3 * np.tan(edge_angle)
    return [*WALL_AT_05, ((2.0, 2.0, 0.1), (x_edge + 1.0, 0.0, 0.35))]


def _make_sensor(scene: list, params: SensorModelParams, seed: int = 0,
                 behaviour: DeviceBehaviour | None = None):
    """The diagram, `dut` and its context."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    mount = plant.AddRigidBody("mount", SpatialInertia.SolidBoxWithMass(0.1, 0.02, 0.02, 0.02))
    plant.WeldFrames(plant.world_frame(), mount.body_frame(), X_WB)
    for i, (size, centre) in enumerate(scene):
        X_WG = X_WS @ RigidTransform(centre)
        plant.RegisterVisualGeometry(plant.world_body(), X_WG, Box(*size), f"box{i}", [1, 1, 1, 1])
    plant.Finalize()
    add_tof_renderer(scene_graph)
    dut = builder.AddSystem(
        ToFSensor(plant.GetBodyFrameIdOrThrow(mount.index()), X_BS, params, seed=seed,
                  behaviour=behaviour)
    )
    builder.Connect(scene_graph.get_query_output_port(), dut.get_geometry_query_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    return diagram, dut, dut.GetMyContextFromRoot(context)


def test_a_capture_given_the_frame_before_it_is_not_the_first_after_ranging_starts() -> None:
    """With the device's start-up statuses, the first frame reads status 6 in every zone that
    sees the wall; a capture handed that frame (the dry run's board captures on a context that
    never advances) reads status 5 again."""
    _, dut, context = _make_sensor(WALL_AT_05, NOISELESS,
                                   behaviour=DeviceBehaviour(startup_statuses=True))
    first = dut.CaptureFrame(context, sequence=1)
    np.testing.assert_array_equal(first.status, STATUS_NO_WRAP_CHECK)
    np.testing.assert_array_equal(dut.CaptureFrame(context, sequence=2).status,
                                  STATUS_NO_WRAP_CHECK)  # nothing in state: first again
    second = dut.CaptureFrame(context, sequence=2, previous=first)
    np.testing.assert_array_equal(second.status, STATUS_VALID)
    np.testing.assert_array_equal(second.distance_mm, first.distance_mm)


def test_wall_reads_its_perpendicular_distance_in_every_zone() -> None:
    _, dut, context = _make_sensor(WALL_AT_05, SensorModelParams())
    frame = dut.CaptureFrame(context)
    np.testing.assert_array_equal(frame.status, STATUS_VALID)
    # sigma(500 mm) = 7.5 mm; the mean of 64 zones has a standard error below 1 mm.
    assert np.all(np.abs(frame.distance_mm.astype(float) - 500) <= 4 * 7.5)
    assert abs(frame.distance_mm.mean() - 500) < 4.0

    _, dut, context = _make_sensor(WALL_AT_05, NOISELESS)
    np.testing.assert_array_equal(dut.CaptureFrame(context).distance_mm, 500)


def test_box_edge_reports_the_nearer_surface_in_the_straddling_zones() -> None:
    # The edge runs through the middle of zone column 2: half of each zone on the box.
    _, dut, context = _make_sensor(_edge_scene(ZONE_CENTRES[2]), NOISELESS)
    frame = dut.CaptureFrame(context)
    np.testing.assert_array_equal(frame.status, STATUS_VALID)
    np.testing.assert_array_equal(frame.distance_mm[:, :2], 500)
    np.testing.assert_array_equal(frame.distance_mm[:, 2], 300)  # not the 400 mm average
    np.testing.assert_array_equal(frame.distance_mm[:, 3:], 300)


@pytest.mark.parametrize(("sub_columns", "column_1_mm"), [(1, 500), (2, 300)])
def test_box_sliver_below_the_share_is_ignored(sub_columns: int, column_1_mm: int) -> None:
    # The edge `sub_columns` sub-samples into column 1: 1/8 of each zone on the box is below
    # the 25 % share and the wall behind is reported; 2/8 is exactly the share.
    sample_pitch = (ZONE_EDGES[1] - ZONE_EDGES[0]) / NOISELESS.subsamples
    edge = ZONE_EDGES[2] - sub_columns * sample_pitch
    _, dut, context = _make_sensor(_edge_scene(edge), NOISELESS)
    frame = dut.CaptureFrame(context)
    np.testing.assert_array_equal(frame.distance_mm[:, 0], 500)
    np.testing.assert_array_equal(frame.distance_mm[:, 1], column_1_mm)
    np.testing.assert_array_equal(frame.distance_mm[:, 2:], 300)


def test_nothing_within_range_is_no_target_everywhere() -> None:
    _, dut, context = _make_sensor(WALL_AT_45, SensorModelParams())
    frame = dut.CaptureFrame(context)
    np.testing.assert_array_equal(frame.status, STATUS_NO_TARGET)
    assert not frame.valid.any()


def test_raw_order_follows_the_board_flips() -> None:
    params = SensorModelParams(geometry=ZoneGeometry(flip_x=True), noise=NoiseModel(0.0, 0.0))
    _, dut, context = _make_sensor(_edge_scene(ZONE_CENTRES[2]), params)
    frame = dut.CaptureFrame(context)
    # The box covers row-major columns 2..7, i.e. raw columns 0..5 when x runs backwards.
    np.testing.assert_array_equal(frame.distance_mm[:, :6], 300)
    np.testing.assert_array_equal(frame.distance_mm[:, 6:], 500)


def test_same_seed_gives_the_same_frame() -> None:
    _, dut, context = _make_sensor(WALL_AT_05, SensorModelParams(), seed=5)
    _, twin, twin_context = _make_sensor(WALL_AT_05, SensorModelParams(), seed=5)
    _, other, other_context = _make_sensor(WALL_AT_05, SensorModelParams(), seed=6)
    a = dut.CaptureFrame(context, sequence=3)
    np.testing.assert_array_equal(dut.CaptureFrame(context, sequence=3).distance_mm, a.distance_mm)
    np.testing.assert_array_equal(twin.CaptureFrame(twin_context, 3).distance_mm, a.distance_mm)
    assert not np.array_equal(other.CaptureFrame(other_context, 3).distance_mm, a.distance_mm)
    assert not np.array_equal(dut.CaptureFrame(context, sequence=4).distance_mm, a.distance_mm)


def test_periodic_capture_fills_the_output_port() -> None:
    diagram, dut, context = _make_sensor(WALL_AT_05, SensorModelParams(), seed=2)
    assert dut.get_tof_frame_output_port().Eval(context).sequence == 0  # nothing captured yet
    simulator = Simulator(diagram)
    context = dut.GetMyContextFromRoot(simulator.get_mutable_context())
    simulator.AdvanceTo(2.5 / 15)  # captures at 0, 1/15 and 2/15 s
    frame = dut.get_tof_frame_output_port().Eval(context)
    assert isinstance(frame, ToFFrame)
    assert frame.sequence == 3
    assert frame.timestamp_us == round(2 / 15 * 1e6)
    # The captured frame is what an on-demand capture of the same sequence gives.
    np.testing.assert_array_equal(dut.CaptureFrame(context, 3).distance_mm, frame.distance_mm)
    assert dut.CaptureFrame(context).sequence == 4


@pytest.mark.parametrize(("offset_px", "covered"), [(-0.25, True), (0.25, False)])
def test_renderer_samples_pixel_u_at_u_plus_half(offset_px: float, covered: bool) -> None:
    """Pins the pixel-centre convention the sub-sample lookup relies on: VTK samples pixel u at
    tan = (u + 0.5 - center_x) / focal_x (CameraInfo's documentation says u - center_x)."""
    info = tof_depth_camera(SensorModelParams()).core().intrinsics()
    u = 40
    edge_tan = (u + 0.5 + offset_px - info.center_x()) / info.focal_x()
    _, dut, context = _make_sensor(_edge_scene(np.arctan(edge_tan)), NOISELESS)
    query_object = dut.get_geometry_query_input_port().Eval(context)
    camera = tof_depth_camera(NOISELESS)
    image = query_object.RenderDepthImage(camera, query_object.inspector().world_frame_id(), X_WS)
    row = np.asarray(image.data)[info.height() // 2, :, 0]
    assert (row[u] == pytest.approx(0.3, abs=1e-3)) == covered
    assert row[u - 1] == pytest.approx(0.5, abs=1e-3)
    assert row[u + 1] == pytest.approx(0.3, abs=1e-3)


@pytest.mark.parametrize(("resolution", "subsamples"), [(8, 8), (8, 5), (4, 8)])
def test_every_sub_sample_pixel_lies_inside_its_zone(resolution: int, subsamples: int) -> None:
    """Sample an image whose pixels hold their own x (or y) angle: each sub-sample must come
    from within a quarter sample pitch of its nominal direction, hence from inside its zone."""
    geometry = ZoneGeometry(resolution=resolution)
    params = SensorModelParams(geometry=geometry, subsamples=subsamples)
    camera = tof_depth_camera(params)
    info = camera.core().intrinsics()
    u = np.arange(info.width())
    angle = np.arctan((u + 0.5 - info.center_x()) / info.focal_x())
    x_image = np.broadcast_to(angle, (info.height(), info.width()))
    nominal = geometry.sub_angles_rad(subsamples).reshape(resolution, subsamples)
    edges = geometry.zone_edges_rad()
    quarter_pitch = (edges[1] - edges[0]) / subsamples / 4
    for sampled in (
        sample_zone_depths(x_image, camera, params),  # [row, col, sub-row, sub-col] = x angle
        sample_zone_depths(x_image.T, camera, params).transpose(1, 0, 3, 2),  # y angle
    ):
        # Indexed [zone along the axis, sub-sample along it, zone across, sub-sample across].
        along = sampled.transpose(1, 3, 0, 2)
        assert np.all(np.abs(along - nominal[:, :, None, None]) <= quarter_pitch + 1e-12)
        assert np.all(along > edges[:-1, None, None, None])
        assert np.all(along < edges[1:, None, None, None])


def test_a_tilted_plane_is_sampled_at_its_true_depth_and_an_edge_at_a_surfaces_depth() -> None:
    """The depth image of a plane has inverse depth linear in the pixel (1/z = a + b tan_x +
    c tan_y): every sample reads the plane's depth along its own direction. Across a step,
    a sample reads one of the two surfaces, never a blend."""
    params = SensorModelParams()
    camera = tof_depth_camera(params)
    info = camera.core().intrinsics()
    u, v = np.meshgrid(np.arange(info.width()), np.arange(info.height()))
    tan_x = (u + 0.5 - info.center_x()) / info.focal_x()
    tan_y = (v + 0.5 - info.center_y()) / info.focal_y()
    a, b, c = 1 / 0.3, 1.2, -0.8  # a plane 0.3 m away on the axis, seen about 55 degrees off
    plane = 1 / (a + b * tan_x + c * tan_y)
    directions = params.geometry.sub_directions(params.subsamples)
    truth = 1 / (a + b * directions[..., 0] + c * directions[..., 1])
    np.testing.assert_allclose(sample_zone_depths(plane, camera, params), truth, rtol=1e-9)
    # The nearest pixel alone is off by up to a millimetre here.
    nearest = plane[np.rint(info.center_y() + info.focal_y() * directions[..., 1] - 0.5)
                    .astype(int), np.rint(info.center_x() + info.focal_x()
                                          * directions[..., 0] - 0.5).astype(int)]
    assert np.abs(nearest - truth).max() > 5e-4
    step = np.where(tan_x < 0.05, 0.25, 0.40)  # an edge: 0.25 m left of it, 0.40 m right
    step[:, :3] = np.inf  # and nothing in range at the far left
    sampled = sample_zone_depths(step, camera, params)
    finite = sampled[np.isfinite(sampled)]
    assert np.all(np.isclose(finite, 0.25, rtol=1e-12) | np.isclose(finite, 0.40, rtol=1e-12))
    assert np.isinf(sampled).any() and np.isclose(finite, 0.25).any()
