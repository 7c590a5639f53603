"""The height-map fit (core/height_map_fit.py): its ray caster against the box fit's, its parts
test, and the estimate on readings the simulated cell renders of objects that are not boxes."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from rendered_views import NOISE_FREE, render, start_near

from lrnbv_drake.core.box_fit import (
    BoxFitParams,
    ZoneRays,
    _as_vector,
    predicted_depths,
    reduction_rule,
    zone_rays,
)
from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.height_map_fit import (
    HeightMapParams,
    ShapeEstimator,
    _back_projection,
    _box_columns,
    _Clip,
    _descend_levels,
    _needed_parts,
    _outlined,
    _Readings,
    _readings_around,
    fit_height_map,
)
from lrnbv_drake.core.poses import look_at
from lrnbv_drake.core.sensor import SensorModelParams, ToFFrame


def _frame(depth_m: np.ndarray) -> ToFFrame:
    mm = np.asarray(np.round(depth_m * 1000), dtype=np.int32).reshape(8, 8)
    return ToFFrame(distance_mm=mm, status=np.full((8, 8), 5), sigma_mm=np.full((8, 8), 5),
                    sequence=1, timestamp_us=0)


def _rays_of(box: OrientedBox, model: SensorModelParams, views: list[np.ndarray]) -> ZoneRays:
    """Each view's zones with the readings the box fit's own caster predicts (any valid depth
    first, then replaced by the prediction)."""
    rays = ZoneRays.empty(model.subsamples ** 2)
    x = _as_vector(box)
    for X in views:
        r = zone_rays(_frame(np.full(64, 0.3)), X, model)
        r.measured[:] = predicted_depths(r, x, 0.0, model)
        rays = rays.extend(r.take(np.isfinite(r.measured)))
    return rays


BOX = OrientedBox(np.array([0.5, 0.0, 0.05]), np.array([0.12, 0.08, 0.10]), 0.0)


def _box_scene(eyes: list[list[float]]):
    """Readings of BOX from `eyes` (looking at its centre), on a 1 cm grid around it whose cell
    edges fall on its sides, and BOX as columns on that grid: (rays, readings, edges_x,
    edges_y, grid)."""
    model = SensorModelParams()
    rays = _rays_of(BOX, model, [look_at(eye, BOX.center) for eye in eyes])
    edges_x, edges_y = np.arange(-0.1, 0.1001, 0.01), np.arange(-0.08, 0.0801, 0.01)
    origin, to_grid = np.array([0.5, 0.0, 0.0]), np.eye(3)
    readings = _Readings(rays, origin, to_grid, 0.0, 0.3, model, BoxFitParams())
    grid = _box_columns(edges_x, edges_y, BOX, 0.0, origin, to_grid)
    return rays, readings, edges_x, edges_y, grid


def test_the_descents_cost_counts_every_wall_once_at_its_full_price():
    """The cost `_descend` returns is what it minimises: each wall between columns once, and
    a wall to the table beyond the grid's border too (it was counted at half)."""
    _, readings, edges_x, edges_y, _ = _box_scene([[0.5, 0.0, 0.45], [0.75, 0.0, 0.3]])
    heights = np.zeros((len(edges_x) - 1, len(edges_y) - 1))
    heights[0, 5], heights[8, 8] = 0.02, 0.03  # one column on the border, one inside
    padded = np.pad(heights, 1)
    walls = np.abs(np.diff(padded, axis=0)).sum() + np.abs(np.diff(padded, axis=1)).sum()
    params = HeightMapParams(volume_cost=0.0, column_cost=0.0, max_sweeps=0)

    def cost(wall_cost):
        flat = heights.reshape(-1).copy()
        return readings.descend(edges_x, edges_y, flat, np.zeros(flat.size),
                                np.ones(flat.size, bool), replace(params, wall_cost=wall_cost))
    assert cost(2000.0) - cost(0.0) == pytest.approx(2000.0 * 0.01 * walls)


def test_columns_of_a_box_predict_what_the_box_fit_predicts():
    """A height map that is a box (its sides on cell edges) seen from above, from the side and
    from 7 cm up (some sub-rays there rise, and still hit its side): the same readings as the
    box fit's slab caster, to the micrometre, on every zone."""
    rays, readings, edges_x, edges_y, grid = _box_scene(
        [[0.5, 0.0, 0.45], [0.78, 0.1, 0.2], [0.75, 0.0, 0.07]])
    assert np.any(rays.directions[..., 2] > 0)  # the low view's upper sub-rays rise
    assert grid.max() == pytest.approx(0.10) and (grid > 0).sum() == 12 * 8
    # Every zone explained exactly costs nothing; the box 2 cm shorter costs something.
    assert readings.cost(edges_x, edges_y, grid) == pytest.approx(0.0, abs=1e-9)
    shorter = grid.copy()
    shorter[14:16] = 0.0
    assert readings.cost(edges_x, edges_y, shorter) > 1.0


