"""The acquisition loop, without Drake: plan a view, move there, wait for a still frame, record
it, let the map take it in, plan again.

`AcquisitionSequencer.step` advances an `AcquisitionState` by one tick:

    PLAN      ask the policy for ranked viewpoints; plan a motion to the first reachable one
    MOVE      play the trajectory (`command`) until it ends; meanwhile, with a
              `StopWhileMoving`, check the stop after the last acquisition and halt the move
              (`MotionPlanning.halt`) if it says stop
    SETTLE    wait for a frame whose integration began `settle_frames` frame periods after
              the stop, then record it as an `Acquisition`; a proposal of `frames` > 1
              records that many consecutive new frames at the view, numbered in their info
              (`FRAME_OF_VIEW`)
    WAIT_MAP  wait 1.5 ticks: the map inserts the frame on the next tick, the planner reads
              the updated map on the one after; then PLAN
    DONE      the policy is done, the stop rule says the reported box is known (`stop`, reading
              the estimates `AcquisitionInputs.estimates` gives once the extraction after
              the last acquisition is logged; while moving when the policy does not read
              the estimate and a `StopWhileMoving` is given), `max_poses`
              frames were recorded, or no proposed viewpoint could be reached
              `max_failed_proposals` times in a row

The `AcquisitionLoop` system steps it from a periodic update and reads its inputs through
`AcquisitionInputs`; the hardware session and the simulated episode share it unchanged.
"""

from __future__ import annotations

import dataclasses as dc
import enum
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.track import EstimateTrack
from lrnbv_drake.core.mapping.extraction import found_box
from lrnbv_drake.core.planning.policy import (
    CANDIDATE_RANK,
    FRAME_OF_VIEW,
    Observation,
    ViewpointPolicy,
)
from lrnbv_drake.core.planning.stop import BoxStop
from lrnbv_drake.core.planning.stop_while_moving import StopWhileMoving
from lrnbv_drake.core.robot.motion import MotionPlanning, Trajectory
from lrnbv_drake.core.robot.self_filter import dropped_zones_info
from lrnbv_drake.core.sensing.sensor import ToFFrame

#: (frame, X_WS, q) -> (the frame without the zones that read the robot itself, their
#: (res, res) mask in raw order): core/robot/self_filter.py's `drop_robot_zones` at joints q.
SelfFilter = Callable[[ToFFrame, np.ndarray, np.ndarray], tuple[ToFFrame, np.ndarray]]

#: A motion starts from the last command, not from the measured joints, when no joint is
#: further apart than this, radians (see `motion_start`).
HOLD_TOLERANCE = 0.005
#: Frame periods the map and the clustering are given to take in a captured frame before the
#: next plan.
MAP_WAIT_PERIODS = 1.5


def seconds_at_a_view(frame_period: float, settle_frames: int) -> float:
    """What the loop waits at a view besides computing: the frames discarded once the arm
    stops, the frame used, and the map's `MAP_WAIT_PERIODS`."""
    return (settle_frames + 1 + MAP_WAIT_PERIODS) * frame_period


@dc.dataclass
class Acquisition:
    """One captured viewpoint."""

    index: int
    time: float
    q: np.ndarray
    X_WS: np.ndarray
    frame: ToFFrame
    info: dict[str, Any] = dc.field(default_factory=dict)


@dc.dataclass
class EpisodeLog:
    """Everything an episode did, in order. A handle: deep copies share it (Drake copies the
    state around every update, and the log grows with every pose)."""

    acquisitions: list[Acquisition] = dc.field(default_factory=list)
    # The object extraction after each acquisition (index-aligned with `acquisitions`).
    extractions: list[Any] = dc.field(default_factory=list)
    # Seconds the clustering took to give each of those extractions.
    clustering_seconds: list[float] = dc.field(default_factory=list)
    # Viewpoints that could not be reached: (time, X_WS, failure, reason).
    motion_failures: list[tuple[float, np.ndarray, str, str]] = dc.field(default_factory=list)
    # Seconds spent choosing each viewpoint (policy) and planning its motion.
    policy_seconds: list[float] = dc.field(default_factory=list)
    motion_seconds: list[float] = dc.field(default_factory=list)
    # Cell time, seconds: each accepted trajectory's duration, and each acquisition's wait
    # from the arm's stop (or the start, or its view's frame before) to the frame used.
    travel_seconds: list[float] = dc.field(default_factory=list)
    settle_seconds: list[float] = dc.field(default_factory=list)
    # Cell time the arm waited at a view for the stop check begun as it moved there, seconds
    # (computation the move did not cover).
    stop_wait_seconds: list[float] = dc.field(default_factory=list)
    termination: str = ""
    # The last accepted proposal's drawable data (tree, cache, ROI), with its "step" number and
    # the chosen "X_WS". Kept here, not in the copied state: its arrays are large.
    plan: dict[str, Any] = dc.field(default_factory=dict)

    def __deepcopy__(self, memo: dict) -> EpisodeLog:
        return self


