"""The acquisition loop's state machine alone (core.acquisition), stepped by hand: no Drake."""

import numpy as np
import pytest
from stop_stand_ins import CountingEstimator, StopAfter

from lrnbv_drake.core.acquisition import (
    HOLD_TOLERANCE,
    Acquisition,
    AcquisitionSequencer,
    EpisodeLog,
    Mode,
    cycle_time,
    motion_start,
)
from lrnbv_drake.core.estimation.track import EstimateTrack
from lrnbv_drake.core.planning.policy import FRAME_OF_VIEW, Observation, Proposal, ViewpointPolicy
from lrnbv_drake.core.planning.stop_while_moving import StopWhileMoving
from lrnbv_drake.core.robot.motion import MotionFailure, MotionPlan
from lrnbv_drake.core.sensing.sensor import ToFFrame

PERIOD, FRAME_PERIOD = 0.05, 0.1


class Ramp:
    """A trajectory from q0 to q1 over [t0, t0 + duration] s, linear."""

    def __init__(self, q0, q1, t0, duration=1.0):
        self.q0, self.q1, self.t0 = np.asarray(q0, float), np.asarray(q1, float), t0
        self.duration = duration

    def value(self, t):
        s = np.clip((t - self.t0) / self.duration, 0.0, 1.0)
        return ((1 - s) * self.q0 + s * self.q1).reshape(6, 1)

    def end_time(self):
        return self.t0 + self.duration


class ToX:
    """Motion stand-in: the joint target is the pose's x in joint 0; x < 0 is unreachable.
    Moves take `duration` s; a halt holds where the ramp is for a tenth of a second."""

    def __init__(self, duration=1.0):
        self.starts, self.duration, self.halts = [], duration, []

    def halt(self, trajectory, t):
        self.halts.append(t)
        q = trajectory.value(t).ravel()
        return Ramp(q, q, t, 0.1)

    def plan(self, q_current, X_WS, start_time=0.0):
        self.starts.append(np.array(q_current))
        if X_WS[0, 3] < 0:
            return MotionPlan(MotionFailure.UNREACHABLE, f"x = {X_WS[0, 3]} < 0")
        q = np.r_[X_WS[0, 3], np.zeros(5)]
        return MotionPlan(None, "ok", q_target=q,
                          trajectory=Ramp(q_current, q, start_time, self.duration))


class Scripted(ViewpointPolicy):
    name = "scripted"

    def __init__(self, proposals):
        self.proposals = list(proposals)
        self.observations = []

    def propose(self, observation):
        self.observations.append(observation)
        return self.proposals.pop(0) if self.proposals else Proposal(done=True, reason="done")


class Inputs:
    """Fixed inputs; `frame` is what the sensor shows now."""

    def __init__(self):
        self.q_value = np.zeros(6)
        self.frame_value = ToFFrame.empty()
        self.extraction = None
        self.estimates_read = 0  # how often the sequencer asked for the estimate track
        self.log = None  # the episode's, when the track is to hold one estimate per extraction

    def frame(self):
        return self.frame_value

    def q(self):
        return self.q_value

    def X_WS(self):
        return np.eye(4)

    def observation(self, n_acquisitions):
        return Observation(time=0.0, q=self.q_value, X_WS=np.eye(4), occupancy=None,
                           extraction=self.extraction, n_acquisitions=n_acquisitions)

    def estimates(self):
        self.estimates_read += 1
        return EstimateTrack((None,) * len(self.log.extractions)) if self.log else EstimateTrack()


def _pose(x):
    X = np.eye(4)
    X[0, 3] = x
    return X


def _frame(sequence, t):
    return ToFFrame(np.full((8, 8), 300), np.full((8, 8), 5), np.full((8, 8), 6),
                    sequence=sequence, timestamp_us=round(t * 1e6))