def test_the_back_projection_puts_the_box_top_under_a_top_view_and_the_table_around_it():
    """From straight above, every zone on the top reads 0.35 m; a cell well inside the top
    (2 cm from its sides, beyond any zone straddling an edge) gets the top's 0.10 m, a cell
    more than 2.5 cm outside (a zone's footprint is 3.4 cm wide at the top's 0.35 m, so one
    that reads the top lies at least half on it) the table's 0."""
    _, readings, edges_x, edges_y, _ = _box_scene([[0.5, 0.0, 0.45]])
    dut = _back_projection(readings, edges_x, edges_y, 0.004)
    cx, cy = (edges_x[:-1] + edges_x[1:]) / 2, (edges_y[:-1] + edges_y[1:]) / 2
    inner = (np.abs(cx) < 0.04)[:, None] & (np.abs(cy) < 0.02)[None, :]
    outer = (np.abs(cx) > 0.088)[:, None] | (np.abs(cy) > 0.068)[None, :]
    assert dut.shape == (len(cx), len(cy)) and inner.sum() == 32 and outer.sum() == 68
    np.testing.assert_allclose(dut[inner], 0.10, atol=1e-6)
    np.testing.assert_array_equal(dut[outer], 0.0)


def test_the_flange_plate_the_box_start_misses_is_raised_from_the_readings():
    """The flange (a 20 mm plate around a 50 mm hub), nine rendered views without noise: the
    box fit is the hub, 14 x 12 cm; the descent from it ends at a higher cost than the descent
    from where the readings put surfaces, which the fit keeps: its box is within 10 mm (from
    the box start alone it was 14 mm long here; with noise, and at other yaws, the flange's
    estimate still ends 5-15 mm off: docs/box-estimation.md)."""
    frames, truth, model = render("object: {name: flange, yaw_deg: 10}\n" + NOISE_FREE)
    estimator = ShapeEstimator(model, 0.0)
    for frame, X_WS in frames:
        estimator.add(frame, X_WS)
    fit = estimator.estimate(start_near(truth))
    start = estimator.last.box
    assert start.dims[1] < truth.dims[1] - 0.05  # the box fit alone: the hub
    params = HeightMapParams()
    readings, origin, to_grid, half = _readings_around(estimator._rays, start, 0.0, model,
                                                       BoxFitParams(), params)
    from_box, from_readings = (_descend_levels(readings, start, 0.0, origin, to_grid, half,
                                               params, False, initial)
                               for initial in ("box", "readings"))
    assert from_readings.cost < from_box.cost
    assert fit.shape == "height_map"
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.010)


def test_a_part_the_readings_do_not_need_is_dropped_and_one_they_need_is_kept():
    """Readings of a 12 x 8 cm box; a height map with the box, a 2-column stub beside it that
    no reading sees, and the box's true last 2 cm row left out of the expected footprint."""
    _, readings, edges_x, edges_y, grid = _box_scene(
        [[0.5, 0.0, 0.45], [0.78, 0.0, 0.25], [0.22, 0.0, 0.25]])
    expected = grid.copy()
    expected[14:16] = 0.0  # the fit expected a box 2 cm shorter
    grid[1, 0:2] = 0.02  # a stub in a corner under the field of view's edge
    out = _needed_parts(readings, edges_x, edges_y, grid, expected, HeightMapParams())
    assert np.all(out[1, 0:2] == 0.0)
    np.testing.assert_array_equal(out[14:16], grid[14:16])


def test_the_clip_of_a_block_the_readings_do_not_see_never_turns_inside_out():
    """Readings of the bare table and a 2 cm block of columns they contradict: the clip's sides
    may close in on it but never pass each other."""
    model = SensorModelParams()
    flat = OrientedBox(np.array([0.5, 0.0, 0.0005]), np.array([0.3, 0.3, 0.001]), 0.0)
    rays = _rays_of(flat, model, [look_at([0.5, 0.0, 0.4], [0.5, 0.0, 0.0]),
                                  look_at([0.7, 0.1, 0.25], [0.5, 0.0, 0.0])])
    edges = np.arange(-0.05, 0.0501, 0.01)
    readings = _Readings(rays, np.array([0.5, 0.0, 0.0]), np.eye(3), 0.0, 0.1, model,
                         BoxFitParams())
    grid = np.zeros((10, 10))
    grid[4:6, 4:6] = 0.03
    clip, cost = _Clip(readings, edges, edges, grid, HeightMapParams()).search()
    assert clip[0] < clip[1] and clip[2] < clip[3] and np.isfinite(cost)


_FIVE_VIEWS = [[0.5, 0.0, 0.45], [0.78, 0.0, 0.25], [0.22, 0.0, 0.25], [0.5, 0.25, 0.25],
               [0.5, -0.25, 0.25]]


