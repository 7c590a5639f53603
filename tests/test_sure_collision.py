"""The balls that reject colliding configurations before SceneGraph's exact check: their
arithmetic by hand, each ball inside the arm's geometry, and never a free configuration
rejected."""

import numpy as np
import pytest

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.sure_collision import ArmBalls, arm_frames, surely_colliding
from lrnbv_drake.station.arm_balls import build_arm_balls
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
        assert surely_colliding(kinematics.HOME, np.eye(4), balls)[0] == collides


def test_two_balls_collide_exactly_when_their_centres_are_nearer_than_the_reach():
    # A ball at `tool0`'s origin and one at `base`'s: at HOME they are |p| apart, p the
    # flange's position from the forward kinematics.
    d = np.linalg.norm(kinematics.forward_kinematics(kinematics.HOME)[:3, 3])
    for reach, collides in ((d + 1e-3, True), (d - 1e-3, False)):
        balls = ArmBalls(frame=[6, 0], centre=np.zeros((2, 3)), radius=[0.0, 0.0],
                         box_from_world=np.zeros((0, 4, 4)), box_half=np.zeros((0, 3)),
                         ball_box=np.zeros((0, 2)), ball_box_reach=[],
                         ball_ball=[[0, 1]], ball_ball_reach=[reach])
        assert surely_colliding(kinematics.HOME, np.eye(4), balls)[0] == collides


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
    sure = surely_colliding(Q, planner.X_W_base, balls)
    assert not np.any(sure & free)
    assert sure.sum() >= 0.8 * (~free).sum()  # 95 % when written
    assert [planner.collision_free(q) for q in Q[:300]] == free[:300].tolist()