def test_one_cycle_moves_settles_records_waits_for_the_map_and_plans_again():
    policy = Scripted([Proposal(candidates=[_pose(0.5)], info={"u": 1.0})])
    dut = AcquisitionSequencer(policy, ToX(), period=PERIOD, frame_period=FRAME_PERIOD,
                               settle_frames=2)
    inputs = Inputs()
    s = dut.initial_state(np.zeros(6))
    assert s.mode is Mode.PLAN
    s = dut.step(s, 0.0, inputs)
    assert s.mode is Mode.MOVE and inputs.estimates_read == 0  # nothing to estimate yet
    np.testing.assert_allclose(dut.command(s, 0.5)[0], 0.25)  # half way along the ramp
    s = dut.step(s, 0.9, inputs)
    assert s.mode is Mode.MOVE  # the trajectory ends at 1.0
    s = dut.step(s, 1.0, inputs)
    assert (s.mode, s.t_stop) == (Mode.SETTLE, 1.0)
    np.testing.assert_allclose(s.hold[0], 0.5)
    # settle_frames x frame_period = 0.2 s: a frame begun at 1.15 is too early, 1.2 is not.
    inputs.frame_value = _frame(7, 1.15)
    s = dut.step(s, 1.25, inputs)
    assert s.mode is Mode.SETTLE and not s.log.acquisitions
    inputs.frame_value = _frame(8, 1.2)
    s = dut.step(s, 1.3, inputs)
    assert s.mode is Mode.WAIT_MAP
    (a,) = s.log.acquisitions
    assert (a.index, a.time, a.frame.sequence) == (0, 1.3, 8)
    assert a.info == {"u": 1.0, "candidate_rank": 0}
    # 1.5 periods for the map and the clustering.
    assert dut.step(s, 1.3 + 1.4 * PERIOD, inputs).mode is Mode.WAIT_MAP
    s = dut.step(s, 1.3 + 1.5 * PERIOD, inputs)
    assert s.mode is Mode.PLAN
    inputs.extraction = "after pose 0"
    s = dut.step(s, 1.5, inputs)
    assert (s.mode, s.log.termination) == (Mode.DONE, "done")
    assert s.log.extractions == ["after pose 0"]
    # The estimate after pose 0 is made as it is planned, with no stop rule to read it.
    assert inputs.estimates_read == 1


def test_a_view_of_several_frames_records_each_new_frame_with_the_views_info():
    """frames=3: after the settle, three new frames in a row, no planning between them; a
    frame seen twice is recorded once, and one of a board that restarted its count (the
    same sequence, a new time) is new; the map's wait after the third."""
    policy = Scripted([Proposal(candidates=[_pose(0.5)], frames=3, info={"view": 4})])

    def first_zone_on_the_first_frame(frame, X_WS, q):  # a self filter hitting frame 4 alone
        hit = np.zeros((8, 8), bool)
        hit[0, 0] = frame.sequence == 4
        return frame, hit
    dut = AcquisitionSequencer(policy, ToX(), period=PERIOD, frame_period=FRAME_PERIOD,
                               settle_frames=1, self_filter=first_zone_on_the_first_frame)
    inputs = Inputs()
    s = dut.step(dut.initial_state(np.zeros(6)), 0.0, inputs)
    s = dut.step(s, 1.0, inputs)  # stopped at 1.0: frames begun from 1.1 on are still
    recorded = []
    for t, (sequence, begun) in zip((1.15, 1.2, 1.25, 1.3, 1.35, 1.4),
                                    ((3, 1.05), (4, 1.1), (4, 1.1), (5, 1.2), (5, 1.2),
                                     (5, 1.3)), strict=True):
        inputs.frame_value = _frame(sequence, begun)
        s = dut.step(s, t, inputs)
        recorded.append((len(s.log.acquisitions), s.mode))
    assert recorded == [(0, Mode.SETTLE), (1, Mode.SETTLE), (1, Mode.SETTLE),
                        (2, Mode.SETTLE), (2, Mode.SETTLE), (3, Mode.WAIT_MAP)]
    assert [(a.frame.sequence, a.frame.timestamp_us) for a in s.log.acquisitions] == [
        (4, 1_100_000), (5, 1_200_000), (5, 1_300_000)]
    # Each frame's own info: the view's, its number, and only its own dropped zones.
    assert [{k: v for k, v in a.info.items() if k != "robot_zones"}
            for a in s.log.acquisitions] == [
        {"view": 4, "candidate_rank": 0, FRAME_OF_VIEW: j} for j in range(3)]
    assert ["robot_zones" in a.info for a in s.log.acquisitions] == [True, False, False]
    # Each frame's wait counts once: 0.2 s to the first after the stop, then 0.1 s each.
    np.testing.assert_allclose(s.log.settle_seconds, [0.2, 0.1, 0.1])
    assert len(policy.observations) == 1


