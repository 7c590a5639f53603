"""AcquisitionLoop alone: fixed inputs, a scripted policy and a straight-line motion stand-in."""

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from lrnbv_drake.core.acquisition import HOLD_TOLERANCE, Acquisition, EpisodeLog
from lrnbv_drake.core.planning.policy import Proposal, ViewpointPolicy
from lrnbv_drake.core.robot.motion import MotionFailure, MotionPlan
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.station.motion import trapezoidal_trajectory
from lrnbv_drake.systems.acquisition_loop import AcquisitionLoop

PERIOD = 0.05


class StraightLine:
    """Motion stand-in: the 'joint target' is the pose's translation padded to 6; a target with
    x < 0 is unreachable."""

    def plan(self, q_current, X_WS, start_time=0.0):
        q = np.r_[X_WS[:3, 3], 0.0, 0.0, 0.0]
        if q[0] < 0:
            return MotionPlan(MotionFailure.UNREACHABLE, "x < 0")
        traj = trapezoidal_trajectory(np.array([q_current, q]), np.ones(6), np.ones(6),
                                      start_time)
        return MotionPlan(None, "ok", q_target=q, trajectory=traj)


class Scripted(ViewpointPolicy):
    name = "scripted"

    def __init__(self, targets, capture_initial=False):
        self.targets = targets
        self.capture_initial = capture_initial
        self.accepted_indices = []

    def propose(self, observation):
        if not self.targets:
            return Proposal(done=True, reason="script finished")
        return Proposal(candidates=self.targets)

    def accepted(self, index, observation):
        self.accepted_indices.append(index)
        self.targets = self.targets[index + 1:]


def _pose(x, y, z):
    X = np.eye(4)
    X[:3, 3] = (x, y, z)
    return X


def _make(targets, capture_initial=False, q_measured=None, **kwargs):
    """The planner holds q = 0 at first; the measured joints are fixed (0 by default)."""
    policy = Scripted(targets, capture_initial)
    dut = AcquisitionLoop(policy, StraightLine(), np.zeros(6), period=PERIOD, frame_period=0.1,
                     settle_frames=1, **kwargs)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("position_measured").FixValue(
        context, np.zeros(6) if q_measured is None else q_measured)
    dut.GetInputPort("X_WS").FixValue(context, RigidTransform([0.1, 0.2, 0.3]))
    frame = ToFFrame(np.full((8, 8), 400), np.full((8, 8), 5), np.full((8, 8), 6),
                     sequence=1, timestamp_us=0)
    dut.GetInputPort("tof_frame").FixValue(context, frame)
    return dut, context, policy


def test_moves_along_the_plan_and_skips_unreachable_candidates():
    dut, context, policy = _make([_pose(-1, 0, 0), _pose(0.5, 0, 0)])
    simulator = Simulator(dut, context)
    simulator.AdvanceTo(PERIOD / 2)  # the first update plans
    assert policy.accepted_indices == [1]
    log = dut.GetOutputPort("log").Eval(context)
    assert [f[2] for f in log.motion_failures] == ["unreachable"]
    # A 0.5 rad move at 1 rad/s, 1 rad/s^2 is a triangle of 2*sqrt(0.5) s; halfway it is at
    # 0.25 rad.
    simulator.AdvanceTo(np.sqrt(0.5))
    np.testing.assert_allclose(dut.GetOutputPort("position_command").Eval(context)[0], 0.25,
                               atol=1e-9)


def test_captures_only_a_frame_taken_after_the_arm_settled():
    dut, context, _policy = _make([_pose(0.5, 0, 0)])
    simulator = Simulator(dut, context)
    simulator.AdvanceTo(3.0)  # motion ends at ~1.41 s; the fixed frame is from t = 0
    assert dut.GetOutputPort("log").Eval(context).acquisitions == []
    late = ToFFrame(np.full((8, 8), 321), np.full((8, 8), 5), np.full((8, 8), 6), sequence=9,
                    timestamp_us=2_900_000)
    dut.GetInputPort("tof_frame").FixValue(context, late)
    status = simulator.AdvanceTo(10.0)
    log = dut.GetOutputPort("log").Eval(context)
    assert len(log.acquisitions) == 1
    acquired = dut.GetOutputPort("acquired_frame").Eval(context)
    assert acquired.sequence == 9 and acquired.distance_mm[0, 0] == 321
    np.testing.assert_allclose(log.acquisitions[0].q, 0.0)  # the fixed measured position
    np.testing.assert_allclose(
        dut.GetOutputPort("acquired_pose").Eval(context).translation(), [0.1, 0.2, 0.3])
    # The policy is then done, which terminates the simulation.
    assert status.reason() == status.ReturnReason.kReachedTerminationCondition
    assert log.termination == "script finished"


