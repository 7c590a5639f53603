"""The box estimator (core/estimation/): its forward model against Drake's renderer and hand
arithmetic, and the box, structure, interval and misfit it gives on readings the simulated
cell renders (Drake's renderer and the simulated device, not the estimator's ray caster)."""

import math

import numba
import numpy as np
import pytest
import trimesh
from rendered_views import NOISE_FREE, render, start_near
from scipy.spatial.transform import Rotation

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation import forward
from lrnbv_drake.core.estimation.estimator import BoxEstimate, ShapeEstimator, misfit_limit
from lrnbv_drake.core.estimation.fit import Problem
from lrnbv_drake.core.estimation.forward import ReadingRule, ZoneRays, zone_rays
from lrnbv_drake.core.estimation.interval import intervals, profile, slice_bounds
from lrnbv_drake.core.estimation.params import EstimationParams
from lrnbv_drake.core.estimation.shape import (
    ROUNDINGS,
    TAPER,
    Shape,
    box_shape,
    moved,
    stepped,
)
from lrnbv_drake.core.sensing.sensor import SensorModelParams, ToFFrame
from lrnbv_drake.core.sensing.tof_device import DeviceBehaviour
from lrnbv_drake.station.parts import sensor_behaviour
from lrnbv_drake.station.scenario import load_scenario

MERGED = DeviceBehaviour(target_order="strongest", merge_mm=600.0)
EXTENT = np.array([-1.0, -1.0, 2.0, 1.0])
#: About a zone's footprint at the rendered views' range (5.6 degrees at 0.4 m): the
#: interval's `span`.
FOOTPRINT = 0.04


def _down(height: float) -> np.ndarray:
    """X_WS of a sensor `height` above the origin looking straight down."""
    X = np.diag([1.0, -1.0, -1.0, 1.0])
    X[2, 3] = height
    return X


def _rays(origin, directions):
    directions = np.asarray(directions, float).reshape(1, -1, 3)
    return ZoneRays(np.asarray(origin, float).reshape(1, 3), directions, np.zeros(1),
                    np.ones(1))


# --- the forward model, by hand ----------------------------------------------------------

def test_a_tube_shows_its_wall_and_the_table_through_its_hole():
    """A cylinder of radius 5 cm, 10 cm tall, minus a hole of radius 3 cm: a vertical ray
    from 50 cm up meets the top at 40 cm over the wall and the table at 50 cm in the hole,
    and the table at 50 cm beside it."""
    parts = np.array([[0, 0, 0, 0.10, 0.10, 0.10, 1, 1, 0, 0],
                      [0, 0, 0, 0.06, 0.06, 2.0, 1, 1, 0, 0]])
    down = [[0, 0, -1.0]]
    for x, expected in ((0.04, 0.40), (0.0, 0.50), (0.02, 0.50), (0.07, 0.50)):
        rays = _rays([x, 0, 0.5], down)
        base = forward.table_depths(rays.origins, rays.directions, 0.0, EXTENT)
        depth = forward.shape_depths(rays.origins, rays.directions, rays.planes, parts,
                                     np.array([True, False]), base, 0.0, forward.NO_CLIP)
        assert depth[0, 0] == pytest.approx(expected), x


def test_a_sphere_is_met_where_the_quadric_says():
    """A ball of radius 5 cm on the table (a box part rounded (1, 1, 1)): a vertical ray at
    3 cm from its axis meets it at z = 5 + 4 cm, 41 cm below a sensor at 50 cm."""
    parts = np.array([[0, 0, 0, 0.1, 0.1, 0.1, 1, 1, 1, 0]])
    rays = _rays([0.03, 0, 0.5], [[0, 0, -1.0]])
    base = forward.table_depths(rays.origins, rays.directions, 0.0, EXTENT)
    depth = forward.shape_depths(rays.origins, rays.directions, rays.planes, parts,
                                 np.array([True]), base, 0.0, forward.NO_CLIP)
    assert depth[0, 0] == pytest.approx(0.5 - 0.09)


@pytest.mark.parametrize(("rounding", "taper"), [
    ((0, 0, 0), 0.5), ((0, 0, 0), -0.4), ((1, 1, 0), 1.0), ((1, 1, 0), -0.3)])
