"""HEU baseline: 13 evenly spaced poses on an ellipse, each looking at the object."""

import numpy as np
import pytest

from lrnbv_drake.core.acquisition import Acquisition
from lrnbv_drake.core.planning.config import HeuParams
from lrnbv_drake.core.planning.heu import HeuPolicy, heu_poses
from lrnbv_drake.core.planning.policy import CANDIDATE_RANK, Observation
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.station.cell_models import place_object
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.parts import make_policy
from lrnbv_drake.station.scenario import load_scenario


def test_look_at_points_the_optical_axis_at_the_target():
    X = look_at([1.0, 2.0, 3.0], [1.0, 2.0, 0.0])
    np.testing.assert_allclose(X[:3, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(X[:3, :3].T @ X[:3, :3], np.eye(3), atol=1e-12)
    assert np.linalg.det(X[:3, :3]) == pytest.approx(1.0)
    X = look_at([0.0, 0.0, 1.0], [1.0, 0.0, 1.0])
    np.testing.assert_allclose(X[:3, 1], [0, 0, -1], atol=1e-12)  # image y points down
    # Along `up` itself, even when up is y: still a rotation, still aimed at the target.
    for up in ([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]):
        X = look_at([0.0, 0.0, 0.0], up, up=up)
        np.testing.assert_allclose(X[:3, 2], up, atol=1e-12)
        np.testing.assert_allclose(X[:3, :3].T @ X[:3, :3], np.eye(3), atol=1e-12)
        assert np.linalg.det(X[:3, :3]) == pytest.approx(1.0)


def test_poses_lie_on_the_ellipse_evenly_spaced_and_look_at_the_target():
    target = np.array([0.5, 0.1, 0.06])
    params = HeuParams(semi_axis_x=0.2, semi_axis_y=0.3, height=0.25)
    poses = heu_poses(target, params)
    assert len(poses) == 13
    p = np.array([X[:3, 3] for X in poses]) - target
    np.testing.assert_allclose(p[:, 2], 0.25)
    np.testing.assert_allclose((p[:, 0] / 0.2) ** 2 + (p[:, 1] / 0.3) ** 2, 1.0)
    angles = np.unwrap(np.arctan2(p[:, 1] / 0.3, p[:, 0] / 0.2))
    np.testing.assert_allclose(np.diff(angles), 2 * np.pi / 13)
    for X in poses:
        to_target = (target - X[:3, 3]) / np.linalg.norm(target - X[:3, 3])
        np.testing.assert_allclose(X[:3, 2], to_target, atol=1e-12)


def test_policy_skips_what_the_loop_could_not_reach_and_ends():
    dut = HeuPolicy(np.zeros(3))
    obs = Observation(time=0.0, q=np.zeros(6), X_WS=np.eye(4))
    first = dut.propose(obs)
    assert len(first.candidates) == 13 and not first.done
    dut.accepted(2, obs)  # poses 0 and 1 were unreachable
    second = dut.propose(obs)
    assert len(second.candidates) == 10
    np.testing.assert_array_equal(second.candidates[0], dut.poses[3])
    dut.accepted(9, obs)
    assert dut.propose(obs).done


def test_restore_goes_on_where_the_run_was():
    """A run that skipped poses 0 and 1 and then visited 2 and 3, restored from what it
    logged: the next proposal is the same."""
    run = HeuPolicy(np.zeros(3))
    obs = Observation(time=0.0, q=np.zeros(6), X_WS=np.eye(4))
    recorded = []
    for rank in (2, 0):
        proposal = run.propose(obs)
        run.accepted(rank, obs)
        recorded.append(Acquisition(
            index=len(recorded), time=0.0, q=np.zeros(6), X_WS=proposal.candidates[rank],
            frame=ToFFrame.empty(), info={**proposal.candidate_info[rank], CANDIDATE_RANK: rank}))
    assert [a.info["ellipse_index"] for a in recorded] == [2, 3]
    restored = HeuPolicy(np.zeros(3))
    restored.restore(recorded)
    expected, proposal = run.propose(obs), restored.propose(obs)
    assert len(proposal.candidates) == len(expected.candidates) == 9
    np.testing.assert_array_equal(proposal.candidates, expected.candidates)
    assert proposal.candidate_info == expected.candidate_info


def test_the_scenario_sets_the_ellipse_the_episode_visits():
    scenario = load_scenario(data="heu: {n_poses: 7, height: 0.12, semi_axis_x: 0.3}")
    placed = place_object(scenario)
    dut = make_policy("heu", scenario, MotionPlanner(scenario), placed)
    p = np.array([X[:3, 3] for X in dut.poses]) - placed.mesh.bounds.mean(axis=0)
    assert len(p) == 7
    np.testing.assert_allclose(p[:, 2], 0.12)
    np.testing.assert_allclose(p[0, :2], [-0.3, 0.0], atol=1e-12)  # start_angle pi: -x
