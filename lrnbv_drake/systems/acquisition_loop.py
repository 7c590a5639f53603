"""AcquisitionLoop: the LeafSystem that drives an episode.

A state machine stepped by a periodic unrestricted update:

    PLAN    ask the policy for ranked viewpoints; plan a motion to the first reachable one
    MOVE    play the trajectory on `position_command` until it ends
    SETTLE  wait for a frame captured after the arm stopped (`settle_frames` periods later)
    CAPTURE publish that frame and its pose on `acquired_frame` / `acquired_pose`, log it, and
            wait two periods so the map and the clustering have taken it in, then PLAN again

The episode ends (the update returns ReachedTermination) when the policy is done, when
`max_poses` frames have been captured, or when no proposed viewpoint can be reached. Given a
`history` (the acquisitions of an interrupted episode), it carries on from there: it starts by
planning, and `max_poses` counts those acquisitions.

The policy and the motion planner are held by the system, not the context: the policy keeps
planner memory (cached nodes, visited cells) across steps, as the algorithm requires. The
episode log is an append-only handle in the state (its deep copy is itself: Drake copies the
state around every update, and the log grows with every pose). Like the map, it makes the
system not context-pure: run an episode forward once, with a new system for a new episode.
"""

from __future__ import annotations

import dataclasses as dc
import enum
import time
from typing import Any

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem
from pydrake.trajectories import PiecewisePolynomial

from lrnbv_drake.core.planning.policy import CANDIDATE_RANK, Observation, ViewpointPolicy
from lrnbv_drake.core.sensor import ToFFrame
from lrnbv_drake.station.motion import MotionPlanner

#: A motion starts from the last command, not from the measured joints, when no joint is
#: further apart than this, radians (see `_motion_start`).
HOLD_TOLERANCE = 0.005


class Mode(enum.Enum):
    PLAN = "plan"
    MOVE = "move"
    SETTLE = "settle"
    WAIT_MAP = "wait_map"
    DONE = "done"


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
    """Everything an episode did, in order. A handle: copies share it (see the module doc)."""

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
    termination: str = ""
    # The last accepted proposal's drawable data (tree, cache, ROI), with its "step" number and
    # the chosen "X_WS". Kept here, not in the copied state: its arrays are large.
    plan: dict[str, Any] = dc.field(default_factory=dict)

    def __deepcopy__(self, memo: dict) -> EpisodeLog:
        return self