def _widening(readings: _Readings) -> float:
    """What the box fit adds to a length or width too: 2 mm and twice 0.15 of a zone's
    footprint at the median range."""
    return 0.002 + 2 * 0.15 * float(np.median(readings.measured)) * np.radians(5.625)


@pytest.mark.parametrize("axis", [0, 1])
def test_a_side_whose_outermost_column_is_a_rod_is_bounded_as_a_wall(axis):
    """Readings of the 12 x 8 x 10 cm box from above and four sides; its columns with a 1 cm
    rod 4 cm long beyond one end (along x) or one side (along y), too thin for any zone to
    report. The clip cuts the rod, and that dimension's upper bound is the box's: the side
    moved out as a wall 10 cm tall, which the readings of the table beyond contradict within
    millimetres. Extended column by column it would move the invisible rod out, to the
    grid's edge, and bound nothing."""
    _, readings, edges_x, edges_y, grid = _box_scene(_FIVE_VIEWS)
    if axis == 0:
        grid[16:20, 8] = 0.10
    else:
        grid[10, 12:16] = 0.10
    dut = _Clip(readings, edges_x, edges_y, grid, HeightMapParams())
    clip, cost = dut.search()
    np.testing.assert_allclose(clip, [-0.06, 0.06, -0.04, 0.04, 0.10], atol=1e-9)
    lower, upper = dut.interval(clip, cost, BoxFitParams(), SensorModelParams())
    true = np.array([0.12, 0.08, 0.10])
    assert upper[axis] - true[axis] - _widening(readings) < 0.005
    assert np.all(lower <= true) and np.all(upper >= true)


def test_a_side_a_rounding_error_past_a_cell_edge_is_walled_from_the_inner_cell():
    """The box's columns with a 5 mm skirt 4 cm long beyond its +x end, and the clip's +x side
    on the edge between them, or one rounding error past it (the search's steps from an edge
    land there): either way the side moves out as a wall of the box's 10 cm, not of the
    skirt's 5 mm, which the readings cannot tell from the table."""
    _, readings, edges_x, edges_y, grid = _box_scene(_FIVE_VIEWS)
    grid[16:20, 4:12] = 0.005
    dut = _Clip(readings, edges_x, edges_y, grid, HeightMapParams())
    uppers = []
    for x1 in (edges_x[16], np.nextafter(edges_x[16], 1.0)):
        clip = np.array([edges_x[4], x1, edges_y[4], edges_y[12], 0.10])
        clip[4] = dut._plateau_top(clip)
        uppers.append(dut.interval(clip, dut.flat_cost(clip), BoxFitParams(),
                                   SensorModelParams())[1][0])
    assert uppers[0] == uppers[1]
    assert uppers[1] - 0.12 - _widening(readings) < 0.005


def test_a_side_no_reading_sees_is_open_to_the_grids_edge_and_no_further():
    """The box seen from above, keeping only the zones whose footprints lie wholly on its near
    half: nothing bounds its far end, which is free to move out; past the grid's edge the map
    has no columns and took no readings, so the bound stops there, not at `interval_max_m`
    (10 cm)."""
    _, readings, edges_x, edges_y, grid = _box_scene([[0.5, 0.0, 0.45], [0.5, 0.0, 0.35]])
    near = (readings.landing[:, 0] < -0.02).reshape(readings.zones, readings.m).all(axis=1)
    readings = readings.take(near, readings.hmax)
    assert 0 < readings.zones < len(near)
    dut = _Clip(readings, edges_x, edges_y, grid, HeightMapParams())
    clip, cost = dut.search()
    _, upper = dut.interval(clip, cost, BoxFitParams(), SensorModelParams())
    out = upper[0] - (clip[1] - clip[0]) - _widening(readings)  # both ends' moves
    assert 0.1 - clip[1] <= out <= 0.1 - clip[1] + 0.01


def _object_file(tmp_path, meshes: list[trimesh.Trimesh]) -> str:
    path = tmp_path / "object.obj"
    trimesh.util.concatenate(meshes).export(path)
    return str(path)


def _shape_fit(scenario_text: str):
    frames, truth, model = render(scenario_text)
    estimator = ShapeEstimator(model, 0.0)
    for frame, X_WS in frames:
        estimator.add(frame, X_WS)
    return estimator.estimate(start_near(truth)), truth


def test_a_thin_plate_is_boxed_within_10_mm(tmp_path):
    plate = trimesh.creation.box(extents=[0.16, 0.12, 0.02])
    fit, truth = _shape_fit(f"object: {{name: {_object_file(tmp_path, [plate])}, "
                            "yaw_deg: 15}\nseed: 3")
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.010)


