"""The balls that settle configurations before SceneGraph's exact check: their arithmetic by
hand, each inner ball inside the arm's geometry and the outer balls holding it, never a free
configuration rejected and never a colliding one passed."""

import itertools

import numpy as np
import pytest
from pydrake.geometry import Convex
from pydrake.multibody.tree import BodyIndex

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.poses import look_at_batch
from lrnbv_drake.core.robot.sure_collision import (
    COLLIDES,
    FREE,
    UNSETTLED,
    ArmBalls,
    arm_frames,
    first_unrejected,
    settle,
)
from lrnbv_drake.station.arm_balls import (
    _always_clear,
    _robot_geometries,
    build_arm_balls,
    build_outer_balls,
)
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.scenario import Scenario


def _one_ball_and_a_box(centre, reach: float) -> ArmBalls:
    """A ball on `base` (the world, here) and the box |x|, |y|, |z| <= 0.1 m."""
    return ArmBalls(frame=[0], centre=[centre], radius=[0.0], box_from_world=[np.eye(4)],
                    box_half=[[0.1, 0.1, 0.1]], ball_box=[[0, 0]], ball_box_reach=[reach],
                    ball_ball=np.zeros((0, 2)), ball_ball_reach=[])


@pytest.mark.parametrize("centre, distance", [
    ([0.0, 0.0, 0.5], 0.4),      # above the top face
    ([0.4, 0.5, 0.1], 0.5),      # beyond an edge: sqrt(0.3^2 + 0.4^2)
    ([0.0, 0.02, 0.05], -0.05),  # inside, 5 cm under the top face
])
def test_a_ball_collides_with_a_box_exactly_when_its_signed_distance_is_under_the_reach(
        centre, distance):
    for reach, collides in ((distance + 1e-3, True), (distance - 1e-3, False)):
        balls = _one_ball_and_a_box(centre, reach)
        assert (settle(kinematics.HOME, np.eye(4), balls)[0] == COLLIDES) == collides


def test_two_balls_collide_exactly_when_their_centres_are_nearer_than_the_reach():
    # A ball at `tool0`'s origin and one at `base`'s: at HOME they are |p| apart, p the
    # flange's position from the forward kinematics.
    d = np.linalg.norm(kinematics.forward_kinematics(kinematics.HOME)[:3, 3])
    for reach, collides in ((d + 1e-3, True), (d - 1e-3, False)):
        balls = ArmBalls(frame=[6, 0], centre=np.zeros((2, 3)), radius=[0.0, 0.0],
                         box_from_world=np.zeros((0, 4, 4)), box_half=np.zeros((0, 3)),
                         ball_box=np.zeros((0, 2)), ball_box_reach=[],
                         ball_ball=[[0, 1]], ball_ball_reach=[reach])
        assert (settle(kinematics.HOME, np.eye(4), balls)[0] == COLLIDES) == collides


def test_the_frames_end_at_the_forward_kinematics_flange():
    q = np.array([0.3, -1.1, 1.3, -0.7, 0.9, 0.4])
    X_W_base = np.eye(4)
    X_W_base[:3, 3] = [0.1, -0.2, 0.3]
    frames = arm_frames(q, X_W_base)
    np.testing.assert_allclose(frames[0], X_W_base)
    np.testing.assert_allclose(frames[6], X_W_base @ kinematics.forward_kinematics(q),
                               atol=1e-12)


@pytest.fixture(scope="module")
def planner():
    return MotionPlanner(Scenario())


@pytest.fixture(scope="module")
def balls(planner):
    return build_arm_balls(planner._checker, planner.X_W_base)


def test_every_ball_lies_inside_the_arms_collision_geometry(planner, balls):
    checker = planner._checker
    plant = checker.plant()
    inspector = checker.model().scene_graph().model_inspector()
    rng = np.random.default_rng(3)
    assert len(balls.frame) >= 20  # every link holds some
    for q in rng.uniform(-np.pi, np.pi, (4, 6)):
        context = checker.UpdatePositions(q)
        query = plant.get_geometry_query_input_port().Eval(context)
        frames = arm_frames(q, planner.X_W_base)
        for frame, centre, radius in zip(balls.frame, balls.centre, balls.radius, strict=True):
            p = (frames[frame] @ np.append(centre, 1.0))[:3]
            depth = min(d.distance for d in query.ComputeSignedDistanceToPoint(p, 0.0)
                        if checker.IsPartOfRobot(plant.GetBodyFromFrameId(
                            inspector.GetFrameId(d.id_G))))
            assert depth <= -radius + 1e-9


def test_no_free_configuration_is_rejected_and_most_colliding_ones_are(planner, balls):
    """Against SceneGraph's exact check, on configurations drawn over the joints' range."""
    Q = np.random.default_rng(0).uniform(-np.pi, np.pi, (2000, 6))
    free = np.array([planner._checker.CheckConfigCollisionFree(q) for q in Q])
    sure = settle(Q, planner.X_W_base, balls) == COLLIDES
    assert not np.any(sure & free)
    assert sure.sum() >= 0.8 * (~free).sum()  # 95 % when written
    assert [planner.collision_free(q) for q in Q[:300]] == free[:300].tolist()