def _carried_on(history: EpisodeLog) -> EpisodeLog:
    """A new log that starts with `history` (its lists copied: the planner appends to them).

    Extractions are index-aligned with acquisitions and the planner logs the one after an
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
        motion_seconds=list(history.motion_seconds), termination="")


def _motion_start(hold: np.ndarray, measured: np.ndarray) -> np.ndarray:
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


@dc.dataclass
class _State:
    mode: Mode = Mode.PLAN
    trajectory: PiecewisePolynomial | None = None
    hold: np.ndarray | None = None
    t_stop: float = 0.0
    t_ready: float = 0.0
    pending_info: dict[str, Any] = dc.field(default_factory=dict)
    failed_in_a_row: int = 0
    log: EpisodeLog = dc.field(default_factory=EpisodeLog)


class AcquisitionLoop(LeafSystem):
    """Drives the cell through an episode of a viewpoint policy.

    Input ports: `position_measured` (6), `tof_frame` (ToFFrame), `X_WS` (RigidTransform),
    `map` (OccupancyMap, optional), `object` (ExtractionResult, optional).
    Output ports: `position_command` (6), `acquired_frame` (ToFFrame), `acquired_pose`
    (RigidTransform), `log` (EpisodeLog), `plan` (dict: the accepted proposal's drawable data,
    its `step` number and the chosen `X_WS`).

    `history`, when it holds acquisitions, is an episode to carry on: the planner starts in
    PLAN (no capture at the start pose), its log is a copy of `history` (so the count towards
    `max_poses`, the indices and the report go on), and `acquired_frame` / `acquired_pose`
    show the last recorded acquisition until the next one. Extractions missing from it are
    logged as None, except the one after the last acquisition, which the first plan takes.
    The policy and the map are the caller's to restore (`ViewpointPolicy.restore`,
    `OccupancyMapSystem.mark_inserted`).
    """

    def __init__(self, policy: ViewpointPolicy, motion: MotionPlanner, q_initial: np.ndarray,
                 *, period: float, frame_period: float, settle_frames: int = 1,
                 max_poses: int = 50, max_failed_proposals: int = 5,
                 history: EpisodeLog | None = None):
        super().__init__()
        self._policy = policy
        self._motion = motion
        self._period = period
        self._frame_period = frame_period
        self._settle = settle_frames * frame_period
        self._max_poses = max_poses
        self._max_failed = max_failed_proposals
        q_initial = np.asarray(q_initial, float)

        self._q_port = self.DeclareVectorInputPort("position_measured", 6)
        self._frame_port = self.DeclareAbstractInputPort(
            "tof_frame", AbstractValue.Make(ToFFrame.empty()))
        self._pose_port = self.DeclareAbstractInputPort(
            "X_WS", AbstractValue.Make(RigidTransform()))
        self._map_port = self.DeclareAbstractInputPort("map", AbstractValue.Make(None))
        self._object_port = self.DeclareAbstractInputPort("object", AbstractValue.Make(None))

        if history is not None and history.acquisitions:
            initial = _State(hold=q_initial, log=_carried_on(history), mode=Mode.PLAN)
        else:
            initial = _State(hold=q_initial, log=EpisodeLog(),
                             mode=Mode.SETTLE if policy.capture_initial else Mode.PLAN)
        self._state_index = self.DeclareAbstractState(AbstractValue.Make(initial))
        state_ticket = {self.abstract_state_ticket(self._state_index)}
        self.DeclareVectorOutputPort("position_command", 6, self._CalcCommand,
                                     prerequisites_of_calc={self.time_ticket(),
                                                            *state_ticket})
        self.DeclareAbstractOutputPort("acquired_frame",
                                       lambda: AbstractValue.Make(ToFFrame.empty()),
                                       self._CalcAcquiredFrame, prerequisites_of_calc=state_ticket)
        self.DeclareAbstractOutputPort("acquired_pose",
                                       lambda: AbstractValue.Make(RigidTransform()),
                                       self._CalcAcquiredPose, prerequisites_of_calc=state_ticket)
        self.DeclareAbstractOutputPort("log", lambda: AbstractValue.Make(EpisodeLog()),
                                       self._CalcLog, prerequisites_of_calc=state_ticket)
        self.DeclareAbstractOutputPort("plan", lambda: AbstractValue.Make({}),
                                       self._CalcPlan, prerequisites_of_calc=state_ticket)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._Update)

    # Outputs -----------------------------------------------------------------------------

    def _state(self, context) -> _State:
        return context.get_abstract_state(self._state_index).get_value()

    def _CalcCommand(self, context, output) -> None:
        s = self._state(context)
        if s.trajectory is not None:
            t = min(context.get_time(), s.trajectory.end_time())
            output.SetFromVector(s.trajectory.value(t).ravel())
        else:
            output.SetFromVector(s.hold)

    def _CalcAcquiredFrame(self, context, output) -> None:
        acquisitions = self._state(context).log.acquisitions
        output.set_value(acquisitions[-1].frame if acquisitions else ToFFrame.empty())

    def _CalcAcquiredPose(self, context, output) -> None:
        acquisitions = self._state(context).log.acquisitions
        output.set_value(RigidTransform(acquisitions[-1].X_WS) if acquisitions
                         else RigidTransform())

    def _CalcLog(self, context, output) -> None:
        output.set_value(self._state(context).log)

    def _CalcPlan(self, context, output) -> None:
        output.set_value(self._state(context).log.plan)

    # The state machine -------------------------------------------------------------------

    def _Update(self, context, state) -> EventStatus:
        s: _State = dc.replace(self._state(context))
        t = context.get_time()
        if s.mode is Mode.DONE:
            return EventStatus.ReachedTermination(self, s.log.termination)
        if s.mode is Mode.MOVE and t >= s.trajectory.end_time():
            s.hold = s.trajectory.value(s.trajectory.end_time()).ravel()
            s.trajectory = None
            s.mode, s.t_stop = Mode.SETTLE, t
        elif s.mode is Mode.SETTLE:
            frame = self._frame_port.Eval(context)
            if frame.sequence > 0 and frame.timestamp_us >= (s.t_stop + self._settle) * 1e6 - 1:
                self._capture(context, s, frame)
        elif s.mode is Mode.WAIT_MAP and t >= s.t_ready:
            s.mode = Mode.PLAN
        elif s.mode is Mode.PLAN:
            self._plan(context, s)
        state.get_mutable_abstract_state(self._state_index).set_value(s)
        if s.mode is Mode.DONE:
            return EventStatus.ReachedTermination(self, s.log.termination)
        return EventStatus.Succeeded()

    def _observation(self, context, s: _State) -> Observation:
        return Observation(
            time=context.get_time(),
            q=np.asarray(self._q_port.Eval(context), float).copy(),
            X_WS=self._pose_port.Eval(context).GetAsMatrix4(),
            occupancy=self._map_port.Eval(context) if self._map_port.HasValue(context) else None,
            extraction=(self._object_port.Eval(context)
                        if self._object_port.HasValue(context) else None),
            n_acquisitions=len(s.log.acquisitions),
        )

    def _capture(self, context, s: _State, frame: ToFFrame) -> None:
        s.log.acquisitions.append(Acquisition(
            index=len(s.log.acquisitions), time=context.get_time(),
            q=np.asarray(self._q_port.Eval(context), float).copy(),
            X_WS=self._pose_port.Eval(context).GetAsMatrix4(), frame=frame,
            info=s.pending_info))
        s.pending_info = {}
        # Two update periods: the map inserts the frame on the next one, the planner reads the
        # updated map on the one after.
        s.mode, s.t_ready = Mode.WAIT_MAP, context.get_time() + 1.5 * self._period

    def _finish(self, s: _State, reason: str) -> None:
        s.mode = Mode.DONE
        s.log.termination = reason

    def _plan(self, context, s: _State) -> None:
        started = time.perf_counter()
        observation = self._observation(context, s)
        if observation.n_acquisitions > len(s.log.extractions):
            s.log.extractions.append(observation.extraction)
            s.log.clustering_seconds.append(time.perf_counter() - started)
        if observation.n_acquisitions >= self._max_poses:
            self._finish(s, f"reached the cap of {self._max_poses} poses")
            return
        started = time.perf_counter()
        proposal = self._policy.propose(observation)
        policy_seconds = time.perf_counter() - started
        s.log.policy_seconds.append(policy_seconds)
        if proposal.done:
            self._finish(s, proposal.reason)
            return
        started = time.perf_counter()
        failures = []
        q_start = _motion_start(s.hold, observation.q)
        for i, X_WS in enumerate(proposal.candidates):
            plan = self._motion.plan(q_start, X_WS, start_time=context.get_time())
            if plan.ok:
                self._policy.accepted(i, observation)
                s.trajectory, s.mode = plan.trajectory, Mode.MOVE
                per_candidate = proposal.candidate_info[i] if proposal.candidate_info else {}
                s.pending_info = {**proposal.info, **per_candidate, CANDIDATE_RANK: i}
                s.log.plan = {**proposal.debug, "step": len(s.log.policy_seconds),
                          "X_WS": np.asarray(X_WS)}
                break
            failures.append((context.get_time(), np.asarray(X_WS), plan.failure.value,
                             plan.reason))
        s.log.motion_failures.extend(failures)
        s.log.motion_seconds.append(time.perf_counter() - started)
        if s.mode is Mode.MOVE:
            s.failed_in_a_row = 0
            return
        s.failed_in_a_row += 1
        if s.failed_in_a_row >= self._max_failed or not proposal.candidates:
            last = failures[-1][3] if failures else "the policy proposed no viewpoint"
            self._finish(s, f"no reachable viewpoint in {s.failed_in_a_row} proposals "
                            f"(last: {last})")