def test_gives_up_when_nothing_is_reachable():
    dut, context, _ = _make([_pose(-1, 0, 0)], max_failed_proposals=3)
    status = Simulator(dut, context).AdvanceTo(10.0)
    log = dut.GetOutputPort("log").Eval(context)
    assert status.reason() == status.ReturnReason.kReachedTerminationCondition
    assert log.termination.startswith("no reachable viewpoint in 3 proposals")
    assert len(log.motion_failures) == 3


def _recorded(n):
    return [Acquisition(index=k, time=float(k), q=np.full(6, 0.1 * k), X_WS=_pose(0.1 * k, 0, 0),
                        frame=ToFFrame(np.full((8, 8), 300 + k), np.full((8, 8), 5),
                                       np.full((8, 8), 6), sequence=40 + k),
                        info={"candidate_rank": 0}) for k in range(n)]


def test_a_history_is_carried_on_from_planning_not_from_a_capture():
    history = EpisodeLog(acquisitions=_recorded(2))
    dut, context, policy = _make([_pose(0.5, 0, 0)], capture_initial=True, max_poses=3,
                                 history=history)
    extraction = {"after": 2}
    dut.GetInputPort("object").FixValue(context, AbstractValue.Make(extraction))
    # Until the next capture, the planner shows the last recorded acquisition.
    assert dut.GetOutputPort("acquired_frame").Eval(context).sequence == 41
    np.testing.assert_allclose(dut.GetOutputPort("acquired_pose").Eval(context).translation(),
                               [0.1, 0, 0])
    simulator = Simulator(dut, context)
    simulator.AdvanceTo(PERIOD / 2)  # the first update plans (a fresh start would settle)
    assert policy.accepted_indices == [0]
    log = dut.GetOutputPort("log").Eval(context)
    assert log.acquisitions[:2] == history.acquisitions
    # The extraction after the last recorded acquisition is the one read now.
    assert log.extractions == [None, extraction]
    late = ToFFrame(np.full((8, 8), 321), np.full((8, 8), 5), np.full((8, 8), 6), sequence=50,
                    timestamp_us=2_900_000)
    dut.GetInputPort("tof_frame").FixValue(context, late)
    status = simulator.AdvanceTo(10.0)
    assert status.reason() == status.ReturnReason.kReachedTerminationCondition
    assert [a.index for a in log.acquisitions] == [0, 1, 2]
    assert log.termination == "reached the cap of 3 poses"  # the history counts
    assert len(history.acquisitions) == 2  # the planner logged into a copy


def test_a_history_at_the_cap_ends_at_once_and_an_empty_one_is_a_fresh_start():
    dut, context, policy = _make([_pose(0.5, 0, 0)], max_poses=2,
                                 history=EpisodeLog(acquisitions=_recorded(2)))
    Simulator(dut, context).AdvanceTo(1.0)
    assert dut.GetOutputPort("log").Eval(context).termination == "reached the cap of 2 poses"
    assert policy.accepted_indices == []
    dut, context, policy = _make([_pose(0.5, 0, 0)], capture_initial=True,
                                 history=EpisodeLog())
    Simulator(dut, context).AdvanceTo(PERIOD / 2)
    assert policy.accepted_indices == []  # settling for the initial capture


@pytest.mark.parametrize("offset, starts_at_hold", [
    (0.8 * HOLD_TOLERANCE, True),   # a servo's residual: go on from the last command
    (10 * HOLD_TOLERANCE, False),   # the arm is elsewhere: start from where it is
])
def test_a_motion_starts_at_the_last_command_unless_the_arm_is_elsewhere(offset, starts_at_hold):
    q_measured = np.full(6, offset)
    dut, context, policy = _make([_pose(0.5, 0, 0)], q_measured=q_measured)
    Simulator(dut, context).AdvanceTo(1e-6)  # planned at t = 0, the first command since
    assert policy.accepted_indices == [0]
    expected = np.zeros(6) if starts_at_hold else q_measured
    np.testing.assert_allclose(dut.GetOutputPort("position_command").Eval(context), expected,
                               atol=1e-9)


def test_the_default_restore_replays_the_acceptances():
    targets = [_pose(0.1 * k, 0, 0) for k in range(1, 5)]
    run, restored = Scripted(list(targets)), Scripted(list(targets))
    run.accepted(0, None)
    run.accepted(1, None)  # the run moved to targets 0 and 2
    recorded = _recorded(3)
    recorded[0].info = {}  # an initial capture: no proposal led to it
    recorded[2].info["candidate_rank"] = 1
    restored.restore(recorded)
    assert restored.accepted_indices == run.accepted_indices == [0, 1]
    assert restored.targets == run.targets
