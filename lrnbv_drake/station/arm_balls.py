"""The arm's balls (core/robot/sure_collision.py) from the plant's collision geometry.

Inner balls: each cylinder, capsule, sphere and box of a body that moves with the arm gets a
row of balls along its axis, each inside the shape; shapes of other kinds (a mesh) get no ball
and are left to the exact check. Outer balls: rows of balls whose union holds each shape, and a
box around each shape of the cell. Each body is assigned the DH frame it rides on by comparing
Drake's kinematics with the analytic chain at two configurations. The pairs are those the
collision checker tests, with its padding.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, Mesh, Sphere
from pydrake.multibody.tree import BodyIndex
from pydrake.planning import SceneGraphCollisionChecker

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.robot.sure_collision import ArmBalls, arm_frames

# Two configurations with no joint at a multiple of pi/2, so no body's pose matches a frame it
# does not ride on at both.
_PROBES = (np.array([0.3, -1.1, 1.3, -0.7, 0.9, 0.4]),
           np.array([-0.8, -1.9, -1.0, 0.6, -1.4, 1.7]))
# Margin under each inner reach, metres: the analytic and Drake's kinematics agree to ~1e-15 m.
_MARGIN = 1e-6
# Margin over each outer reach, metres: also above the error of Drake's distance between two
# shapes, which an iterative solver (GJK) computes for some pairs.
_OUTER_MARGIN = 1e-4
# How far an outer ball may stand out of a round shape's side, metres: thinner is tighter but
# more balls.
OUTER_SLACK = 0.004


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


def _covering_balls(half_length: float, radius: float, axis: int, slack: float
                    ) -> list[tuple[np.ndarray, float]]:
    """Balls whose union holds the cylinder of `radius` and `half_length` along `axis`: each
    holds a slice of it, standing at most `slack` out of its side."""
    step = math.sqrt((radius + slack) ** 2 - radius ** 2)  # half a slice, at most
    count = max(1, math.ceil(half_length / step))
    a = half_length / count
    balls = []
    for t in np.linspace(a - half_length, half_length - a, count):
        centre = np.zeros(3)
        centre[axis] = t
        balls.append((centre, math.hypot(radius, a)))
    return balls


def _vertices(shape) -> np.ndarray:
    """(n, 3): the vertices of a mesh's convex hull, which Drake's distances use, in its frame."""
    hull = shape.GetConvexHull()
    return np.array([hull.vertex(i) for i in range(hull.num_vertices())])


def _outer_shape_balls(shape, slack: float) -> list[tuple[np.ndarray, float]] | None:
    """Balls whose union holds `shape`, in its own frame; None for a shape of another kind."""
    if isinstance(shape, Cylinder):
        return _covering_balls(shape.length() / 2, shape.radius(), 2, slack)
    if isinstance(shape, Capsule):  # the caps: a ball of the radius at each end
        ends = [(np.array([0.0, 0.0, z]), shape.radius()) for z in (-1, 1)]
        return _covering_balls(shape.length() / 2, shape.radius(), 2, slack) + [
            (c * shape.length() / 2, r) for c, r in ends]
    if isinstance(shape, Sphere):
        return [(np.zeros(3), shape.radius())]
    if isinstance(shape, Box):  # the cylinder round its longest axis
        half = np.array([shape.width(), shape.depth(), shape.height()]) / 2
        axis = int(np.argmax(half))
        return _covering_balls(half[axis], float(np.hypot(*np.delete(half, axis))), axis,
                               slack)
    if isinstance(shape, Convex | Mesh):
        v = _vertices(shape)
        centre = (v.min(axis=0) + v.max(axis=0)) / 2
        return [(centre, float(np.max(np.linalg.norm(v - centre, axis=1))))]
    return None


def _outer_box(shape, X_W_G: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(X_B_W, half extents): a box B holding `shape` posed at X_W_G; None for a shape of
    another kind. A mesh's box is upright, with the least footprint (`OrientedBox.from_points`;
    the objects stand on the table)."""
    if isinstance(shape, Box):
        return np.linalg.inv(X_W_G), np.array([shape.width(), shape.depth(),
                                               shape.height()]) / 2
    if isinstance(shape, Cylinder | Capsule):
        r, h = shape.radius(), shape.length() / 2
        return np.linalg.inv(X_W_G), np.array([r, r, h + (r if isinstance(shape, Capsule)
                                                          else 0.0)])
    if isinstance(shape, Sphere | Ellipsoid):
        half = np.full(3, shape.radius()) if isinstance(shape, Sphere) else \
            np.array([shape.a(), shape.b(), shape.c()])
        return np.linalg.inv(X_W_G), half
    if isinstance(shape, Convex | Mesh):
        box = OrientedBox.from_points((X_W_G[:3, :3] @ _vertices(shape).T).T + X_W_G[:3, 3])
        X_W_B = np.eye(4)
        X_W_B[:2, :2] = box.rotation_xy()
        X_W_B[:3, 3] = box.center
        return np.linalg.inv(X_W_B), box.dims / 2
    return None