def carried_on(history: EpisodeLog) -> EpisodeLog:
    """A new log that starts with `history` (its lists copied: the loop appends to them).

    Extractions are index-aligned with acquisitions and the loop logs the one after an
    acquisition when it next plans, so the history's are padded with None up to the one
    before its last acquisition; its termination is cleared, since the episode goes on.
    """
    aligned = len(history.acquisitions) - 1
    return dc.replace(
        history, acquisitions=list(history.acquisitions),
        extractions=history.extractions + [None] * (aligned - len(history.extractions)),
        clustering_seconds=(history.clustering_seconds
                            + [0.0] * (aligned - len(history.clustering_seconds))),
        motion_failures=list(history.motion_failures),
        policy_seconds=list(history.policy_seconds),
        motion_seconds=list(history.motion_seconds),
        travel_seconds=list(history.travel_seconds),
        settle_seconds=list(history.settle_seconds),
        stop_wait_seconds=list(history.stop_wait_seconds), termination="")


def estimator_inputs(log: EpisodeLog) -> tuple[list[tuple[ToFFrame, np.ndarray]],
                                                list[OrientedBox | None]]:
    """What `EpisodeEstimator.update` folds in from `log`: each acquisition's (frame, X_WS)
    and the cell box of each extraction logged (None where no object was found)."""
    return ([(a.frame, a.X_WS) for a in log.acquisitions],
            [found_box(e) for e in log.extractions])


@dc.dataclass(frozen=True)
class CycleTime:
    """What the cell's time went on, seconds: the arm moving along its trajectories, waiting
    for a still frame, and the computer choosing, planning, mapping and estimating (on the
    real cell the arm waits for it; in simulation it costs no simulated time)."""

    motion: float
    settle: float
    computation: float

    @property
    def total(self) -> float:
        return self.motion + self.settle + self.computation


def cycle_time(log: EpisodeLog, other_computation: float = 0.0) -> CycleTime:
    """The episode's `CycleTime`: the trajectories' durations, the waits for frames, and the
    measured planning time, the waits for stop checks plus `other_computation` (map,
    clustering, box estimate)."""
    return CycleTime(motion=float(sum(log.travel_seconds)), settle=float(sum(log.settle_seconds)),
                     computation=float(sum(log.policy_seconds) + sum(log.motion_seconds)
                                       + sum(log.stop_wait_seconds) + other_computation))