def test_unreachable_candidates_fall_through_to_the_next_and_failures_end_the_episode():
    motion = ToX()
    policy = Scripted([Proposal(candidates=[_pose(-1), _pose(0.3)])]
                      + [Proposal(candidates=[_pose(-2)])] * 3)
    dut = AcquisitionSequencer(policy, motion, period=PERIOD, frame_period=FRAME_PERIOD,
                               max_failed_proposals=3)
    s = dut.step(dut.initial_state(np.zeros(6)), 0.0, Inputs())
    assert s.mode is Mode.MOVE and s.pending_info["candidate_rank"] == 1
    assert [f[2] for f in s.log.motion_failures] == ["unreachable"]
    s.mode, s.trajectory = Mode.PLAN, None
    for k in range(3):
        assert s.mode is Mode.PLAN
        s = dut.step(s, 2.0 + k, Inputs())
    assert s.mode is Mode.DONE
    assert s.log.termination == "no reachable viewpoint in 3 proposals (last: x = -2.0 < 0)"


def test_the_pose_cap_counts_recorded_acquisitions_and_a_history_carries_on():
    recorded = [Acquisition(k, 0.1 * k, np.zeros(6), np.eye(4), _frame(k + 1, 0.1 * k))
                for k in range(2)]
    history = EpisodeLog(acquisitions=recorded)
    dut = AcquisitionSequencer(Scripted([]), ToX(), period=PERIOD, frame_period=FRAME_PERIOD,
                               max_poses=2)
    s = dut.initial_state(np.zeros(6), history)
    assert s.mode is Mode.PLAN and s.log is not history
    assert s.log.extractions == [None]  # padded up to the one before the last acquisition
    s = dut.step(s, 0.0, Inputs())
    assert s.log.termination == "reached the cap of 2 poses"
    assert len(history.acquisitions) == 2 and history.termination == ""


def test_a_policy_that_captures_first_starts_by_settling():
    policy = Scripted([])
    policy.capture_initial = True
    dut = AcquisitionSequencer(policy, ToX(), period=PERIOD, frame_period=FRAME_PERIOD)
    assert dut.initial_state(np.zeros(6)).mode is Mode.SETTLE


@pytest.mark.parametrize("offset, from_hold", [(0.99 * HOLD_TOLERANCE, True),
                                               (1.01 * HOLD_TOLERANCE, False)])
def test_a_motion_starts_from_the_held_command_within_the_tolerance(offset, from_hold):
    hold, measured = np.zeros(6), np.r_[offset, np.zeros(5)]
    expected = hold if from_hold else measured
    np.testing.assert_array_equal(motion_start(hold, measured), expected)


def test_bad_periods_and_caps_are_refused_with_their_names():
    with pytest.raises(ValueError, match="period"):
        AcquisitionSequencer(Scripted([]), ToX(), period=0.0, frame_period=FRAME_PERIOD)
    with pytest.raises(ValueError, match="max_poses"):
        AcquisitionSequencer(Scripted([]), ToX(), period=PERIOD, frame_period=FRAME_PERIOD,
                             max_poses=0)


