"""`Ur5eCommandSender`: the diagram's joint commands sent to the UR5e as servoJ targets, like
Drake's LcmPublisherSystem; `Ur5eStatusReceiver` reads the controller in periodic state
updates, this one commands it from periodic publish events. No output calculation ever touches
the network.

Commands are paced `servoJ` targets sampled from the `ur5e.position` input every
`servo_period`. servoJ, not moveJ, because the planner's trajectory is what was checked for
collisions: servoJ follows it point by point (waypoints through home included) at the
planner's speed, so the arm stops when the planner thinks it does (plus the servo's lag). A
moveJ to each held position would start only once the whole trajectory has been played,
would cut straight to the last waypoint of a multi-segment path, and could not be stopped
part way by a blocking call.

Before each command the sender checks it (`SafetyLimits`): joint limits, the sensor origin in
the workspace box and above the table, joint speed and acceleration caps on the step from the
previous command, and the distance to the measured joints. It also checks the status the
receiver read: protective stop, emergency stop, safeguard stop, a robot that is not running,
a stopped control script or a lost connection. Any of these stops the arm (when the
controller still listens) and raises `RobotFault`, whose message says what happened and what
to do; the Simulator passes the exception on to whoever called `AdvanceTo`.
"""

from __future__ import annotations

import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, DiscreteValues, LeafSystem

from lrnbv_drake.core.robot_safety import (
    RESUME_HINT,
    RobotFault,
    RobotInterface,
    SafetyLimits,
    Ur5eStatus,
    read_status,
)

_log = logging.getLogger(__name__)


class Ur5eCommandSender(LeafSystem):
    """Sends the `position` input to the UR5e as paced servoJ targets, like Drake's
    LcmPublisherSystem, after checking the robot and the command.

    @system
    name: Ur5eCommandSender
    input_ports:
    - position
    - status
    @endsystem

    A periodic publish event (every `period`) checks the `status` input (a `Ur5eStatus`) and
    the command against `limits`, then calls servoJ(q, ..., time=period, lookahead_time, gain);
    when servoJ is refused, a fresh status reading names the cause.
    A periodic discrete update at the same times stores the command just sent and its speed:
    the next publish measures its step against them (an initialization event starts them at
    the measured joints, at rest). A fault or a refused command stops the arm with
    servoStop(stop_deceleration) when the controller still listens, and raises `RobotFault`.
    """

    def __init__(self, robot: RobotInterface, limits: SafetyLimits, *, period: float = 0.008,
                 lookahead_time: float = 0.1, gain: float = 300.0,
                 stop_deceleration: float = 2.0, robot_ip: str = "the robot") -> None:
        super().__init__()
        self._robot = robot
        self._limits = limits
        self._period = period
        self._lookahead_time = lookahead_time
        self._gain = gain
        self._stop_deceleration = stop_deceleration
        self._robot_ip = robot_ip
        # servoJ ignores speed and acceleration, but ur_rtde checks them against [0, 3.14]
        # and [0, 40]: pass the caps.
        self._speed = float(np.max(limits.max_velocity))
        self._acceleration = float(np.max(limits.max_acceleration))
        self._position_port = self.DeclareVectorInputPort("position", 6)
        self._status_port = self.DeclareAbstractInputPort(
            "status", AbstractValue.Make(Ur5eStatus()))
        # The last command sent and its speed.
        self._sent_index = self.DeclareDiscreteState(12)
        self.DeclareInitializationDiscreteUpdateEvent(self._Start)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._Remember)
        self.DeclarePeriodicPublishEvent(period, 0.0, self._Send)

    def _Start(self, context: Context, discrete_state: DiscreteValues) -> None:
        status: Ur5eStatus = self._status_port.Eval(context)
        discrete_state.set_value(self._sent_index, np.r_[status.q, np.zeros(6)])

    def _Remember(self, context: Context, discrete_state: DiscreteValues) -> None:
        q = self._position_port.Eval(context)
        q_previous = context.get_discrete_state(self._sent_index).value()[:6]
        discrete_state.set_value(self._sent_index, np.r_[q, (q - q_previous) / self._period])

    def _Send(self, context: Context) -> None:
        status: Ur5eStatus = self._status_port.Eval(context)
        fault = status.fault(self._robot_ip)
        if fault is not None:
            self._stop(listening=fault.kind != "disconnected")
            raise fault
        q = np.asarray(self._position_port.Eval(context), float)
        sent = context.get_discrete_state(self._sent_index).value()
        reason = self._limits.check(q, sent[:6], sent[6:], status.q, self._period)
        if reason is not None:
            self._stop(listening=True)
            raise RobotFault("refused", (
                f"refused the command at t = {context.get_time():.3f} s: {reason}. The arm "
                f"was stopped. The planner should never produce such a command: check the "
                f"scenario (workspace, table height, speed fractions) against the cell, and "
                f"hardware.* caps against the planner's, before resuming"))
        if not self._robot.servo_j(q.tolist(), self._speed, self._acceleration, self._period,
                                   self._lookahead_time, self._gain):
            # Refused since the status was read (a stop just happened?): read it again for the
            # specific cause.
            fault = read_status(self._robot, context.get_time(), status).fault(self._robot_ip)
            if fault is not None and fault.kind != "script_stopped":
                raise fault
            raise RobotFault("script_stopped", (
                f"{self._robot_ip} did not accept servoJ: ur_rtde's control script is not "
                f"executing commands. Check the pendant, {RESUME_HINT}"))

    def _stop(self, listening: bool) -> None:
        """Orders a stop; a stop that cannot be delivered is logged, not raised, so that the
        fault that caused it is what the caller sees."""
        if not listening:
            return
        try:
            self._robot.servo_stop(self._stop_deceleration)
        except RuntimeError as e:
            _log.warning("servoStop on %s failed: %s", self._robot_ip, e)
