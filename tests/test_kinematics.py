"""UR5e kinematics against hand-worked poses, its own inverse, and Drake's MultibodyPlant."""

from __future__ import annotations

import importlib.util
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.core.robot import kinematics as kin
from lrnbv_drake.station.resources import MODELS_DIR, make_parser, package_url


def _random_q(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(kin.JOINT_LOWER, kin.JOINT_UPPER, (n, 6))


def _pose_errors(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error (m) and rotation error (rad, small-angle) between transforms."""
    pos = np.linalg.norm(A[..., :3, 3] - B[..., :3, 3], axis=-1)
    rot = np.linalg.norm(A[..., :3, :3] - B[..., :3, :3], axis=(-2, -1)) / np.sqrt(2)
    return pos, rot


@pytest.fixture(scope="module")
def station():
    """(plant, scene_graph, diagram, context) with the UR5e's base_link welded to the world."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    make_parser(plant).AddModels(url=package_url("ur5e/ur5e.urdf"))
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base_link"))
    plant.Finalize()
    diagram = builder.Build()
    return plant, scene_graph, diagram, diagram.CreateDefaultContext()


def test_forward_kinematics_hand_worked():
    # Zero: arm stretched along -x of `base`, joint offsets and tool axis along -y.
    X0 = kin.forward_kinematics(np.zeros(6))
    np.testing.assert_allclose(X0[:3, 3], [-0.425 - 0.3922, -0.1333 - 0.0996, 0.1625 - 0.0997],
                               atol=1e-15)
    np.testing.assert_allclose(X0[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)
    # Home: upper arm up, forearm back along -x, tool pointing down.
    Xh = kin.forward_kinematics(kin.HOME)
    np.testing.assert_allclose(Xh[:3, 3], [-0.3922 - 0.0997, -0.1333, 0.1625 + 0.425 - 0.0996],
                               atol=1e-15)
    np.testing.assert_allclose(Xh[:3, :3], [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-15)
    assert kin.forward_kinematics(np.zeros((3, 2, 6))).shape == (3, 2, 4, 4)


def test_ik_round_trip():
    q = _random_q(250, seed=0)
    X = kin.forward_kinematics(q)
    Q, ok = kin.inverse_kinematics(X.reshape(5, 50, 4, 4))
    assert Q.shape == (5, 50, 8, 6) and ok.shape == (5, 50, 8)
    Q, ok = Q.reshape(250, 8, 6), ok.reshape(250, 8)

    pos, rot = _pose_errors(kin.forward_kinematics(Q), X[:, None])
    assert ok.sum() > 250
    assert pos[ok].max() < 1e-9 and rot[ok].max() < 1e-9
    assert np.all(np.abs(Q) <= np.pi)

    # The configuration the target came from is one of the solutions, modulo 2 pi.
    gap = np.abs(kin.wrap_to_pi(Q - q[:, None])).max(axis=-1)
    assert np.where(ok, gap, np.inf).min(axis=1).max() < 1e-8

    # ...and with +-2 pi equivalents taken into account it is exactly the closest one.
    q_best, found = kin.closest_solution(Q, ok, q)
    assert found.all()
    np.testing.assert_allclose(q_best, q, atol=1e-8)


def test_forward_kinematics_matches_drake(station):
    plant, _, _, context = station
    plant_context = plant.GetMyContextFromRoot(context)
    names = [plant.get_joint(i).name() for i in plant.GetJointIndices()
             if plant.get_joint(i).num_positions() == 1]
    assert tuple(names) == kin.JOINT_NAMES
    base, tool0 = plant.GetFrameByName("base"), plant.GetFrameByName("tool0")
    for q in _random_q(100, seed=1):
        plant.SetPositions(plant_context, q)
        X_drake = plant.CalcRelativeTransform(plant_context, base, tool0).GetAsMatrix4()
        pos, rot = _pose_errors(kin.forward_kinematics(q), X_drake)
        assert pos < 1e-9 and rot < 1e-9


def test_frames_match_ros(station):
    plant, _, _, context = station
    plant_context = plant.GetMyContextFromRoot(context)
    plant.SetPositions(plant_context, _random_q(1, seed=2)[0])

    def X(a: str, b: str) -> np.ndarray:
        frame_a, frame_b = plant.GetFrameByName(a), plant.GetFrameByName(b)
        return plant.CalcRelativeTransform(plant_context, frame_a, frame_b).GetAsMatrix4()

    Rz_pi = np.diag([-1.0, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(X("base_link", "base"), Rz_pi, atol=1e-15)
    np.testing.assert_allclose(X("wrist_3_link", "tool0"), np.eye(4), atol=1e-15)
    # flange has ROS-Industrial axes: x along tool0's z (out of the flange), y along tool0's x.
    np.testing.assert_allclose(X("tool0", "flange")[:3, :3], [[0, 1, 0], [0, 0, 1], [1, 0, 0]],
                               atol=1e-15)


def test_unreachable_targets_are_not_ok_and_quiet():
    far = np.eye(4)
    far[:3, 3] = [2.0, 0.0, 0.5]
    # Wrist centre on joint 1's axis (closer than d4): the shoulder cannot reach it.
    inside = np.diag([1.0, -1.0, -1.0, 1.0])
    inside[:3, 3] = [0.0, 0.0, 0.3]
    nan = np.full((4, 4), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Q, ok = kin.inverse_kinematics(np.stack([far, inside, nan]))
        q, found = kin.closest_solution(Q, ok, kin.HOME)
    assert not ok.any() and not found.any()
    assert np.all(Q == 0.0)
    np.testing.assert_array_equal(q, np.broadcast_to(kin.HOME, (3, 6)))


def test_wrist_singularity_uses_given_q6():
    q = np.array([0.4, -1.1, 1.3, -0.7, 0.0, 0.9])
    X = kin.forward_kinematics(q)
    Q, ok = kin.inverse_kinematics(X, q6_singular=-0.25)
    assert ok.any()
    pos, rot = _pose_errors(kin.forward_kinematics(Q[ok]), X)
    assert pos.max() < 1e-9 and rot.max() < 1e-9
    singular = ok & (np.abs(np.sin(Q[:, 4])) < 1e-9)
    assert singular.any()
    np.testing.assert_allclose(Q[singular, 5], -0.25)


def test_closest_solution_constructed():
    Q = np.zeros((8, 6))
    ok = np.zeros(8, dtype=bool)
    Q[0], ok[0] = kin.HOME, True
    Q[1], ok[1] = [1.0, -2.0, -1.5, 0.5, 1.5, 0.0], True
    Q[2] = [1.0, -2.0, -1.4, 0.5, 1.5, 0.0]  # nearest of all, but not a solution
    q_current = np.array([1.0, -2.0, -1.4, 0.5, 1.5, 0.1])
    q, found = kin.closest_solution(Q, ok, q_current)
    assert found
    np.testing.assert_array_equal(q, Q[1])

    # Shoulder pan (+-2 pi) takes the short way round; the elbow (+-pi) cannot.
    ok[0] = False
    Q[1, :3] = [-3.0, -2.0, -3.0]
    q_current[:3] = [3.1, -2.0, 3.1]
    q, found = kin.closest_solution(Q, ok, q_current)
    assert found
    np.testing.assert_allclose(q[:3], [-3.0 + 2 * np.pi, -2.0, -3.0])
    np.testing.assert_allclose(kin.nearest_equivalents(Q[1:2], q_current), q[None])

    q, found = kin.closest_solution(Q, np.zeros(8, dtype=bool), q_current)
    assert not found
    np.testing.assert_array_equal(q, q_current)


def test_ranked_solutions_constructed():
    """Solutions at their nearest equivalents, the valid ones by the slowest joint's time,
    ties in their order; an invalid one last whatever its time."""
    q_current = np.array([3.1, -2.0, 0.0, 0.0, 0.0, 0.0])
    Q = np.zeros((1, 4, 6))
    Q[0, :, 1] = -2.0
    Q[0, 0, 0] = -3.0  # 0.1832 rad away the short way round (+2 pi): 0.0583 s at pi rad/s
    Q[0, 1, 5] = 0.3   # 0.3 rad: 0.0955 s
    Q[0, 2, 0] = 3.0   # 0.1 rad, but not a solution
    Q[0, 3, 5] = -0.3  # ties with the second
    ok = np.array([[True, True, False, True]])
    ranked, n = kin.ranked_solutions(Q, ok, q_current, np.full(6, np.pi))
    assert n.tolist() == [3]
    np.testing.assert_allclose(ranked[0, 0, 0], -3.0 + 2 * np.pi)
    np.testing.assert_array_equal(ranked[0, 1:, 5], [0.3, -0.3, 0.0])
    np.testing.assert_array_equal(ranked[0, 3, 0], 3.0)


def test_ranked_solutions_are_numpys_bit_for_bit():
    """The kernel against what the planner did in numpy: the same bits, every pose."""
    rng = np.random.default_rng(4)
    velocity = np.array([1.0, 1.0, 1.5, 2.0, 2.0, 2.0]) * np.pi
    for trial in range(100):
        X = kin.forward_kinematics(rng.uniform(-np.pi, np.pi, (int(rng.integers(1, 40)), 6)))
        X[::3, :3, 3] *= 1.5  # some out of reach
        Q, ok = kin.inverse_kinematics(X)
        q_current = rng.uniform(-2 * np.pi, 2 * np.pi, 6)
        if trial % 4 == 0:  # ties, and joints a multiple of pi away
            Q[:, 4:] = Q[:, :4]
            q_current = np.round(q_current / np.pi) * np.pi
        near = kin.nearest_equivalents(Q, q_current)
        cost = np.where(ok, np.max(np.abs(near - q_current) / velocity, axis=-1), np.inf)
        order = np.argsort(cost, axis=1, kind="stable")
        ranked, n = kin.ranked_solutions(Q, ok, q_current, velocity)
        assert ranked.tobytes() == near[np.arange(len(Q))[:, None], order].tobytes()
        np.testing.assert_array_equal(n, ok.sum(axis=1))


def test_urdf_limits_match_constants(station):
    plant = station[0]
    np.testing.assert_array_equal(plant.GetPositionLowerLimits(), kin.JOINT_LOWER)
    np.testing.assert_array_equal(plant.GetPositionUpperLimits(), kin.JOINT_UPPER)
    np.testing.assert_array_equal(plant.GetVelocityUpperLimits(), kin.VELOCITY_LIMIT)
    np.testing.assert_array_equal(plant.GetVelocityLowerLimits(), -kin.VELOCITY_LIMIT)
    np.testing.assert_array_equal(plant.GetAccelerationUpperLimits(), kin.ACCELERATION_LIMIT)
    np.testing.assert_array_equal(plant.GetEffortUpperLimits(), kin.EFFORT_LIMIT)
    assert plant.num_actuators() == 6
    assert plant.CalcTotalMass(plant.CreateDefaultContext()) == pytest.approx(21.7)


def test_self_collision(station):
    plant, scene_graph, _, context = station
    plant_context = plant.GetMyContextFromRoot(context)
    query_port = scene_graph.get_query_output_port()

    def collides(q: np.ndarray) -> bool:
        plant.SetPositions(plant_context, q)
        return query_port.Eval(scene_graph.GetMyContextFromRoot(context)).HasCollisions()

    assert not collides(kin.HOME)
    assert not collides(np.zeros(6))
    # Elbow folded flat: the wrist lands on the shoulder (why ROS stops the elbow at +-pi).
    assert collides(np.array([0.0, 0.0, np.pi, 0.0, 0.0, 0.0]))


def test_shipped_urdf_is_generated(monkeypatch):
    path = MODELS_DIR / "ur5e" / "make_urdf.py"
    spec = importlib.util.spec_from_file_location("make_urdf", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "make_urdf", module)  # dataclasses look themselves up here
    spec.loader.exec_module(module)
    assert Path(MODELS_DIR / "ur5e" / "ur5e.urdf").read_text() == module.make_urdf()