def test_the_cycle_time_is_the_trajectories_plus_the_waits_for_frames():
    """Two 1 s ramps (ToX's trajectories last 1 s) and frames that arrive 0.25 s and 0.35 s
    after each stop: motion 2 s, settling 0.6 s, and the planning time measured."""
    policy = Scripted([Proposal(candidates=[_pose(0.5)]), Proposal(candidates=[_pose(0.2)])])
    dut = AcquisitionSequencer(policy, ToX(), period=PERIOD, frame_period=FRAME_PERIOD)
    inputs = Inputs()
    s = dut.step(dut.initial_state(np.zeros(6)), 0.0, inputs)  # plan at 0, stop at 1.0
    sequence = 0
    for stop, wait in ((1.0, 0.25), (2.5, 0.35)):
        s = dut.step(s, stop, inputs)
        assert s.mode is Mode.SETTLE
        sequence += 1
        inputs.frame_value = _frame(sequence, stop + FRAME_PERIOD)
        s = dut.step(s, stop + wait, inputs)
        s = dut.step(s, stop + wait + 2 * PERIOD, inputs)  # the map's wait
        s = dut.step(s, 1.5 if sequence == 1 else 3.0, inputs)  # plan (or finish)
    cycle = cycle_time(s.log, other_computation=0.5)
    assert s.log.travel_seconds == [1.0, 1.0]
    assert s.log.settle_seconds == pytest.approx([0.25, 0.35])
    assert (cycle.motion, cycle.settle) == (2.0, pytest.approx(0.6))
    planning = sum(s.log.policy_seconds) + sum(s.log.motion_seconds)
    assert cycle.computation == pytest.approx(planning + 0.5)
    assert cycle.total == pytest.approx(2.6 + planning + 0.5)


def test_a_self_filter_takes_the_robot_out_of_the_recorded_frame_and_counts_it():
    """The filter sees the acquired frame with the pose and joints it was taken at; what it
    returns is what the log (and so the map and the box fit) keeps."""
    seen = []

    def marks_first_row(frame, X_WS, q):
        seen.append((frame.sequence, q.copy()))
        hit = np.zeros((8, 8), bool)
        hit[0] = True
        return ToFFrame(frame.distance_mm, np.where(hit, 254, frame.status), frame.sigma_mm,
                        frame.sequence, frame.timestamp_us), hit

    policy = Scripted([])
    policy.capture_initial = True
    dut = AcquisitionSequencer(policy, ToX(), period=PERIOD, frame_period=FRAME_PERIOD,
                               self_filter=marks_first_row)
    inputs = Inputs()
    inputs.q_value = np.full(6, 0.1)
    inputs.frame_value = _frame(3, 0.2)
    s = dut.step(dut.initial_state(np.zeros(6)), 0.3, inputs)
    (a,) = s.log.acquisitions
    assert seen[0][0] == 3 and np.array_equal(seen[0][1], inputs.q_value)
    assert a.frame.valid.sum() == 56 and not a.frame.valid[0].any()
    # What restores the raw frame: the dropped zones' raw indices and original statuses.
    assert a.info == {"robot_zones": {"index": list(range(8)), "status": [5] * 8}}


def _run(dut, inputs, until=20.0):
    """Steps `dut` every PERIOD, the arm where it was commanded, a new frame every
    FRAME_PERIOD, until it is done."""
    s, t = dut.initial_state(np.zeros(6)), 0.0
    inputs.log = s.log
    while s.mode is not Mode.DONE and t < until:
        inputs.q_value = dut.command(s, t)
        inputs.frame_value = _frame(1 + round(t / FRAME_PERIOD), t - t % FRAME_PERIOD)
        s = dut.step(s, t, inputs)
        t = round(t + PERIOD, 9)
    return s


def _beside(seconds=0.0, n=2):
    return StopWhileMoving(CountingEstimator(seconds=seconds), StopAfter(n), threaded=False)