def test_a_tapered_part_is_met_where_its_mesh_is(rounding, taper):
    """A pyramid's frustum or a cone's (a 512-gon), narrowing or widening upward, as a mesh
    cast by trimesh: every ray from above that meets one meets the other at the same depth
    (within the 512-gon's chord), bar a few grazing its edge."""
    length, width, height, yaw = 0.12, 0.08, 0.10, 0.4
    x = np.array([0.5, 0.1, yaw, length, width, height, *rounding, taper])
    scale = (1.0 - max(-taper, 0.0), 1.0 - max(taper, 0.0))  # base, top
    t = np.linspace(0, 2 * np.pi, 512, endpoint=False)
    section = (np.c_[np.cos(t), np.sin(t)] if rounding[0] else
               np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]))
    section = section * [length / 2, width / 2]
    corners = np.r_[np.c_[section * scale[0], np.zeros(len(section))],
                    np.c_[section * scale[1], np.full(len(section), height)]]
    corners[:, :2] = corners[:, :2] @ np.array([[math.cos(yaw), math.sin(yaw)],
                                                [-math.sin(yaw), math.cos(yaw)]]) + x[:2]
    mesh = trimesh.convex.convex_hull(corners)
    rng = np.random.default_rng(5)
    origins = np.c_[rng.uniform([0.3, -0.1], [0.7, 0.3], (2000, 2)), np.full(2000, 0.4)]
    targets = np.c_[rng.uniform([0.42, 0.02, 0.0], [0.58, 0.18, 0.1], (2000, 3))]
    directions = (targets - origins) / (0.4 - targets[:, 2:3])  # t: the depth below
    rays = ZoneRays(origins, directions[:, None], np.zeros(2000), np.ones(2000))
    base = np.full((2000, 1), np.inf)
    depth = forward.shape_depths(rays.origins, rays.directions, rays.planes, x[None],
                                 np.array([True]), base, 0.0, forward.NO_CLIP)[:, 0]
    hits, index, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
    truth = np.full(2000, np.inf)
    np.minimum.at(truth, index, np.einsum("ij,ij->i", hits - origins[index],
                                          directions[index]) / np.sum(directions[index] ** 2, 1))
    both = np.isfinite(depth) & np.isfinite(truth)
    assert both.sum() > 300 and np.sum(np.isfinite(depth) != np.isfinite(truth)) <= 10
    np.testing.assert_allclose(depth[both], truth[both], atol=2e-4)


def test_a_cone_stepped_once_is_a_disc_and_a_hub():
    """A tapered cylinder 20 cm across and 5 cm tall narrowing by 0.8 (a flange's shape as
    a taper draws it) stepped (`shape.stepped`): a disc of its section at 1.25 cm up,
    20 (1 - 0.2) = 16 cm across and 2.5 cm tall, and a hub of its section at 3.75 cm up,
    20 (1 - 0.6) = 8 cm across and 5 cm tall, neither tapered, both rounded. A vertical
    ray from 50 cm up meets the hub's top at 3.5 cm from the axis (45 cm), the disc's at
    6 cm (47.5 cm) and the table at 9 cm."""
    cone = Shape(np.array([[0, 0, 0, 0.2, 0.2, 0.05, 1, 1, 0, 0.8]]), (True,), (True,),
                 (True,))
    dut = stepped(cone, 0)
    assert dut.solid == (True, True) and dut.rounded == (True, True)
    assert dut.tapered == (False, False) and not np.any(dut.parts[:, TAPER])
    np.testing.assert_allclose(dut.parts[:, 3:6], [[0.16, 0.16, 0.025], [0.08, 0.08, 0.05]])
    for x, expected in ((0.035, 0.45), (0.06, 0.475), (0.09, 0.5)):
        rays = _rays([x, 0, 0.5], [[0, 0, -1.0]])
        base = forward.table_depths(rays.origins, rays.directions, 0.0, EXTENT)
        depth = forward.shape_depths(rays.origins, rays.directions, rays.planes, dut.parts,
                                     np.array(dut.solid), base, 0.0, forward.NO_CLIP)
        assert depth[0, 0] == pytest.approx(expected), x


def test_a_shape_of_parts_of_another_width_is_refused():
    """The kernels read a fixed number of values per part: a row short would be read past."""
    with pytest.raises(ValueError, match=r"Shape.parts: shape \(1, 9\), expected \(n, 10\)"):
        Shape(np.zeros((1, 9)), (False,), (True,))


