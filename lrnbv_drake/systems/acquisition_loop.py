"""`AcquisitionLoop`: the system that drives an episode, a thin wrapper of
`core.acquisition.AcquisitionSequencer` (the state machine and its records live there).

The policy and the motion planner are held by the sequencer, not the context: the policy keeps
planner memory across steps, as the algorithm requires. The episode log is an append-only
handle in the state. Like the map, it makes the system not context-pure: run an episode
forward once, with a new system for a new episode.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, EventStatus, LeafSystem, State

from lrnbv_drake.core.acquisition import (
    AcquisitionSequencer,
    AcquisitionState,
    EpisodeLog,
    Mode,
    SelfFilter,
)
from lrnbv_drake.core.estimation.track import EstimateTrack
from lrnbv_drake.core.planning.policy import Observation, ViewpointPolicy
from lrnbv_drake.core.planning.stop import BoxStop
from lrnbv_drake.core.planning.stop_while_moving import StopWhileMoving
from lrnbv_drake.core.robot.motion import MotionPlanning
from lrnbv_drake.core.sensing.sensor import ToFFrame


class _PortInputs:
    """`AcquisitionInputs` read from the system's input ports in one context."""

    def __init__(self, system: AcquisitionLoop, context: Context) -> None:
        self._system, self._context = system, context

    def frame(self) -> ToFFrame:
        return self._system.GetInputPort("tof_frame").Eval(self._context)

    def q(self) -> np.ndarray:
        return np.asarray(self._system.GetInputPort("position_measured").Eval(self._context),
                          float)

    def X_WS(self) -> np.ndarray:
        return self._system.GetInputPort("X_WS").Eval(self._context).GetAsMatrix4()

    def estimates(self) -> EstimateTrack:
        port = self._system.GetInputPort("box_estimate")
        return port.Eval(self._context) if port.HasValue(self._context) else EstimateTrack()

    def observation(self, n_acquisitions: int) -> Observation:
        def optional(name: str):
            port = self._system.GetInputPort(name)
            return port.Eval(self._context) if port.HasValue(self._context) else None
        return Observation(time=self._context.get_time(), q=self.q().copy(), X_WS=self.X_WS(),
                           occupancy=optional("map"), extraction=optional("object"),
                           n_acquisitions=n_acquisitions)


class AcquisitionLoop(LeafSystem):
    """Drives the cell through an episode of a viewpoint policy.

    @system
    name: AcquisitionLoop
    input_ports:
    - position_measured
    - tof_frame
    - X_WS
    - map (optional)
    - object (optional)
    - box_estimate (optional)
    output_ports:
    - position_command
    - acquired_frame
    - acquired_pose
    - log
    - plan
    @endsystem

    `position_measured` (6), `tof_frame` (ToFFrame), `X_WS` (RigidTransform), `map`
    (OccupancyMap), `object` (ExtractionResult), `box_estimate` (EstimateTrack, what the
    stop rule reads; the `BoxEstimation` system computes it from `log`). `position_command`
    (6) plays the current trajectory; `acquired_frame` / `acquired_pose` show the last
    acquisition; `log` is the `EpisodeLog`; `plan` the accepted proposal's drawable data. A
    periodic unrestricted update steps the sequencer and returns ReachedTermination when the
    episode is done.

    `stop_while_moving` (sharing the `BoxEstimation` system's estimator) checks the stop
    beside each move when the policy does not read the estimate; `box_estimate` is then
    read only where the loop checks in order.

    `history`, when it holds acquisitions, is an episode to carry on (`initial_state`): the
    policy and the map are the caller's to restore (`ViewpointPolicy.restore`,
    `OccupancyMapSystem.insert_recorded`).
    """

    def __init__(self, policy: ViewpointPolicy, motion: MotionPlanning, q_initial: np.ndarray,
                 *, period: float, frame_period: float, settle_frames: int = 1,
                 max_poses: int = 50, max_failed_proposals: int = 5,
                 history: EpisodeLog | None = None, stop: BoxStop | None = None,
                 self_filter: SelfFilter | None = None,
                 stop_while_moving: StopWhileMoving | None = None):
        super().__init__()
        self._sequencer = AcquisitionSequencer(
            policy, motion, period=period, frame_period=frame_period,
            settle_frames=settle_frames, max_poses=max_poses,
            max_failed_proposals=max_failed_proposals, stop=stop, self_filter=self_filter,
            stop_while_moving=stop_while_moving)
        self.DeclareVectorInputPort("position_measured", 6)
        self.DeclareAbstractInputPort("tof_frame", AbstractValue.Make(ToFFrame.empty()))
        self.DeclareAbstractInputPort("X_WS", AbstractValue.Make(RigidTransform()))
        self.DeclareAbstractInputPort("map", AbstractValue.Make(None))
        self.DeclareAbstractInputPort("object", AbstractValue.Make(None))
        self.DeclareAbstractInputPort("box_estimate", AbstractValue.Make(EstimateTrack()))

        initial = self._sequencer.initial_state(q_initial, history)
        self._state_index = self.DeclareAbstractState(AbstractValue.Make(initial))
        state_ticket = {self.abstract_state_ticket(self._state_index)}
        self.DeclareVectorOutputPort("position_command", 6, self._CalcCommand,
                                     prerequisites_of_calc={self.time_ticket(), *state_ticket})
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

    def _state(self, context: Context) -> AcquisitionState:
        return context.get_abstract_state(self._state_index).get_value()

    def _CalcCommand(self, context: Context, output) -> None:
        output.SetFromVector(self._sequencer.command(self._state(context), context.get_time()))

    def _CalcAcquiredFrame(self, context: Context, output) -> None:
        acquisitions = self._state(context).log.acquisitions
        output.set_value(acquisitions[-1].frame if acquisitions else ToFFrame.empty())

    def _CalcAcquiredPose(self, context: Context, output) -> None:
        acquisitions = self._state(context).log.acquisitions
        output.set_value(RigidTransform(acquisitions[-1].X_WS) if acquisitions
                         else RigidTransform())

    def _CalcLog(self, context: Context, output) -> None:
        output.set_value(self._state(context).log)

    def _CalcPlan(self, context: Context, output) -> None:
        output.set_value(self._state(context).log.plan)

    def _Update(self, context: Context, state: State) -> EventStatus:
        current = self._state(context)
        if current.mode is Mode.DONE:
            return EventStatus.ReachedTermination(self, current.log.termination)
        s = self._sequencer.step(current, context.get_time(), _PortInputs(self, context))
        state.get_mutable_abstract_state(self._state_index).set_value(s)
        if s.mode is Mode.DONE:
            return EventStatus.ReachedTermination(self, s.log.termination)
        return EventStatus.Succeeded()
