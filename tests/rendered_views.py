"""Readings of an object rendered by the simulated cell (Drake's renderer and the simulated
device, not an estimator's own ray caster) from nine views around it: the data the box and
height-map fits are tested on."""

import dataclasses as dc

import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.evaluation.metrics import true_box
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import SensorModelParams, ToFFrame
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.parts import sensor_params
from lrnbv_drake.station.scenario import load_scenario
from lrnbv_drake.station.sim_cell import make_sim_cell

NOISE_FREE = "device: {sigma0_mm: 0.0, noise_k: 0.0}"
OFF_MODEL = "device: {min_share: 0.4, sigma0_mm: 8.0, noise_k: 0.02, cluster_gap_mm: 30.0}"


def views(center: np.ndarray) -> list[np.ndarray]:
    """A top view and eight around the object, 25 cm out and 22 cm up, at its centre."""
    offsets = [(0.0, 0.0, 0.40)] + [(0.25 * np.cos(a), 0.25 * np.sin(a), 0.22)
                                    for a in np.deg2rad(np.arange(0, 360, 45))]
    return [look_at(np.add(center, offset), center) for offset in offsets]


def render(scenario_text: str) -> tuple[list[tuple[ToFFrame, np.ndarray]], OrientedBox,
                                         SensorModelParams]:
    """The frames (with their sensor poses) of the reachable views, the object's true box and
    the sensor model of the scenario `scenario_text`."""
    scenario = load_scenario(data=scenario_text)
    cell = make_sim_cell(scenario)
    # The views exactly as planned: the device's noise is drawn per zone in its own order, so
    # a view rolled half a turn would be another noise draw than the one the tests expect.
    motion = MotionPlanner(dc.replace(scenario, robot=dc.replace(scenario.robot,
                                                                   sensor_roll_step_deg=0.0)))
    context = cell.diagram.CreateDefaultContext()
    tof = cell.diagram.GetSubsystemByName("tof")
    truth = true_box(cell.models.placed_object.mesh.vertices, 0.0)
    frames, q = [], np.asarray(scenario.robot.initial_position)
    for i, X in enumerate(views(truth.center)):
        solutions = [s for s in motion.ik(X, q) if motion.collision_free(s)]
        if not solutions:
            continue
        cell.diagram.GetInputPort("ur5e.position").FixValue(context, solutions[0])
        frame = tof.CaptureFrame(tof.GetMyContextFromRoot(context), sequence=i + 1)
        X_WS = cell.diagram.GetOutputPort("tof.pose").Eval(context).GetAsMatrix4()
        frames.append((frame, X_WS))
    assert len(frames) >= 8, f"only {len(frames)} of the views are reachable"
    return frames, truth, sensor_params(scenario)


def start_near(truth: OrientedBox) -> OrientedBox:
    """A start like the cell box: 1.5 cm too big, off by 1 cm and 3 degrees."""
    return OrientedBox(np.add(truth.center, [0.01, -0.01, 0.0075]), truth.dims + 0.015,
                       truth.yaw + np.deg2rad(3))