def motion_start(hold: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Where the next trajectory starts: the last command when the arm is within
    HOLD_TOLERANCE of it on every joint, else the measured joints.

    A real servo comes to rest a little off its target, so the measured joints differ from the
    command held at rest. A trajectory from the measured joints would make its first command
    jump by that residual (refused by the hardware sender beyond its jump tolerance); one from
    the held command goes on from it smoothly and the servo takes up the residual. Further
    apart, the arm is not where the last command put it (pushed, or still moving), and the
    motion must start from where it is. In simulation the measured joints are the command, so
    this changes nothing there.
    """
    return hold if np.abs(measured - hold).max() <= HOLD_TOLERANCE else measured


class Mode(enum.Enum):
    PLAN = "plan"
    MOVE = "move"
    SETTLE = "settle"
    WAIT_MAP = "wait_map"
    DONE = "done"


@dc.dataclass
class AcquisitionState:
    """The loop's state; `step` returns a new one (the log is shared, see `EpisodeLog`)."""

    mode: Mode
    hold: np.ndarray
    log: EpisodeLog
    trajectory: Trajectory | None = None
    t_stop: float = 0.0
    t_ready: float = 0.0
    pending_info: dict[str, Any] = dc.field(default_factory=dict)
    failed_in_a_row: int = 0
    # Frames still to record at this view, of how many; the (sequence, board time) of its last
    # frame recorded (a new frame differs in either, so a board that restarts its count is
    # still read); since when the loop has waited for the next (the stop, or the last frame).
    frames_left: int = 1
    view_frames: int = 1
    last_frame: tuple[int, int] = (0, 0)
    t_waiting: float = 0.0
    # The reason a stop check beside the move gave to stop, the move halted, once the arm is
    # at rest.
    halting: str | None = None


class AcquisitionInputs(Protocol):
    """What the loop reads, when it needs it (reading a port can cost a map query)."""

    def frame(self) -> ToFFrame: ...
    def q(self) -> np.ndarray: ...
    def X_WS(self) -> np.ndarray: ...
    def observation(self, n_acquisitions: int) -> Observation: ...
    def estimates(self) -> EstimateTrack: ...


class AcquisitionSequencer:
    """Steps the acquisition loop of one episode (see the module docstring).

    The policy keeps planner memory (cached nodes, visited cells) across steps, as the
    algorithm requires, so one sequencer runs one episode. `self_filter`, when given, takes
    the zones that read the robot itself out of each acquired frame before the map, the
    clustering and the box fit see it. `stop_while_moving`, when given, checks the stop while
    the arm moves for every policy that does not read the estimate.
    """

    def __init__(self, policy: ViewpointPolicy, motion: MotionPlanning, *, period: float,
                 frame_period: float, settle_frames: int = 1, max_poses: int = 50,
                 max_failed_proposals: int = 5, stop: BoxStop | None = None,
                 self_filter: SelfFilter | None = None,
                 stop_while_moving: StopWhileMoving | None = None) -> None:
        if not period > 0 or not frame_period > 0:
            raise ValueError(f"period and frame_period must be > 0, got {period} and "
                             f"{frame_period}")
        if max_poses < 1:
            raise ValueError(f"max_poses must be at least 1, got {max_poses}")
        self.policy = policy
        self._motion = motion
        self._period = period
        self._settle = settle_frames * frame_period
        self._max_poses = max_poses
        self._max_failed = max_failed_proposals
        self._stop = stop
        self._self_filter = self_filter
        self._beside = stop_while_moving

    def initial_state(self, q_initial: np.ndarray, history: EpisodeLog | None = None
                      ) -> AcquisitionState:
        """Holding `q_initial`; capturing first if the policy wants the start pose. With a
        `history` holding acquisitions, carrying that episode on from planning."""
        q_initial = np.asarray(q_initial, float)
        if history is not None and history.acquisitions:
            return AcquisitionState(Mode.PLAN, q_initial, carried_on(history))
        return AcquisitionState(Mode.SETTLE if self.policy.capture_initial else Mode.PLAN,
                                q_initial, EpisodeLog())

    @staticmethod
    def command(state: AcquisitionState, t: float) -> np.ndarray:
        """The joint command at time t."""
        if state.trajectory is not None:
            return np.asarray(state.trajectory.value(min(t, state.trajectory.end_time())),
                              float).ravel()
        return state.hold

    def step(self, state: AcquisitionState, t: float, inputs: AcquisitionInputs
             ) -> AcquisitionState:
        """The state after the tick at time t."""
        s = dc.replace(state)
        if s.mode is Mode.MOVE and t >= s.trajectory.end_time():
            s.hold = np.asarray(s.trajectory.value(s.trajectory.end_time()), float).ravel()
            s.trajectory = None
            s.mode, s.t_stop, s.t_waiting = Mode.SETTLE, t, t
            if s.halting is not None:
                self._finish(s, s.halting)
        elif self._beside is not None and self._beside.running:  # moving, or arrived first
            self._collect(s, t)
        elif s.mode is Mode.SETTLE:
            frame = inputs.frame()
            if (frame.sequence > 0 and (frame.sequence, frame.timestamp_us) != s.last_frame
                    and frame.timestamp_us >= (s.t_stop + self._settle) * 1e6 - 1):
                self._record(s, t, frame, inputs)
        elif s.mode is Mode.WAIT_MAP and t >= s.t_ready:
            s.mode = Mode.PLAN
        elif s.mode is Mode.PLAN:
            self._plan(s, t, inputs)
        return s

    def _record(self, s: AcquisitionState, t: float, frame: ToFFrame,
                inputs: AcquisitionInputs) -> None:
        q, X_WS = np.asarray(inputs.q(), float).copy(), inputs.X_WS()
        info = dict(s.pending_info)
        if s.view_frames > 1:
            info[FRAME_OF_VIEW] = s.view_frames - s.frames_left
        s.last_frame = (frame.sequence, frame.timestamp_us)
        if self._self_filter is not None:
            filtered, hit = self._self_filter(frame, X_WS, q)
            if hit.any():
                info["robot_zones"] = dropped_zones_info(frame, hit)
            frame = filtered
        s.log.acquisitions.append(Acquisition(
            index=len(s.log.acquisitions), time=t, q=q, X_WS=X_WS, frame=frame, info=info))
        s.log.settle_seconds.append(t - s.t_waiting)
        s.t_waiting = t
        s.frames_left -= 1
        if s.frames_left > 0:  # the view's next frame, each with the view's info
            return
        s.pending_info = {}
        s.mode, s.t_ready = Mode.WAIT_MAP, t + MAP_WAIT_PERIODS * self._period

    def _collect(self, s: AcquisitionState, t: float) -> None:
        """Takes the stop check's result once it is known. Moving, a stop halts the move,
        and a check done after the arrival (`StopCheck.ready_at`) is the arm's wait at the
        view; at a view, the wait is until it was done, and a stop ends the episode."""
        check = self._beside.result(t)
        if check is None:
            return
        if s.mode is Mode.MOVE:
            if check.reason is not None:
                halted = self._motion.halt(s.trajectory, t)
                s.log.travel_seconds[-1] -= s.trajectory.end_time() - halted.end_time()
                s.trajectory, s.halting = halted, check.reason
            elif check.ready_at > s.trajectory.end_time():
                s.log.stop_wait_seconds.append(check.ready_at - s.trajectory.end_time())
            return
        s.log.stop_wait_seconds.append(max(0.0, check.ready_at - s.t_waiting))
        s.t_waiting = max(s.t_waiting, min(t, check.ready_at))
        if check.reason is not None:
            self._finish(s, check.reason)

    def _stop_now(self, s: AcquisitionState, inputs: AcquisitionInputs
                  ) -> EstimateTrack | None:
        """Makes the estimate and checks the stop in order, the arm at rest: the track, or
        None when the stop ended the episode."""
        track = inputs.estimates()
        reason = self._stop.update(track) if self._stop is not None else None
        if reason is not None:
            self._finish(s, reason)
            return None
        return track

    @staticmethod
    def _finish(s: AcquisitionState, reason: str) -> None:
        s.mode = Mode.DONE
        s.log.termination = reason

    def _plan(self, s: AcquisitionState, t: float, inputs: AcquisitionInputs) -> None:
        started = time.perf_counter()
        observation = inputs.observation(len(s.log.acquisitions))
        if observation.n_acquisitions > len(s.log.extractions):
            s.log.extractions.append(observation.extraction)
            s.log.clustering_seconds.append(time.perf_counter() - started)
        if observation.n_acquisitions >= self._max_poses:
            self._finish(s, f"reached the cap of {self._max_poses} poses")
            return
        started = time.perf_counter()
        # The estimate is made pose by pose whatever the planner: each one's cycle time pays
        # for it, and a report after a fault waits on no acquisition but the last. Beside the
        # next move when nothing else waits on it.
        beside = (self._beside is not None and observation.n_acquisitions > 0
                  and not self.policy.reads_estimate)
        if observation.n_acquisitions > 0 and not beside:
            track = self._stop_now(s, inputs)
            if track is None:
                s.log.policy_seconds.append(time.perf_counter() - started)
                return
            observation = dc.replace(observation, estimate=track.latest)
        proposal = self.policy.propose(observation)
        stopped = proposal.done and beside and self._stop_now(s, inputs) is None
        s.log.policy_seconds.append(time.perf_counter() - started)
        if stopped:
            return
        if proposal.done:
            self._finish(s, proposal.reason)
            return
        started = time.perf_counter()
        failures = []
        q_start = motion_start(s.hold, observation.q)
        for i, X_WS in enumerate(proposal.candidates):
            plan = self._motion.plan(q_start, X_WS, start_time=t)
            if plan.ok:
                self.policy.accepted(i, observation)
                s.trajectory, s.mode = plan.trajectory, Mode.MOVE
                s.log.travel_seconds.append(plan.trajectory.end_time() - t)
                per_candidate = proposal.candidate_info[i] if proposal.candidate_info else {}
                s.pending_info = {**proposal.info, **per_candidate, CANDIDATE_RANK: i}
                s.frames_left = s.view_frames = proposal.frames
                s.log.plan = {**proposal.debug, "step": len(s.log.policy_seconds),
                              "X_WS": np.asarray(X_WS)}
                break
            failures.append((t, np.asarray(X_WS), plan.failure.value, plan.reason))
        s.log.motion_failures.extend(failures)
        if s.mode is Mode.MOVE:
            s.log.motion_seconds.append(time.perf_counter() - started)
            s.failed_in_a_row = 0
            if beside:
                self._beside.start(*estimator_inputs(s.log), t)
            return
        stopped = beside and self._stop_now(s, inputs) is None
        s.log.motion_seconds.append(time.perf_counter() - started)
        if stopped:
            return
        s.failed_in_a_row += 1
        if s.failed_in_a_row >= self._max_failed or not proposal.candidates:
            last = failures[-1][3] if failures else "the policy proposed no viewpoint"
            self._finish(s, f"no reachable viewpoint in {s.failed_in_a_row} proposals "
                            f"(last: {last})")