def test_the_stop_checked_beside_the_move_ends_with_the_same_poses_and_halts_that_move():
    """Stop after 2 poses. In order, the loop checks before planning the third view; beside,
    it plans and starts the third move, then halts it when the check says stop: the same two
    poses and reason, a third policy call, and the halted move's time in the motion."""
    views = [Proposal(candidates=[_pose(x)]) for x in (0.5, 0.2, 0.9, 0.4)]
    in_order = AcquisitionSequencer(Scripted(views), ToX(), period=PERIOD,
                                    frame_period=FRAME_PERIOD, stop=StopAfter(2))
    motion = ToX()
    dut = AcquisitionSequencer(Scripted(views), motion, period=PERIOD,
                               frame_period=FRAME_PERIOD, stop=StopAfter(2),
                               stop_while_moving=_beside())
    ordered, beside = _run(in_order, Inputs()), _run(dut, Inputs())
    assert ordered.log.termination == beside.log.termination == "stop after 2"
    assert ([a.frame.sequence for a in ordered.log.acquisitions]
            == [a.frame.sequence for a in beside.log.acquisitions]) and len(
        beside.log.acquisitions) == 2
    assert (len(in_order.policy.observations), len(dut.policy.observations)) == (2, 3)
    # The third move (0.2 -> 0.9 in a 1 s ramp) halted at the first tick after it began,
    # where the arm stays: its motion is those ticks and the halt's 0.1 s.
    (t_halt,) = motion.halts
    assert len(beside.log.travel_seconds) == 3
    assert beside.log.travel_seconds[2] == pytest.approx(t_halt + 0.1 - (t_halt - PERIOD))
    assert beside.hold[0] == pytest.approx(0.2 + 0.7 * PERIOD)
    assert beside.log.stop_wait_seconds == []  # both checks were done while the arm moved


def test_a_check_slower_than_the_move_is_waited_for_at_the_view_as_computation():
    """A 0.1 s move and a check of 0.3 s: the arm would wait at the view the 0.2 s the move
    did not cover, which the cycle counts as computation; the simulated loop goes on at
    once, so the frames are taken when they would have been with a quick check."""
    views = [Proposal(candidates=[_pose(x)]) for x in (0.5, 0.2)]
    quick = _run(AcquisitionSequencer(Scripted(views), ToX(duration=0.1), period=PERIOD,
                                      frame_period=FRAME_PERIOD,
                                      stop_while_moving=_beside(0.0, 5)), Inputs())
    dut = AcquisitionSequencer(Scripted(views), ToX(duration=0.1), period=PERIOD,
                               frame_period=FRAME_PERIOD, stop_while_moving=_beside(0.3, 5))
    s = _run(dut, Inputs())
    assert len(s.log.acquisitions) == 2 and s.log.termination == "done"
    (wait,) = s.log.stop_wait_seconds
    assert 0.2 - 1e-9 <= wait < 1.0
    assert cycle_time(s.log).computation == pytest.approx(
        sum(s.log.policy_seconds) + sum(s.log.motion_seconds) + wait)
    assert [a.time for a in s.log.acquisitions] == [a.time for a in quick.log.acquisitions]


@pytest.mark.parametrize("after_second", [Proposal(done=True, reason="policy done"),
                                          Proposal(candidates=[_pose(-1.0)])])
def test_when_no_move_follows_a_pose_the_stop_is_checked_at_rest_and_ends_it(after_second):
    """Beside the moves, but after the second pose the policy is done, or its one view is
    unreachable: nothing moves, so the stop is checked there, and the episode ends with its
    reason, as checking first would."""
    views = [Proposal(candidates=[_pose(0.5)]), Proposal(candidates=[_pose(0.2)]), after_second]
    dut = AcquisitionSequencer(Scripted(views), ToX(), period=PERIOD, frame_period=FRAME_PERIOD,
                               stop=StopAfter(2), stop_while_moving=_beside())
    s = _run(dut, Inputs())
    assert s.log.termination == "stop after 2" and len(s.log.acquisitions) == 2
    assert len(s.log.travel_seconds) == 2  # no third move begun