@pytest.mark.parametrize(("hole_x", "length", "center_x"), [
    (-0.12, 0.22, 0.04),  # cuts the bar's end off (x < -0.07): the box ends at the hole
    (0.0, 0.30, 0.0),  # a slot across its middle: the box is the bar's
])
def test_the_box_of_a_shape_is_that_of_its_material_not_of_its_solids(hole_x, length,
                                                                      center_x):
    bar = [0.0, 0.0, 0.0, 0.30, 0.02, 0.03, 0, 0, 0, 0]  # 30 x 2 cm along x, 3 cm tall
    hole = [hole_x, 0.0, 0.0, 0.10, 0.10, 2.0, 0, 0, 0, 0]
    dut = Shape(np.array([bar, hole]), (False, False), (True, False))
    box = dut.box(0.0)
    assert box.dims == pytest.approx([length, 0.02, 0.03], abs=1e-9)
    assert box.center[:2] == pytest.approx([center_x, 0.0], abs=1e-9)


def test_a_shape_whose_holes_remove_every_solid_still_has_a_box():
    """A search may try a hole over a small solid; the box falls back to the solids'."""
    solid = [0.0, 0.0, 0.0, 0.008, 0.008, 0.01, 0, 0, 0, 0]
    hole = [0.0, 0.0, 0.0, 0.01, 0.01, 2.0, 0, 0, 0, 0]
    dut = Shape(np.array([solid, hole]), (False, False), (True, False))
    assert dut.box(0.0).dims == pytest.approx([0.008, 0.008, 0.01], abs=1e-9)


def test_a_merged_zone_reads_the_signal_weighted_mean_depth():
    """Half a zone's sub-rays on a top at 0.3 m, half on the table at 0.5 m: each returns
    1 / d^2, so the zone reads (32 / 0.3 + 32 / 0.5) / (32 / 0.09 + 32 / 0.25) = 0.3529 m;
    the nearest-cluster rule reads the top, 0.3 m."""
    depths = np.r_[np.full(32, 0.3), np.full(32, 0.5)][None]
    model = SensorModelParams()
    merged = ReadingRule.of(model, MERGED)
    nearest = ReadingRule.of(model, DeviceBehaviour())
    ones = np.ones(1)
    assert forward.zone_losses(depths, ones, ones, *merged.args(), 2.0, 5.0)[0][0] == \
        pytest.approx((32 / 0.3 + 32 / 0.5) / (32 / 0.09 + 32 / 0.25))
    assert forward.zone_losses(depths, ones, ones, *nearest.args(), 2.0, 5.0)[0][0] == \
        pytest.approx(0.3)