_NO_BALLS = ArmBalls(frame=np.zeros(0), centre=np.zeros((0, 3)), radius=[],
                     box_from_world=np.zeros((0, 4, 4)), box_half=np.zeros((0, 3)),
                     ball_box=np.zeros((0, 2)), ball_box_reach=[], ball_ball=np.zeros((0, 2)),
                     ball_ball_reach=[])


@pytest.mark.parametrize("centre, distance", [
    ([0.0, 0.0, 0.5], 0.4),      # above the top face
    ([0.4, 0.5, 0.1], 0.5),      # beyond an edge: sqrt(0.3^2 + 0.4^2)
])
def test_an_outer_ball_proves_free_exactly_when_its_box_lies_beyond_the_reach(centre, distance):
    for reach, settled in ((distance - 1e-3, FREE), (distance + 1e-3, UNSETTLED)):
        outer = _one_ball_and_a_box(centre, reach)
        assert settle(kinematics.HOME, np.eye(4), _NO_BALLS, outer)[0] == settled
        # Without outer balls nothing is free; the inner balls' answer comes first.
        assert settle(kinematics.HOME, np.eye(4), _NO_BALLS)[0] == UNSETTLED
        inner = _one_ball_and_a_box(centre, distance + 1e-3)
        assert settle(kinematics.HOME, np.eye(4), inner, outer)[0] == COLLIDES


def test_two_outer_balls_prove_free_exactly_when_their_centres_are_beyond_the_reach():
    d = np.linalg.norm(kinematics.forward_kinematics(kinematics.HOME)[:3, 3])
    for reach, settled in ((d - 1e-3, FREE), (d + 1e-3, UNSETTLED)):
        outer = ArmBalls(frame=[6, 0], centre=np.zeros((2, 3)), radius=[0.0, 0.0],
                         box_from_world=np.zeros((0, 4, 4)), box_half=np.zeros((0, 3)),
                         ball_box=np.zeros((0, 2)), ball_box_reach=[],
                         ball_ball=[[0, 1]], ball_ball_reach=[reach])
        assert settle(kinematics.HOME, np.eye(4), _NO_BALLS, outer)[0] == settled


def test_the_first_configuration_not_rejected_is_where_settle_first_does_not_say_collides():
    # A ball on `base` (the world here) at the origin of the box |x|, |y|, |z| <= 0.1 m, and
    # a ball on `tool0`: the first rejects every configuration; with the second's reach
    # below its distance to the box, the outer ball proves free any configuration.
    X_W_base = np.eye(4)
    inner = _one_ball_and_a_box([0.0, 0.0, 0.0], 0.05)
    Q = np.tile(kinematics.HOME, (3, 1))
    assert first_unrejected(Q, X_W_base, inner) == (3, COLLIDES)
    assert first_unrejected(Q[:0], X_W_base, inner) == (0, COLLIDES)
    far = _one_ball_and_a_box([0.0, 0.0, 0.0], -1.0)  # rejects nothing
    assert first_unrejected(Q, X_W_base, far) == (0, UNSETTLED)
    d = _box_distance_of_tool0(kinematics.HOME)
    outer = ArmBalls(frame=[6], centre=np.zeros((1, 3)), radius=[0.0],
                     box_from_world=[np.eye(4)], box_half=[[0.1, 0.1, 0.1]], ball_box=[[0, 0]],
                     ball_box_reach=[d - 1e-3], ball_ball=np.zeros((0, 2)), ball_ball_reach=[])
    assert first_unrejected(Q, X_W_base, far, outer) == (0, FREE)
    assert first_unrejected(Q, X_W_base, inner, outer) == (3, COLLIDES)  # inner first


def _box_distance_of_tool0(q) -> float:
    """The distance from `tool0`'s origin at q (`base` at the world) to the box |x|, |y|,
    |z| <= 0.1 m."""
    p = kinematics.forward_kinematics(q)[:3, 3]
    return float(np.linalg.norm(np.maximum(np.abs(p) - 0.1, 0.0)))


@pytest.fixture(scope="module")
def outer(planner):
    outer = build_outer_balls(planner._checker, planner.X_W_base)
    assert outer is not None
    return outer


def _surface(shape, rng, n: int = 400) -> np.ndarray:
    """(n, 3) points on a cylinder's surface (its rims among them), in its frame."""
    r, h = shape.radius(), shape.length() / 2
    angle = rng.uniform(0, 2 * np.pi, n)
    radius = np.where(np.arange(n) % 2 == 0, r, r * np.sqrt(rng.uniform(0, 1, n)))
    z = np.where(np.arange(n) % 2 == 0, rng.uniform(-h, h, n), rng.choice([-h, h], n))
    z[:8], radius[:8] = np.repeat([-h, h], 4), r  # the rims
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), z])