def _robot_geometries(checker: SceneGraphCollisionChecker, X_W_base: np.ndarray) -> list:
    """(body, geometry, DH frame, X_frame_G 4x4, shape) of every collision geometry of the
    robot; a body that rides on no DH frame gets frame None."""
    plant = checker.plant()
    inspector = checker.model().scene_graph().model_inspector()
    robot = [plant.get_body(i) for mi in checker.robot_model_instances()
             for i in plant.GetBodyIndices(mi)]
    poses = []
    for q in _PROBES:
        probe = plant.CreateDefaultContext()
        plant.SetPositions(probe, q)  # the arm's six joints are the plant's positions
        poses.append((arm_frames(q, X_W_base),
                      {b.index(): plant.EvalBodyPoseInWorld(probe, b).GetAsMatrix4()
                       for b in robot}))
    geometries = []
    for body in robot:
        X_i_B = [np.linalg.inv(frames) @ X_W[body.index()] for frames, X_W in poses]
        frame = next((i for i in range(7)
                      if np.allclose(X_i_B[0][i], X_i_B[1][i], atol=1e-9)), None)
        for geometry in plant.GetCollisionGeometriesForBody(body):
            X_BG = inspector.GetPoseInFrame(geometry).GetAsMatrix4()
            geometries.append((body, geometry, frame,
                               None if frame is None else X_i_B[0][frame] @ X_BG,
                               inspector.GetShape(geometry)))
    return geometries


def _environment(checker: SceneGraphCollisionChecker) -> list:
    """(body, geometry, shape, X_W_G 4x4) of every collision geometry not on the robot."""
    plant = checker.plant()
    inspector = checker.model().scene_graph().model_inspector()
    query = plant.get_geometry_query_input_port().Eval(checker.plant_context())
    return [(body, geometry, inspector.GetShape(geometry),
             query.GetPoseInWorld(geometry).GetAsMatrix4())
            for body in (plant.get_body(BodyIndex(i)) for i in range(plant.num_bodies()))
            if not checker.IsPartOfRobot(body)
            for geometry in plant.GetCollisionGeometriesForBody(body)]


def _arm_balls(checker: SceneGraphCollisionChecker, balls: list, boxes: list, tested,
               margin: float) -> ArmBalls:
    """ArmBalls of `balls` (body, geometry, frame, centre, radius) and `boxes` (body,
    geometry, X_B_W, half extents), the pairs `tested`, each reach the radii, the padding and
    `margin`."""
    ball_box, ball_box_reach = [], []
    for (i, (body, geometry, _, _, radius)), (k, (env, box, _, _)) in itertools.product(
            enumerate(balls), enumerate(boxes)):
        if tested(body, geometry, env, box):
            ball_box.append((i, k))
            ball_box_reach.append(radius + checker.GetPaddingBetween(body, env) + margin)
    ball_ball, ball_ball_reach = [], []
    for (i, a), (j, b) in itertools.combinations(enumerate(balls), 2):
        if a[0].index() != b[0].index() and tested(a[0], a[1], b[0], b[1]):
            ball_ball.append((i, j))
            ball_ball_reach.append(a[4] + b[4] + checker.GetPaddingBetween(a[0], b[0])
                                   + margin)
    return ArmBalls(frame=[b[2] for b in balls],
                    centre=np.reshape([b[3] for b in balls], (-1, 3)),
                    radius=[b[4] for b in balls],
                    box_from_world=np.reshape([b[2] for b in boxes], (-1, 4, 4)),
                    box_half=np.reshape([b[3] for b in boxes], (-1, 3)),
                    ball_box=np.reshape(ball_box, (-1, 2)), ball_box_reach=ball_box_reach,
                    ball_ball=np.reshape(ball_ball, (-1, 2)),
                    ball_ball_reach=ball_ball_reach)