def test_two_blocks_3_cm_apart_are_boxed_within_10_mm(tmp_path):
    blocks = [trimesh.creation.box(extents=[0.08, 0.10, 0.06]),
              trimesh.creation.box(extents=[0.08, 0.10, 0.06])]
    blocks[0].apply_translation([-0.055, 0.0, 0.0])
    blocks[1].apply_translation([0.055, 0.0, 0.0])
    fit, truth = _shape_fit(f"object: {{name: {_object_file(tmp_path, blocks)}}}\nseed: 3")
    np.testing.assert_allclose(truth.dims, [0.19, 0.10, 0.06], atol=1e-6)
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.010)


def test_the_gripper_is_boxed_within_10_mm_where_the_box_fit_is_short():
    """The gripper's fingers are lower than its housing: the solid box fit leaves them out;
    the height map's box does not."""
    frames, truth, model = render("object: {name: gripper, yaw_deg: 20}\nseed: 3")
    estimator = ShapeEstimator(model, 0.0)
    for frame, X_WS in frames:
        estimator.add(frame, X_WS)
    fit = estimator.estimate(start_near(truth))
    assert fit.shape == "height_map"
    assert estimator.last.box.dims[0] < truth.dims[0] - 0.015  # the box fit alone
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.010)
    assert np.all(fit.dims_lower <= fit.box.dims) and np.all(fit.box.dims <= fit.dims_upper)


def test_the_outline_leaves_columns_that_explain_the_readings_as_they_are():
    """BOX's own columns, its readings predicted from them: no outline explains them better,
    so the outline neither cuts nor fills (it may only round their corners off by a cell)."""
    _, readings, edges_x, edges_y, grid = _box_scene([[0.5, 0.0, 0.45], [0.8, 0.1, 0.2],
                                                       [0.3, -0.2, 0.25]])
    params = HeightMapParams()
    fx, fy, heights, filled = _outlined(readings, edges_x, edges_y, grid, params)
    assert not filled.any()
    raised = heights > params.min_height
    ix, iy = np.flatnonzero(raised.any(axis=1)), np.flatnonzero(raised.any(axis=0))
    np.testing.assert_allclose([fx[ix[0]], fx[ix[-1] + 1], fy[iy[0]], fy[iy[-1] + 1]],
                               [-0.06, 0.06, -0.04, 0.04], atol=1e-9)


def test_the_flange_outline_fills_only_its_plate_and_boxes_it_within_10_mm():
    """The flange (a 20 mm plate Ø200 around a 50 mm hub), nine rendered views without noise:
    the 1 cm columns lose parts of the round rim; the outline's fill puts plate back only on
    the plate (no cell more than a cell off its disk, none in its bore), its box within 10 mm."""
    frames, truth, model = render("object: {name: flange, yaw_deg: 10}\n" + NOISE_FREE)
    estimator = ShapeEstimator(model, 0.0)
    for frame, X_WS in frames:
        estimator.add(frame, X_WS)
    fit = estimator.estimate(start_near(truth), interval=False)
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.010)
    shape = fit_height_map(estimator._rays, estimator.last.box, 0.0, model, interval=False,
                           screen=True)
    assert shape.filled.any()
    c, s = np.cos(shape.yaw), np.sin(shape.yaw)
    offset = truth.center[:2] - shape.origin
    centre = (c * offset[0] + s * offset[1], -s * offset[0] + c * offset[1])
    cx = (shape.edges_x[:-1] + shape.edges_x[1:]) / 2
    cy = (shape.edges_y[:-1] + shape.edges_y[1:]) / 2
    r = np.hypot(cx[:, None] - centre[0], cy[None, :] - centre[1])[shape.filled]
    reach = np.sqrt(2) * (shape.edges_x[1] - shape.edges_x[0])  # a cell's diagonal
    assert np.all(r <= 0.100 + reach) and np.all(r >= 0.04125 - reach)


def test_on_a_box_the_box_fit_stands():
    frames, truth, model = render("object: {name: horizontal_box, yaw_deg: 30}\n" + NOISE_FREE)
    estimator = ShapeEstimator(model, 0.0)
    for frame, X_WS in frames:
        estimator.add(frame, X_WS)
    fit = estimator.estimate(start_near(truth))
    assert fit.shape == "box"
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.002)


def test_no_reading_near_the_start_gives_no_height_map():
    model = SensorModelParams()
    far = OrientedBox(np.array([3.0, 3.0, 0.05]), np.array([0.1, 0.1, 0.1]), 0.0)
    rays = _rays_of(OrientedBox(np.array([0.5, 0.0, 0.05]), np.array([0.1, 0.1, 0.1]), 0.0),
                    model, [look_at([0.5, 0.0, 0.45], [0.5, 0.0, 0.05])])
    assert fit_height_map(rays, far, 0.0, model) is None
    assert reduction_rule(model, None, 64)[0] == 16  # the rule the casters share