def test_the_outer_balls_hold_the_arms_collision_geometry_and_the_boxes_the_cells(planner,
                                                                                   outer):
    checker = planner._checker
    plant = checker.plant()
    inspector = checker.model().scene_graph().model_inspector()
    rng = np.random.default_rng(5)
    bodies = [plant.get_body(BodyIndex(i)) for i in range(plant.num_bodies())]
    robot = [g for b in bodies if checker.IsPartOfRobot(b)
             for g in plant.GetCollisionGeometriesForBody(b)]
    for q in rng.uniform(-np.pi, np.pi, (3, 6)):
        query = plant.get_geometry_query_input_port().Eval(checker.UpdatePositions(q))
        frames = arm_frames(q, planner.X_W_base)
        centres = np.array([(frames[f] @ np.append(c, 1.0))[:3]
                            for f, c in zip(outer.frame, outer.centre, strict=True)])
        for g in robot:  # every point of each cylinder inside some ball
            X_WG = query.GetPoseInWorld(g).GetAsMatrix4()
            points = _surface(inspector.GetShape(g), rng) @ X_WG[:3, :3].T + X_WG[:3, 3]
            gap = np.linalg.norm(points[:, None] - centres[None], axis=2) - outer.radius
            assert np.all(gap.min(axis=1) <= 1e-9), inspector.GetName(g)
    environment = [(inspector.GetShape(g), query.GetPoseInWorld(g).GetAsMatrix4())
                   for b in bodies if not checker.IsPartOfRobot(b)
                   for g in plant.GetCollisionGeometriesForBody(b)]
    assert len(environment) == len(outer.box_half) == 6  # the table's top and legs, the object
    for (shape, X_WG), X_BW, half in zip(environment, outer.box_from_world, outer.box_half,
                                         strict=True):
        if isinstance(shape, Convex):
            hull = shape.GetConvexHull()
            corners = np.array([hull.vertex(i) for i in range(hull.num_vertices())])
        else:  # a box: its corners
            corners = np.array(list(itertools.product(
                *((-e / 2, e / 2) for e in (shape.width(), shape.depth(), shape.height())))))
        p = corners @ X_WG[:3, :3].T + X_WG[:3, 3]
        assert np.all(np.abs(p @ X_BW[:3, :3].T + X_BW[:3, 3]) <= half + 1e-9)


def _views_of_the_object(planner, rng, n: int) -> np.ndarray:
    """The IK solutions of n sensor poses in the workspace looking at points around the
    object: configurations like those the planner checks, many near the table and object."""
    eyes = rng.uniform(planner.workspace[0], planner.workspace[1], (n, 3))
    targets = rng.uniform([0.35, -0.15, 0.0], [0.65, 0.15, 0.15], (n, 3))
    Q, counts = planner.ik_batch(look_at_batch(eyes, targets), kinematics.HOME)
    return np.concatenate([Q[i, :k] for i, k in enumerate(counts)])


def test_no_colliding_configuration_is_proved_free_and_most_free_ones_are(planner, outer):
    """Against SceneGraph's exact check, on configurations over the joints' range and on IK
    solutions of views of the object."""
    rng = np.random.default_rng(1)
    for Q, proved in ((rng.uniform(-np.pi, np.pi, (2000, 6)), 0.9),
                      (_views_of_the_object(planner, rng, 400), 0.9)):  # 98 and 97 % when written
        free = np.array([planner._checker.CheckConfigCollisionFree(q) for q in Q])
        settled = settle(Q, planner.X_W_base, planner._balls, outer)
        assert not np.any((settled == FREE) & ~free)
        assert not np.any((settled == COLLIDES) & free)
        assert np.sum(settled == FREE) >= proved * free.sum()
        assert [planner.collision_free(q) for q in Q[:300]] == free[:300].tolist()
        for rows in np.array_split(np.arange(len(Q)), len(Q) // 4):  # a view's solutions
            assert planner.first_free(Q[rows]) == next(
                (j for j, r in enumerate(rows) if free[r]), -1)


def test_the_pairs_left_out_keep_the_same_distance_in_every_configuration(planner):
    """The wrist's housing and the sensor's mount turn about the same axis: their outer balls
    would always overlap, so the proof leaves them out, which holds only while they keep clear
    whatever the joints."""
    checker = planner._checker
    plant = checker.plant()
    inspector = checker.model().scene_graph().model_inspector()
    clear = _always_clear(checker, planner.X_W_base,
                          _robot_geometries(checker, planner.X_W_base))
    names = {frozenset(inspector.GetName(g) for g in pair) for pair in clear}
    assert frozenset(("ur5e::wrist_3_housing", "tof_mount::mount_collision")) in names
    pairs = [tuple(pair) for pair in clear]
    padding = [checker.GetPaddingBetween(*(plant.GetBodyFromFrameId(inspector.GetFrameId(g))
                                           for g in pair)) for pair in pairs]
    distances = []
    for q in np.random.default_rng(2).uniform(-np.pi, np.pi, (50, 6)):
        query = plant.get_geometry_query_input_port().Eval(checker.UpdatePositions(q))
        distances.append([query.ComputeSignedDistancePairClosestPoints(*pair).distance
                          for pair in pairs])
    distances = np.array(distances)
    assert np.all(distances > np.array(padding))
    assert np.all(np.abs(distances - distances[0]) <= 1e-9)