def build_arm_balls(checker: SceneGraphCollisionChecker, X_W_base: np.ndarray) -> ArmBalls:
    """The inner balls, boxes and pairs of `checker`'s robot and environment, `base` at
    X_W_base: a pair the checker tests (neither its body filter nor SceneGraph's)."""
    inspector = checker.model().scene_graph().model_inspector()
    balls = [(body, geometry, frame, (X_i_G @ np.append(centre, 1.0))[:3], radius)
             for body, geometry, frame, X_i_G, shape in _robot_geometries(checker, X_W_base)
             if frame is not None for centre, radius in _shape_balls(shape)]
    boxes = [(body, geometry, np.linalg.inv(X_W_G),
              np.array([shape.width(), shape.depth(), shape.height()]) / 2)
             for body, geometry, shape, X_W_G in _environment(checker)
             if isinstance(shape, Box)]

    def tested(body_a, geometry_a, body_b, geometry_b) -> bool:
        return not (checker.IsCollisionFilteredBetween(body_a, body_b)
                    or inspector.CollisionFiltered(geometry_a, geometry_b))
    return _arm_balls(checker, balls, boxes, tested, -_MARGIN)


def build_outer_balls(checker: SceneGraphCollisionChecker, X_W_base: np.ndarray,
                      slack: float = OUTER_SLACK) -> ArmBalls | None:
    """The outer balls, boxes and pairs of `checker`'s robot and environment, `base` at
    X_W_base: every pair of bodies the checker does not filter (SceneGraph's own filters may
    only spare more). None where a shape cannot be held (a body off the arm's DH chain, a
    shape of another kind): then no configuration is proved free."""
    balls, boxes, geometries = [], [], _robot_geometries(checker, X_W_base)
    for body, geometry, frame, X_i_G, shape in geometries:
        held = None if frame is None else _outer_shape_balls(shape, slack)
        if held is None:
            return None
        balls += [(body, geometry, frame, (X_i_G @ np.append(centre, 1.0))[:3], radius)
                  for centre, radius in held]
    for body, geometry, shape, X_W_G in _environment(checker):
        box = _outer_box(shape, X_W_G)
        if box is None:
            return None
        boxes.append((body, geometry, *box))
    clear = _always_clear(checker, X_W_base, geometries)

    def tested(body_a, geometry_a, body_b, geometry_b) -> bool:
        return not (checker.IsCollisionFilteredBetween(body_a, body_b)
                    or frozenset((geometry_a, geometry_b)) in clear)
    return _arm_balls(checker, balls, boxes, tested, _OUTER_MARGIN)


def _round_about_z(shape, X_i_G: np.ndarray) -> bool:
    """Whether `shape` posed at X_i_G in a DH frame is round about that frame's z axis (a
    turn about it leaves the shape where it is)."""
    on_axis = np.allclose(X_i_G[:2, 3], 0.0, atol=1e-9)
    if isinstance(shape, Sphere):
        return on_axis
    return isinstance(shape, Cylinder | Capsule) and on_axis and \
        abs(abs(X_i_G[2, 2]) - 1.0) < 1e-12


def _always_clear(checker: SceneGraphCollisionChecker, X_W_base: np.ndarray,
                  geometries: list) -> set:
    """The pairs of the robot's `geometries` (`_robot_geometries`, each on a DH frame) whose
    distance no configuration changes, and which keep clear of each other by more than their
    padding: pairs on the DH frames either side of one joint of which one is round about the
    joint's axis (the wrist's housings and the sensor's mount, coaxial with wrist 3, whose
    outer balls always overlap). Their distance is Drake's, once."""
    q = _PROBES[0]
    frames = arm_frames(q, X_W_base)
    query = checker.plant().get_geometry_query_input_port().Eval(checker.UpdatePositions(q))
    clear = set()
    for a, b in itertools.combinations(geometries, 2):
        (body_a, geometry_a, i, X_i_A, shape_a), (body_b, geometry_b, j, X_j_B, shape_b) = \
            sorted((a, b), key=lambda g: g[2])
        if j != i + 1 or checker.IsCollisionFilteredBetween(body_a, body_b):
            continue
        X_i_B = np.linalg.inv(frames[i]) @ frames[j] @ X_j_B  # joint j turns about z_i
        if not (_round_about_z(shape_a, X_i_A) or _round_about_z(shape_b, X_i_B)):
            continue
        distance = query.ComputeSignedDistancePairClosestPoints(geometry_a, geometry_b).distance
        if distance > checker.GetPaddingBetween(body_a, body_b) + _OUTER_MARGIN:
            clear.add(frozenset((geometry_a, geometry_b)))
    return clear
