"""The arm's balls (core/robot/sure_collision.py) from the plant's collision geometry.

Each cylinder, capsule, sphere and box of a body that moves with the arm gets a row of balls
along its axis, each inside the shape; each body is assigned the DH frame it rides on by
comparing Drake's kinematics with the analytic chain at two configurations. The pairs are
those the collision checker tests, with its padding; shapes of other kinds (a mesh) get no
ball and are left to the exact check.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from pydrake.geometry import Box, Capsule, Cylinder, Sphere
from pydrake.multibody.tree import BodyIndex
from pydrake.planning import SceneGraphCollisionChecker

from lrnbv_drake.core.robot.sure_collision import ArmBalls, arm_frames

# Two configurations with no joint at a multiple of pi/2, so no body's pose matches a frame it
# does not ride on at both.
_PROBES = (np.array([0.3, -1.1, 1.3, -0.7, 0.9, 0.4]),
           np.array([-0.8, -1.9, -1.0, 0.6, -1.4, 1.7]))
# Margin under each reach, metres: the analytic and Drake's kinematics agree to ~1e-15 m.
_MARGIN = 1e-6


def _axis_balls(half_length: float, radius: float, axis: int) -> list[tuple[np.ndarray, float]]:
    """Balls of radius min(radius, half_length) inside a round shape along `axis` (0, 1, 2) of
    its frame, spaced by at most their radius, the two end balls touching its ends."""
    rho = min(radius, half_length)
    reach = half_length - rho
    count = math.ceil(2 * reach / rho) + 1 if reach > 0 else 1
    balls = []
    for t in np.linspace(-reach, reach, count):
        centre = np.zeros(3)
        centre[axis] = t
        balls.append((centre, rho))
    return balls


def _shape_balls(shape) -> list[tuple[np.ndarray, float]]:
    """Balls inside `shape`, in its own frame."""
    if isinstance(shape, Cylinder):
        return _axis_balls(shape.length() / 2, shape.radius(), 2)
    if isinstance(shape, Capsule):  # the hemispherical caps hold balls of the full radius
        return [(c, shape.radius()) for c, _ in
                _axis_balls(shape.length() / 2 + shape.radius(), shape.radius(), 2)]
    if isinstance(shape, Sphere):
        return [(np.zeros(3), shape.radius())]
    if isinstance(shape, Box):
        half = np.array([shape.width(), shape.depth(), shape.height()]) / 2
        axis = int(np.argmax(half))
        return _axis_balls(half[axis], float(np.min(half)), axis)
    return []


def build_arm_balls(checker: SceneGraphCollisionChecker, X_W_base: np.ndarray) -> ArmBalls:
    """The balls, boxes and pairs of `checker`'s robot and environment, `base` at X_W_base."""
    plant = checker.plant()
    context = checker.plant_context()
    inspector = checker.model().scene_graph().model_inspector()
    query = plant.get_geometry_query_input_port().Eval(context)
    robot = [plant.get_body(i) for mi in checker.robot_model_instances()
             for i in plant.GetBodyIndices(mi)]
    robot_ids = {int(b.index()) for b in robot}
    environment = [plant.get_body(BodyIndex(i)) for i in range(plant.num_bodies())
                   if i not in robot_ids]

    # Which DH frame each robot body rides on.
    poses = []
    for q in _PROBES:
        probe = plant.CreateDefaultContext()
        plant.SetPositions(probe, q)  # the arm's six joints are the plant's positions
        poses.append((arm_frames(q, X_W_base),
                      {b.index(): plant.EvalBodyPoseInWorld(probe, b).GetAsMatrix4()
                       for b in robot}))
    balls = []  # (body, geometry, frame, centre in that frame, radius)
    for body in robot:
        X_i_B = [np.linalg.inv(frames) @ X_W[body.index()] for frames, X_W in poses]
        frame = next((i for i in range(7)
                      if np.allclose(X_i_B[0][i], X_i_B[1][i], atol=1e-9)), None)
        if frame is None:
            continue
        for geometry in plant.GetCollisionGeometriesForBody(body):
            X_BG = inspector.GetPoseInFrame(geometry).GetAsMatrix4()
            for centre, radius in _shape_balls(inspector.GetShape(geometry)):
                c = (X_i_B[0][frame] @ X_BG @ np.append(centre, 1.0))[:3]
                balls.append((body, geometry, frame, c, radius))

    boxes = []  # (body, geometry, X_G_W, half extents)
    for body in environment:
        for geometry in plant.GetCollisionGeometriesForBody(body):
            shape = inspector.GetShape(geometry)
            if isinstance(shape, Box):
                X_W_G = query.GetPoseInWorld(geometry).GetAsMatrix4()
                boxes.append((body, geometry, np.linalg.inv(X_W_G),
                              np.array([shape.width(), shape.depth(), shape.height()]) / 2))

    def tested(body_a, geometry_a, body_b, geometry_b) -> bool:
        return not (checker.IsCollisionFilteredBetween(body_a, body_b)
                    or inspector.CollisionFiltered(geometry_a, geometry_b))

    ball_box, ball_box_reach = [], []
    for (i, (body, geometry, _, _, radius)), (k, (env, box, _, _)) in itertools.product(
            enumerate(balls), enumerate(boxes)):
        if tested(body, geometry, env, box):
            ball_box.append((i, k))
            ball_box_reach.append(radius + checker.GetPaddingBetween(body, env) - _MARGIN)
    ball_ball, ball_ball_reach = [], []
    for (i, a), (j, b) in itertools.combinations(enumerate(balls), 2):
        if a[0].index() != b[0].index() and tested(a[0], a[1], b[0], b[1]):
            ball_ball.append((i, j))
            ball_ball_reach.append(a[4] + b[4] + checker.GetPaddingBetween(a[0], b[0])
                                   - _MARGIN)
    return ArmBalls(frame=[b[2] for b in balls],
                    centre=np.reshape([b[3] for b in balls], (-1, 3)),
                    radius=[b[4] for b in balls],
                    box_from_world=np.reshape([b[2] for b in boxes], (-1, 4, 4)),
                    box_half=np.reshape([b[3] for b in boxes], (-1, 3)),
                    ball_box=np.reshape(ball_box, (-1, 2)), ball_box_reach=ball_box_reach,
                    ball_ball=np.reshape(ball_ball, (-1, 2)),
                    ball_ball_reach=ball_ball_reach)
