"""The sensor-model box fit (core/box_fit.py) on readings rendered by the simulated cell: Drake's
renderer and the simulated device, not the estimator's own ray caster, make the data."""

import numpy as np
import pytest

from lrnbv_drake.core.box_fit import BoxEstimator, fit_box, predicted_depths, zone_rays
from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.metrics import true_box
from lrnbv_drake.core.poses import look_at
from lrnbv_drake.core.sensor import SensorModelParams, ToFFrame
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.parts import sensor_params
from lrnbv_drake.station.scenario import load_scenario
from lrnbv_drake.station.sim_cell import make_sim_cell

NOISE_FREE = "device: {sigma0_mm: 0.0, noise_k: 0.0}"
OFF_MODEL = "device: {min_share: 0.4, sigma0_mm: 8.0, noise_k: 0.02, cluster_gap_mm: 30.0}"


def _views(center: np.ndarray) -> list[np.ndarray]:
    """A top view and eight around the object, 25 cm out and 22 cm up, at its centre."""
    offsets = [(0.0, 0.0, 0.40)] + [(0.25 * np.cos(a), 0.25 * np.sin(a), 0.22)
                                    for a in np.deg2rad(np.arange(0, 360, 45))]
    return [look_at(np.add(center, offset), center) for offset in offsets]


def _render(scenario_text: str) -> tuple[list[tuple[ToFFrame, np.ndarray]], OrientedBox,
                                         SensorModelParams]:
    scenario = load_scenario(data=scenario_text)
    cell = make_sim_cell(scenario)
    motion = MotionPlanner(scenario)
    context = cell.diagram.CreateDefaultContext()
    tof = cell.diagram.GetSubsystemByName("tof")
    truth = true_box(cell.models.placed_object.mesh.vertices, 0.0)
    frames, q = [], np.asarray(scenario.robot.initial_position)
    for i, X in enumerate(_views(truth.center)):
        solutions = [s for s in motion.ik(X, q) if motion.collision_free(s)]
        if not solutions:
            continue
        cell.diagram.GetInputPort("ur5e.position").FixValue(context, solutions[0])
        frame = tof.CaptureFrame(tof.GetMyContextFromRoot(context), sequence=i + 1)
        X_WS = cell.diagram.GetOutputPort("tof.pose").Eval(context).GetAsMatrix4()
        frames.append((frame, X_WS))
    assert len(frames) >= 8, f"only {len(frames)} of the views are reachable"
    return frames, truth, sensor_params(scenario)


def _start(truth: OrientedBox) -> OrientedBox:
    """A start like the cell box: 1.5 cm too big, off by 1 cm and 3 degrees."""
    return OrientedBox(np.add(truth.center, [0.01, -0.01, 0.0075]), truth.dims + 0.015,
                       truth.yaw + np.deg2rad(3))


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