def test_a_zone_bundle_culls_only_boxes_none_of_its_sub_rays_meets():
    """Each zone's four bundle planes hold all its sub-rays behind them, and the cull they
    allow changes nothing: `crossing` and `shape_depths` give what casting every sub-ray
    gives (the same kernels with planes that cull nothing), over random views and parts."""
    rng = np.random.default_rng(3)
    model = SensorModelParams()
    frame = ToFFrame(np.full((8, 8), 400), np.full((8, 8), 5), np.full((8, 8), 5))
    missed = met = 0
    for _ in range(20):
        X_WS = np.eye(4)
        rpy = rng.uniform([np.pi - 0.8, -0.8, -np.pi], [np.pi + 0.8, 0.8, np.pi])
        X_WS[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
        X_WS[:3, 3] = rng.uniform([0.3, -0.2, 0.25], [0.7, 0.2, 0.5])
        rays = zone_rays(frame, X_WS, model)
        assert np.all(np.einsum("nij,nmj->nim", rays.planes, rays.directions) <= 1e-12)
        cast_all = np.zeros_like(rays.planes)
        parts = np.c_[rng.uniform([0.35, -0.15, -np.pi, 0.01, 0.01, 0.01],
                                  [0.65, 0.15, np.pi, 0.2, 0.2, 0.2], (3, 6)),
                      rng.integers(0, 2, (3, 3)), rng.uniform(-1, 1, 3)]
        parts[:, 9] *= parts[:, 8] == 0  # a tapered part has rz = 0
        solid = np.array([True, True, False])
        rows = np.arange(len(rays))
        for x in parts:
            fast = rays.crossing(x, 0.0)
            assert np.array_equal(fast, forward.crossing(rays.origins, rays.directions,
                                                         cast_all, rows, x, 0.0))
            met += int(fast.any(axis=1).sum())
            missed += int((~fast.any(axis=1)).sum())
        base = forward.table_depths(rays.origins, rays.directions, 0.0, EXTENT)
        np.testing.assert_array_equal(
            forward.shape_depths(rays.origins, rays.directions, rays.planes, parts, solid,
                                 base, 0.0, forward.NO_CLIP),
            forward.shape_depths(rays.origins, rays.directions, cast_all, parts, solid,
                                 base, 0.0, forward.NO_CLIP))
    assert met > 0 and missed > 0  # zones both sides of the cull


def test_a_sub_ray_that_sees_a_surface_before_a_region_does_not_cross_it():
    """A ray from (-0.3, 0, 0.5) along (0.35, 0, -0.4) meets a top at z = 0.1 at t = 1 and
    enters the slab 0.09 <= x <= 0.11 (0.1 tall) at t = 0.39 / 0.35 = 1.114, at z = 0.054:
    it crosses the slab, but not before a depth of 1 (the top it sees), only before 1.2."""
    rays = _rays([-0.3, 0, 0.5], [[0.35, 0, -0.4]])
    slab = np.array([0.1, 0.0, 0.0, 0.02, 0.2, 0.1, 0, 0, 0, 0])
    assert rays.crossing(slab, 0.0)[0, 0]
    assert not rays.crossing(slab, 0.0, before=np.array([[1.0]]))[0, 0]
    assert rays.crossing(slab, 0.0, before=np.array([[1.2]]))[0, 0]
    assert rays.crossing(slab, 0.0, before=np.array([[0.39 / 0.35]]))[0, 0]


def test_a_grid_costs_what_each_candidate_costs_alone_on_any_number_of_threads():
    """`Problem.trials` (one kernel call for a grid of one coordinate, re-casting only the
    sub-rays the grid can change) gives each candidate's zone losses as `evaluate` of that
    shape does, and the same bits on one thread as on every thread."""
    frames, truth, model = render("{object: {name: mug}}")
    scenario = load_scenario(data="{object: {name: mug}}")
    rays = ZoneRays.concatenate([zone_rays(f, X, model) for f, X in frames], 64)
    problem = Problem(rays, 0.0, np.array(scenario.cell.table_extent),
                      ReadingRule.of(model, sensor_behaviour(scenario)), 2.0, 5.0, 0.0005)
    body = box_shape(truth, 0.0).parts[0]
    body[6:9] = (1, 1, 0)  # an upright cylinder, and a box part beside it
    shape = Shape(np.array([body, [*truth.center[:2] + 0.05, 0.3, 0.03, 0.02, 0.05, 0, 0, 0, 0]]),
                  (True, True), (True, False))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        alone = problem.evaluate(shape)
    finally:
        numba.set_num_threads(before)
    fit = problem.evaluate(shape)
    assert np.array_equal(alone.depths, fit.depths) and np.array_equal(alone.costs, fit.costs)
    near = np.arange(len(problem))
    boxed = box_shape(truth, 0.0)
    # The cylinder narrowing upward: a side's move moves the opposite side too.
    tapered = shape.with_part(0, np.r_[body[:9], 0.4], tapered=True)
    # The last two: grids without the part as it is (a solid's candidates beyond the
    # problem's region are dropped), a box's side and top moved inward only.
    for trial, k, coordinate, grid in (
            (shape, 0, 1, 0.004 * np.arange(-3, 4)), (shape, 0, 8, 0.15 * np.arange(7)),
            (shape, 1, 4, 0.004 * np.arange(-3, 4)), (shape, 1, 5, 0.1 * np.arange(-3, 4)),
            (tapered, 0, 1, 0.004 * np.arange(-3, 4)), (tapered, 0, 9, 0.2 * np.arange(-3, 4)),
            (boxed, 0, 1, 0.004 * np.arange(-6, -2)), (boxed, 0, 4, 0.004 * np.arange(-6, -2))):
        fit = problem.evaluate(trial)
        xs = np.array([moved(trial.parts[k], coordinate, g) for g in grid])
        runs, before = [], numba.get_num_threads()
        try:
            for threads in (1, numba.config.NUMBA_NUM_THREADS):
                numba.set_num_threads(threads)
                runs.append(problem.trials(fit, k, coordinate, xs, grid[0], grid[-1], near))
        finally:
            numba.set_num_threads(before)
        (zones, losses), (zones_all, losses_all) = runs
        assert len(zones) > 0
        assert np.array_equal(zones, zones_all) and np.array_equal(losses, losses_all)
        for x, row in zip(xs, losses, strict=True):
            alone = problem.evaluate(trial.with_part(k, x)).costs
            np.testing.assert_allclose(row, alone[zones], rtol=1e-12, atol=1e-12)
            # Every zone left out keeps its loss.
            others = np.setdiff1d(near, zones)
            np.testing.assert_allclose(alone[others], fit.costs[others], rtol=1e-12, atol=1e-12)


def test_a_search_counts_its_casts_and_stops_at_its_budget():
    """A grid's casts are its moving sub-rays x candidates x parts; once a problem's casts
    reach its budget, no grid is evaluated and a refine keeps the shape it was given, while
    without a budget the same refine moves a box started 2 cm wide of the truth."""
    frames, truth, model = render("{object: {name: horizontal_box}}")
    scenario = load_scenario(data="{object: {name: horizontal_box}}")
    rays = ZoneRays.concatenate([zone_rays(f, X, model) for f, X in frames], 64)

    def problem(budget):
        return Problem(rays, 0.0, np.array(scenario.cell.table_extent),
                       ReadingRule.of(model, sensor_behaviour(scenario)), 2.0, 5.0, 0.0005,
                       budget=budget)
    wide = OrientedBox(truth.center, truth.dims + np.array([0.02, 0.02, 0.0]), truth.yaw)
    start = box_shape(wide, 0.0)
    dut = problem(math.inf)
    fit = dut.evaluate(start)
    grid = 0.004 * np.arange(-3, 4)
    xs = np.array([moved(start.parts[0], 1, g) for g in grid])
    near = np.arange(len(dut))
    moving = dut._moving(fit, 0, 1, grid[0], grid[-1], near)
    zones, _ = dut.trials(fit, 0, 1, xs, grid[0], grid[-1], near)
    assert len(zones) > 0 and dut.casts == int(moving.sum()) * len(xs) * 1
    refined = dut.refine(fit, 0.02)
    assert refined.cost < fit.cost and np.any(refined.shape.parts != start.parts)
    spent = problem(1.0)
    spent.casts = 1
    assert spent.trials(fit, 0, 1, xs, grid[0], grid[-1], near)[0].size == 0
    kept = spent.refine(spent.evaluate(start), 0.02)
    assert np.array_equal(kept.shape.parts, start.parts) and kept.cost == fit.cost


def test_the_estimate_does_not_depend_on_which_unchanged_zones_the_search_sums(monkeypatch):
    """A dumbbell's rendered views estimated twice: the line search re-casting only the
    sub-rays its grid can change, and re-casting every sub-ray of the zones near the part.
    The zones that cannot change add the same losses to every candidate, so the two searches
    must take the same candidates and end on the same box; a float sum's last bits must not
    pick among equal-cost candidates (before the least move was taken, they did: 11.9 and
    9.4 mm long)."""
    frames, truth, model = render("{object: {name: dumbbell}}")
    scenario = load_scenario(data="{object: {name: dumbbell}}")

    def estimate():
        dut = ShapeEstimator(model, sensor_behaviour(scenario), 0.0,
                             tuple(scenario.cell.table_extent), EstimationParams())
        for frame, X_WS in frames:
            dut.add(frame, X_WS)
            estimate = dut.estimate(start_near(truth))
        return estimate.box.dims

    filtered = estimate()
    crossing = ZoneRays.crossing
    monkeypatch.setattr(ZoneRays, "crossing", lambda self, x, floor, rows=None, before=None:
                        crossing(self, x, floor, rows))
    np.testing.assert_array_equal(estimate(), filtered)


def test_the_forward_model_predicts_what_drakes_renderer_and_the_device_read():
    """The true box of the horizontal box, cast by the estimator, against noise-free frames
    rendered by Drake's VTK renderer and reduced by the simulated device: half the zones
    within 0.5 mm (the device rounds to whole millimetres) and 90 % within 2 mm. The rest
    see an edge (the box's, the table's) where the renderer's pixel nearest a sub-ray lies
    up to a quarter of a sample pitch off it, so that at grazing incidence a sub-ray the
    estimator puts on the table's last 5 mm sees past it."""
    frames, truth, model = render(NOISE_FREE)
    scenario = load_scenario(data=NOISE_FREE)
    rays = ZoneRays.concatenate([zone_rays(f, X, model) for f, X in frames], 64)
    problem = Problem(rays, 0.0, np.array(scenario.cell.table_extent),
                      ReadingRule.of(model, sensor_behaviour(scenario)), 2.0, 5.0, 0.0005)
    shape = Shape(np.array([[*truth.center[:2], truth.yaw, *truth.dims, 0, 0, 0, 0]]), (False,),
                  (True,))
    predicted = problem.evaluate(shape).predicted
    errors = np.abs(predicted - rays.measured)
    assert np.median(errors) < 0.0005 and np.percentile(errors, 90) < 0.002


# --- the estimate on rendered readings ---------------------------------------------------

def _estimate(scenario_text: str) -> tuple[BoxEstimate, np.ndarray]:
    frames, truth, model = render(scenario_text)
    scenario = load_scenario(data=scenario_text)
    dut = ShapeEstimator(model, sensor_behaviour(scenario), 0.0,
                         tuple(scenario.cell.table_extent), scenario.estimation)
    start = _cell_like(truth)
    estimate = None
    for frame, X_WS in frames:
        dut.add(frame, X_WS)
        estimate = dut.estimate(start)
    return estimate, truth.dims


def _cell_like(truth: OrientedBox) -> OrientedBox:
    """A start like the cell box: larger than the object, off its centre and yaw."""
    return OrientedBox(np.add(truth.center, [0.01, -0.01, 0.01]), truth.dims + 0.03,
                       truth.yaw + math.radians(5))


# The bounds: a box's flat sides are located within half a sub-ray pitch (about 2 mm at
# these views' range); a round side is seen only at grazing incidence, within about a pitch
# on each side (5 mm across a can or a bucket, 6 mm across a ball); an L-shape's inner
# corner as a ball.
@pytest.mark.parametrize(("name", "bound_mm", "shape"), [
    ("horizontal_box", 2.0, "box"),
    ("can", 5.0, "rounded"),
    ("bucket", 5.0, "tapered"),
    ("ball", 6.0, "rounded"),
    ("l_shape", 6.0, "2 parts"),
])
def test_each_class_is_recovered_from_a_handful_of_views(name, bound_mm, shape):
    estimate, true_dims = _estimate(f"{{object: {{name: {name}}}}}")
    errors = 1000 * (estimate.box.dims - true_dims)
    assert np.all(np.abs(errors) <= bound_mm), errors
    assert estimate.shape.name().startswith(shape)


def test_a_box_is_a_box_and_its_interval_holds_it():
    estimate, true_dims = _estimate("{object: {name: horizontal_box}}")
    assert estimate.shape.name() == "box" and not estimate.misfit_flag
    assert np.all((estimate.dims_lower <= true_dims) & (true_dims <= estimate.dims_upper))
    assert estimate.misfit < misfit_limit(estimate.n_zones)


def test_a_device_the_model_does_not_explain_is_flagged_and_its_interval_widens():
    """The nearest-surface device under the merged model: the misfit flag is set, and the
    interval, scaled by the misfit, is wider than on the model's own device and holds the
    truth."""
    own, true_dims = _estimate("{object: {name: vertical_box}}")
    off, _ = _estimate("{object: {name: vertical_box}, device: {profile: nearest}}")
    assert off.misfit_flag and not own.misfit_flag
    assert np.all(off.widths > own.widths)
    assert np.all((off.dims_lower <= true_dims) & (true_dims <= off.dims_upper))


def test_the_profile_reaches_past_a_rise_the_cost_falls_back_from():
    """A staircase cost scanned every 2 mm: 10 at rest, a 6-unit spike over 3.5-5.5 mm (one
    zone flipping), back to 11 until 29.5 mm, then 20. With a rise of 5 the side reaches
    29.5 mm (the middle of a 0.5 mm bracket round it): the first rise bounds nothing, and a
    span of 25 mm past the farthest move within (28 mm) finds the same. A cost that falls to
    4 over 47.5-51.5 mm lowers the level to 9: the side reaches 51.5 mm. A rise held over
    more than the span bounds the side where it begins; a cost above the level everywhere
    leaves the first bracket's middle, 0.25 mm."""
    def staircase(v):
        return 16.0 if 0.0035 <= v < 0.0055 else 11.0 if v < 0.0295 else 20.0

    def dip_far(v):
        return 4.0 if 0.0475 <= v < 0.0515 else 11.0

    def wide_spike(v):
        return 16.0 if 0.0035 <= v < 0.0095 else 11.0

    def near(value, expected):
        return abs(value - expected) <= 0.00025 + 1e-12
    assert near(profile(staircase, 0.1, 5.0, 10.0, 0.002, math.inf), 0.0295)
    assert near(profile(staircase, 0.1, 5.0, 10.0, 0.002, 0.025), 0.0295)
    assert profile(lambda v: 10.0, 0.1, 5.0, 10.0, 0.002, math.inf) == 0.1
    assert near(profile(dip_far, 0.1, 5.0, 10.0, 0.002, math.inf), 0.0515)
    assert near(profile(wide_spike, 0.1, 5.0, 10.0, 0.002, 0.003), 0.0035)
    assert profile(wide_spike, 0.1, 5.0, 10.0, 0.002, 0.007) == 0.1
    assert near(profile(lambda v: 20.0, 0.1, 5.0, 10.0, 0.002, math.inf), 0.00025)
    with pytest.raises(ValueError, match="step > 0"):
        profile(staircase, 0.1, 5.0, 10.0, 0.0, math.inf)


@pytest.fixture(scope="module")
def can_as_box():
    """Rendered readings of a can, its fitted problem, the can fitted as a box (the class
    held) and the true box."""
    frames, truth, model = render("{object: {name: can}}")
    scenario = load_scenario(data="{object: {name: can}}")
    rays = ZoneRays.concatenate([zone_rays(f, X, model) for f, X in frames], 64)
    problem = Problem(rays, 0.0, np.array(scenario.cell.table_extent),
                      ReadingRule.of(model, sensor_behaviour(scenario)), 2.0, 5.0, 0.0005)
    as_box = problem.refine(problem.evaluate(box_shape(_cell_like(truth), 0.0)), 0.03)
    return problem, as_box, truth


def test_the_interval_holds_a_class_the_readings_fit_as_well(can_as_box):
    """The can fitted as a box: the box's own slice of the cost misses the can's size on
    every dimension, while the interval over the shapes whose cost lies within the same
    rise, the can's part re-classed among them, holds it."""
    problem, as_box, truth = can_as_box
    assert not as_box.shape.rounded[0]

    def holds(bounds):
        return (bounds[0] <= truth.dims) & (truth.dims <= bounds[1])
    assert not np.any(holds(slice_bounds(problem, as_box, 2.71, 0.1, 0.002, FOOTPRINT)))
    assert np.all(holds(intervals(problem, as_box, 2.71, 0.1, 0.002, FOOTPRINT)))


def test_the_interval_rises_from_the_lowest_cost_found(can_as_box):
    """The upright cylinder explains the can's readings better than the box fit by more than
    the rise, so the box gets no rise of its own: the interval is the cylinder's slice at the
    full rise (not at the rise plus the box's excess), with the box's own dimensions held;
    and the interval says the criterion would not keep the box, while it keeps the
    cylinder."""
    problem, as_box, _ = can_as_box
    cylinder = problem.reclassed(as_box, 0, (1.0, 1.0, 0.0), 0.01)
    others = [problem.reclassed(as_box, 0, r, 0.01) for r in ROUNDINGS]
    assert cylinder.cost == min(o.cost for o in others)
    assert cylinder.cost < as_box.cost - 2.71
    # The other classes cost more than the cylinder plus the rise: only it is held.
    assert sorted(o.cost for o in others)[1] > cylinder.cost + 2.71
    sides = 0.002 * np.array([2, 2, 1])
    dims = as_box.shape.box(0.0).dims
    low, high = slice_bounds(problem, cylinder, 2.71, 0.1, 0.002, FOOTPRINT)
    lower, upper, chosen = intervals(problem, as_box, 2.71, 0.1, 0.002, FOOTPRINT)
    np.testing.assert_array_equal(lower, np.minimum(low, dims - sides))
    np.testing.assert_array_equal(upper, np.maximum(high, dims + sides))
    # The fit's level would have let the cylinder rise by its excess too: wider.
    old_low, old_high = slice_bounds(problem, cylinder, as_box.cost + 2.71 - cylinder.cost,
                                     0.1, 0.002, FOOTPRINT)
    assert np.any(old_high - old_low > high - low + 0.001)
    # Cheaper by more than the rounding's price: the criterion would choose the cylinder.
    assert problem.score(cylinder) < problem.score(as_box)
    assert not chosen
    assert intervals(problem, cylinder, 2.71, 0.1, 0.002, FOOTPRINT)[2]
