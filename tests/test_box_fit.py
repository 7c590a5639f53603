"""The sensor-model box fit (core/box_fit.py) on readings rendered by the simulated cell: Drake's
renderer and the simulated device, not the estimator's own ray caster, make the data."""

import math

import numpy as np
import pytest
from rendered_views import NOISE_FREE, OFF_MODEL
from rendered_views import render as _render
from rendered_views import start_near as _start

from lrnbv_drake.core import box_fit
from lrnbv_drake.core.box_fit import (
    BoxEstimator,
    BoxFit,
    BoxFitParams,
    ZoneRays,
    _as_vector,
    _Edges,
    _SideSearch,
    _through,
    fit_box,
    predicted_depths,
    profile_move,
    zone_rays,
)
from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.poses import look_at
from lrnbv_drake.core.sensor import SensorModelParams, ToFFrame, nearest_cluster_depth
from lrnbv_drake.core.tof_device import DeviceBehaviour


def _fit(frames, start, model):
    estimator = BoxEstimator(model, 0.0)
    for frame, X_WS in frames:
        estimator.add(frame, X_WS)
    return estimator.estimate(start)


@pytest.mark.parametrize("obj", [
    "object: {name: horizontal_box}",
    "object: {name: horizontal_box, yaw_deg: 30}",
    "object: {name: vertical_box, yaw_deg: -20, scale: 0.8}",
])
def test_noise_free_readings_give_the_box_within_2_mm(obj):
    frames, truth, model = _render(obj + "\n" + NOISE_FREE)
    fit = _fit(frames, _start(truth), model)
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.002)
    np.testing.assert_allclose(fit.box.center[:2], truth.center[:2], atol=0.002)
    assert np.all(fit.dims_lower <= fit.box.dims) and np.all(fit.box.dims <= fit.dims_upper)


@pytest.mark.parametrize("obj", ["object: {name: horizontal_box, yaw_deg: 10}",
                                 "object: {name: vertical_box}"])
def test_a_device_off_the_model_stays_within_the_reported_interval(obj):
    frames, truth, model = _render(obj + "\n" + OFF_MODEL + "\nseed: 4")
    fit = _fit(frames, _start(truth), model)
    assert np.all(fit.dims_lower <= truth.dims), (fit.dims_lower, truth.dims)
    assert np.all(truth.dims <= fit.dims_upper), (fit.dims_upper, truth.dims)
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.010)


def test_predicted_depths_of_a_hand_worked_view():
    """Straight down from 0.5 m over a 0.1 m tall box at the origin: zones over the top read
    0.4 m, zones wholly beside it the table at 0.5 m."""
    model = SensorModelParams()
    X_WS = look_at(np.array([0.0, 0.0, 0.5]), np.zeros(3))
    frame = ToFFrame(np.full((8, 8), 1), np.full((8, 8), 5), np.zeros((8, 8)))
    rays = zone_rays(frame, X_WS, model)
    depth = predicted_depths(rays, np.array([0.0, 0.0, 0.0, 0.2, 0.2, 0.1]), 0.0, model)
    depth = depth.reshape(8, 8)
    # The box top spans +-0.1 m at 0.4 m: +-14 degrees, the middle 4 x 4 zones (+-11.25).
    np.testing.assert_allclose(depth[2:6, 2:6], 0.4)
    assert np.all(np.isclose(depth[0], 0.5)) and np.all(np.isclose(depth[:, 7], 0.5))


def test_no_reading_near_the_box_gives_no_fit():
    model = SensorModelParams()
    away = look_at(np.array([2.0, 2.0, 0.5]), np.array([2.0, 2.0, 0.0]))
    frame = ToFFrame(np.full((8, 8), 500), np.full((8, 8), 5), np.zeros((8, 8)))
    box = OrientedBox(np.array([0.0, 0.0, 0.05]), np.array([0.2, 0.1, 0.1]), 0.0)
    assert fit_box(zone_rays(frame, away, model), box, 0.0, model) is None


def _reference_depths(rays, x, floor, table):
    """(n, m) sub-ray depths on box x standing on z = floor, then the table plane z = table
    (None: no table), cast in numpy: the slab test written out independently of the kernel."""
    c, s = math.cos(x[2]), math.sin(x[2])  # as the kernel: libm, not numpy's SIMD
    px, py = rays.origins[:, None, 0] - x[0], rays.origins[:, None, 1] - x[1]
    o = np.stack(np.broadcast_arrays(c * px + s * py, -s * px + c * py,
                                     rays.origins[:, None, 2] - floor - abs(x[5]) / 2), -1)
    d = rays.directions
    d = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], -1)
    half = np.abs(x[3:]) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o) / d, (half - o) / d
        inside = np.abs(o) <= half
        near = np.where(d == 0, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(-1)
        far = np.where(d == 0, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(-1)
        t = np.where((near <= far) & (far > 0), np.maximum(near, 0.0), np.inf)
        if table is not None:
            t_table = (table - rays.origins[:, None, 2]) / d[..., 2]
            t = np.where((d[..., 2] < 0) & (t_table > 0) & (t_table < t), t_table, t)
    return t


def _reference_costs(rays, x, model, params):
    """The zone costs as numpy steps: the simulator's own cluster reduction, soft-L1."""
    if np.any(x[3:] <= 0):
        return np.full(len(rays), np.inf)
    predicted = nearest_cluster_depth(_reference_depths(rays, x, 0.0, 0.0), model)
    r = (rays.measured - predicted) / rays.sigma
    z = (np.where(np.isnan(r), params.no_return_residual, r) / params.loss_scale) ** 2
    return 2.0 * (np.sqrt(1.0 + z) - 1.0) * params.loss_scale ** 2


def test_the_cost_kernel_equals_numpy_steps_on_random_boxes():
    """The search's batched kernel (insertion sort from each zone's previous order, rotated
    sub-rays shared across a grid) against the cost computed in numpy, bit for bit: the grid
    search compares sums of piecewise-constant costs, so a last-bit change could pick another
    step. Random boxes near the truth, flat ones among them, over zone subsets."""
    model, params = SensorModelParams(), BoxFitParams()
    truth = np.array([0.01, -0.02, 0.3, 0.3, 0.2, 0.12])
    rng, rays = np.random.default_rng(0), None
    for eye in ([0.0, 0.0, 0.45], [0.3, 0.1, 0.3], [-0.2, -0.3, 0.35], [0.05, 0.35, 0.25]):
        X_WS = look_at(np.array(eye), truth[:3] * [1, 1, 0])
        frame = ToFFrame(np.full((8, 8), 1), np.full((8, 8), 5), np.zeros((8, 8)))
        depth = predicted_depths(zone_rays(frame, X_WS, model), truth, 0.0, model)
        reading = np.rint(1000 * depth + rng.normal(0, 5, 64)).reshape(8, 8)
        ok = np.isfinite(reading)
        frame = ToFFrame(np.where(ok, reading, 0), np.where(ok, 5, 255), np.zeros((8, 8)))
        more = zone_rays(frame, X_WS, model)
        rays = more if rays is None else rays.extend(more)
    start = OrientedBox(np.r_[truth[:2], 0.06], truth[3:], truth[2])
    search = _SideSearch(rays, _Edges(start), 0.0, model, params)
    for _ in range(12):
        ps = search.edges.p0 + rng.normal(0, [0.01, 0.01, 0.01, 0.01, 0.01, 0.05], (5, 6))
        ps[rng.random(5) < 0.2, 4] = -0.01  # a flat box
        ps[:3, 5] = ps[0, 5]  # a shared yaw, as in a side's grid
        zones = np.flatnonzero(rng.random(len(rays)) < 0.5)
        got = search.zone_costs(ps, zones)
        for p, row in zip(ps, got, strict=True):
            x = search.edges.to_x(p)
            np.testing.assert_array_equal(row, _reference_costs(rays, x, model, params)[zones])
            through = np.isfinite(_reference_depths(rays, x, -0.02, None)).any(-1)
            np.testing.assert_array_equal(_through(rays, x, -0.02), through)


def test_beyond_the_tables_footprint_a_sub_ray_sees_nothing():
    """The hand-worked view with the table ending at x = 0.15: the zones whose every sub-ray
    passes beyond it (the columns past x = 0.15 at 0.5 m, +16.7 degrees and more: the last
    one) report nothing; the box top still reads 0.4 m."""
    model = SensorModelParams()
    X_WS = look_at(np.array([0.0, 0.0, 0.5]), np.zeros(3))
    frame = ToFFrame(np.full((8, 8), 1), np.full((8, 8), 5), np.zeros((8, 8)))
    rays = zone_rays(frame, X_WS, model)
    x = np.array([0.0, 0.0, 0.0, 0.2, 0.2, 0.1])
    params = BoxFitParams(table_extent=(-1.0, -1.0, 0.15, 1.0))
    depth = predicted_depths(rays, x, 0.0, model, params).reshape(8, 8)
    endless = predicted_depths(rays, x, 0.0, model).reshape(8, 8)
    np.testing.assert_allclose(depth[2:6, 2:6], 0.4)
    beyond = ~np.isclose(depth, endless, equal_nan=True)
    assert beyond.any()
    # World x of the view grows along one image axis: every zone that changed is one whose
    # rays reach past x = 0.15 m, and it reports no sizeable surface.
    assert np.all(np.isnan(depth[beyond]))


def test_a_merging_model_predicts_the_signal_weighted_depth_of_a_zone():
    """With the model's merge rule (every surface of a zone within 600 mm one return at the
    signal-weighted depth, signal 1 / d^2 for one reflectance), each zone of the hand-worked
    view reads sum(1 / d) / sum(1 / d^2) over its sub-ray depths, cast independently; zones
    that see only the table read 0.5 m as before."""
    model = SensorModelParams()
    X_WS = look_at(np.array([0.0, 0.0, 0.5]), np.zeros(3))
    frame = ToFFrame(np.full((8, 8), 1), np.full((8, 8), 5), np.zeros((8, 8)))
    rays = zone_rays(frame, X_WS, model)
    x = np.array([0.0, 0.0, 0.0, 0.2, 0.2, 0.1])
    merging = BoxFitParams(behaviour=DeviceBehaviour(merge_mm=600.0, target_order="strongest"))
    depth = predicted_depths(rays, x, 0.0, model, merging)
    samples = _reference_depths(rays, x, 0.0, 0.0)
    expected = np.sum(1 / samples, axis=1) / np.sum(1 / samples**2, axis=1)
    np.testing.assert_allclose(depth, expected, rtol=1e-12)
    nearest = predicted_depths(rays, x, 0.0, model)
    straddling = (samples.min(axis=1) < 0.45) & (samples.max(axis=1) > 0.45)
    assert straddling.any() and np.all(depth[straddling] > nearest[straddling] + 1e-3)


def test_a_strongest_model_without_merging_predicts_the_surface_of_most_signal():
    """Strongest order, merge_mm 0 (a rule `lrnbv sensor characterize` can fit): each zone
    reads the signal-weighted depth of whichever of the box's top (0.4 m) and the table
    (0.5 m) returns more signal, as the device does, not the nearest cluster holding
    min_share."""
    model = SensorModelParams()
    X_WS = look_at(np.array([0.0, 0.0, 0.5]), np.zeros(3))
    frame = ToFFrame(np.full((8, 8), 1), np.full((8, 8), 5), np.zeros((8, 8)))
    rays = zone_rays(frame, X_WS, model)
    x = np.array([0.0, 0.0, 0.0, 0.2, 0.2, 0.1])
    strongest = BoxFitParams(behaviour=DeviceBehaviour(target_order="strongest"))
    depth = predicted_depths(rays, x, 0.0, model, strongest)
    samples = _reference_depths(rays, x, 0.0, 0.0)
    expected = []
    for zone in samples:
        surfaces = [zone[zone < 0.45], zone[zone >= 0.45]]
        signal = [np.sum(1 / s**2) for s in surfaces]
        s = surfaces[int(np.argmax(signal))]
        expected.append(np.sum(1 / s) / np.sum(1 / s**2))
    np.testing.assert_allclose(depth, expected, rtol=1e-12)
    nearest = predicted_depths(rays, x, 0.0, model)
    assert np.any(np.abs(depth - nearest) > 0.05)  # zones where the table outshines the top


def test_the_readings_width_is_wide_for_sides_no_view_saw_from_outside():
    """The horizontal box (length along x) from straight above only: the view's +-22.5 degrees
    end 12 cm from the centre, inside both ends, so no reading bounds the length; with all nine
    views both ends are seen beside the box and the readings pin every dimension within 1 cm."""
    frames, truth, model = _render("object: {name: horizontal_box}\n" + NOISE_FREE)
    top = [(f, X) for f, X in frames if np.allclose(X[:2, 3], truth.center[:2], atol=0.01)]
    assert len(top) == 1
    above = _fit(top, _start(truth), model)
    full = _fit(frames, _start(truth), model)
    assert above.readings_width[0] > 0.1, above.readings_width
    assert np.all(full.readings_width < 0.01), full.readings_width
    # The reported interval is the readings' part and the widening on top of it.
    assert np.all(full.dims_upper - full.dims_lower > full.readings_width)


@pytest.fixture(scope="module")
def noise_free_box():
    return _render("object: {name: horizontal_box, yaw_deg: 30}\n" + NOISE_FREE)


def test_a_start_flat_in_two_dimensions_still_finds_the_box():
    """The cell centres of one column give a start 0 x 0 in footprint: every trial one side at
    a time stayed flat (cost inf), the fit was the flat start itself, and the estimator kept
    it. A small object, as only those have one column of cells."""
    frames, truth, model = _render("object: {name: vertical_box, scale: 0.4}\n" + NOISE_FREE)
    column = OrientedBox.from_points(
        np.array([[*truth.center[:2], z] for z in np.arange(0.005, truth.dims[2], 0.01)]),
        floor_z=0.0)
    assert column.dims[0] == column.dims[1] == 0.0
    fit = _fit(frames, column, model)
    assert math.isfinite(fit.cost)
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.003)


def test_the_estimator_starts_again_when_its_estimate_is_of_something_else(noise_free_box):
    """A first cell box 16 cm off (a cluster on something else) must not hold the warm
    estimate there once the cell box is on the object."""
    frames, truth, model = noise_free_box
    estimator = BoxEstimator(model, 0.0)
    away = OrientedBox(np.add(truth.center, [0.0, 0.16, -0.03]), np.array([0.05, 0.04, 0.04]),
                       0.0)
    for i, (frame, X_WS) in enumerate(frames):
        estimator.add(frame, X_WS)
        fit = estimator.estimate(away if i == 0 else _start(truth), interval=False)
    np.testing.assert_allclose(fit.box.dims, truth.dims, atol=0.003)


def test_a_square_boxs_bounds_follow_its_axes_whichever_way_the_search_was_turned():
    """A square's canonical yaw may turn by 90 degrees without its dims swapping: the bounds
    must swap with the yaw. Views along one axis only, so the two axes' bounds differ."""
    truth = OrientedBox(np.array([0.5, 0.0, 0.05]), np.array([0.12, 0.12, 0.10]), 1.0)
    model = SensorModelParams()
    u = np.array([math.cos(1.0), math.sin(1.0)])
    along = np.array([-u[1], u[0]])
    eyes = [np.r_[truth.center[:2], 0.45]] + [np.r_[truth.center[:2] + s * 0.25 * along, 0.3]
                                              for s in (-1, 1)]
    rays = ZoneRays.empty(model.subsamples ** 2)
    for eye in eyes:
        X = look_at(eye, truth.center)
        probe = zone_rays(ToFFrame(np.full((8, 8), 300), np.full((8, 8), 5),
                                   np.zeros((8, 8))), X, model)
        depths = predicted_depths(probe, _as_vector(truth), 0.0, model)
        rays = rays.extend(ZoneRays(probe.origins, probe.directions, depths,
                                    np.full(len(depths), 0.005)).take(np.isfinite(depths)))
    # (The first start's fit came out exactly square, its yaw turned, its bounds not.)
    fits = [fit_box(rays, OrientedBox(truth.center, np.array(dims), yaw), 0.0, model)
            for dims, yaw in (([0.121, 0.120, 0.1], 1.0), ([0.125, 0.125, 0.1], truth.yaw))]
    tight = [int(np.argmin(f.readings_width[:2])) for f in fits]
    # Whatever yaw each reports, the tight bound lies along `along` in the world.
    for fit, axis in zip(fits, tight, strict=True):
        direction = np.array([math.cos(fit.box.yaw), math.sin(fit.box.yaw)])
        if axis == 1:
            direction = np.array([-direction[1], direction[0]])
        assert abs(direction @ along) > 0.9, (fit.box.yaw, fit.readings_width)


def test_a_second_start_runs_only_when_the_footprints_disagree(monkeypatch):
    """A flat object's estimate and its cell box (3 cm larger, twice as tall) overlap by 0.30
    in volume but 0.76 on the table: the same place, so one warm fit, not a second from the
    cell box at every pose; a cell box 16 cm away is another place, and gets its own fit."""
    flat = OrientedBox(np.array([0.5, 0.0, 0.01]), np.array([0.2, 0.2, 0.02]), 0.0)
    cell_box = OrientedBox(np.array([0.5, 0.0, 0.025]), np.array([0.23, 0.23, 0.05]), 0.0)
    away = OrientedBox(np.array([0.5, 0.16, 0.025]), np.array([0.05, 0.04, 0.05]), 0.0)
    assert flat.iou(cell_box) < 0.5 <= flat.footprint_iou(cell_box)
    starts = []

    def fit(rays, start, *args, **kwargs):
        starts.append(start)
        return BoxFit(start, start.dims, start.dims, 1.0, 10, 1)
    monkeypatch.setattr(box_fit, "fit_box", fit)
    estimator = BoxEstimator(SensorModelParams(), 0.0)
    for start, fits in ((cell_box, 1), (away, 2)):
        estimator.last = BoxFit(flat, flat.dims, flat.dims, 1.0, 10, 1)
        starts.clear()
        estimator.estimate(start, interval=False)
        assert len(starts) == fits


def test_a_profile_is_bounded_from_the_lowest_cost_it_meets():
    """A cost that falls by 10 over the first 4 mm of the move and then rises 2500 a metre:
    the move ends where it is `rise` above that low, 4 + 2.71 / 2500 m = 5.08 mm (to the
    bisection's 0.5 mm), not where it is `rise` above the start (9.08 mm)."""
    def cost(q):
        return 2500.0 * abs(q[0] - 0.004) - 10.0

    dut = profile_move(cost, np.zeros(1), 0, 1, 0.0, 2.71, BoxFitParams())
    assert dut == pytest.approx(0.004 + 2.71 / 2500.0, abs=0.0005)


def test_a_profile_that_never_rises_stops_at_its_limit():
    params = BoxFitParams()
    flat = lambda q: 1.0  # noqa: E731
    assert profile_move(flat, np.zeros(1), 0, -1, 1.0, 2.71, params) == params.interval_max_m
    assert profile_move(flat, np.zeros(1), 0, -1, 1.0, 2.71, params, limit=0.03) == 0.03
    assert profile_move(flat, np.zeros(1), 0, -1, 1.0, 2.71, params, limit=0.0) == 0.0
    assert profile_move(flat, np.zeros(1), 0, -1, 1.0, 2.71, params, limit=-0.01) == 0.0
