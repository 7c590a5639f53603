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

Before each command the sender checks it (`SafetyLimits`): the controller's joint limits, the
sensor origin in the workspace box and above the table, joint speed and acceleration caps on
the step from the previous command, and the distance to the measured joints (the servo's lag
at the command's speed plus a small residual). It also checks the status the receiver read:
stops, reduced mode, speed scaling, a robot that is not running, a stopped control script or
a lost connection. Any of these stops the arm (unless the link is lost) and raises
`RobotFault`, whose message says what happened and what to do; so do ur_rtde's own errors
(an argument out of its range, a dead client). The Simulator passes the exception on to
whoever called `AdvanceTo`.
"""

from __future__ import annotations

import logging
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, DiscreteValues, LeafSystem

from lrnbv_drake.core.robot.safety import (
    RESUME_HINT,
    RobotFault,
    RobotInterface,
    SafetyLimits,
    Ur5eStatus,
    read_status,
)

_log = logging.getLogger(__name__)

#: servoJ's speed (rad/s) and acceleration (rad/s^2): the script ignores both, but ur_rtde
#: refuses values outside [0, 3.14] and [0, 40], so these are ur_rtde's own example values.
SERVOJ_SPEED = 0.5
SERVOJ_ACCELERATION = 0.5
#: How long a stopped script or a refused servoJ waits for the status to show why, seconds:
#: ur_rtde's control interface can hear that the script stopped before its receive interface
#: gets the package with the stop (a few packages; 0.05 s was too short on a loaded machine).
CAUSE_WAIT = 0.25
#: What to do after a refused command, by `Refusal.kind`.
REFUSAL_ADVICE = {
    "refused": ("The planner's trajectories keep the caps, so either a hardware.* limit is "
                "narrower than what the planner was allowed (joint limits, workspace, table "
                "clearance, speed fractions), or the diagram fell behind and raced: check the "
                "scenario against the cell"),
    "tracking": ("The arm does not follow the commands as servoJ should: look for a stop or "
                 "speed scaling on the pendant, another program moving the arm, or a start "
                 "pose the arm is not at"),
}


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
    servoStop(stop_deceleration) (m/s^2 at the tool) unless the link is lost, and raises
    `RobotFault`.
    """

    def __init__(self, robot: RobotInterface, limits: SafetyLimits, *, period: float = 0.008,
                 lookahead_time: float = 0.1, gain: float = 300.0,
                 stop_deceleration: float = 2.0, robot_ip: str = "the robot",
                 watchdog_hold: float = 60.0) -> None:
        super().__init__()
        self._robot = robot
        self._limits = limits
        self._period = period
        self._lookahead_time = lookahead_time
        self._gain = gain
        self._stop_deceleration = stop_deceleration
        self._robot_ip = robot_ip
        self._watchdog_hold = watchdog_hold
        # Wall time of the last servoJ the controller accepted (of the initialization before
        # the first): a refusal long after it means the driver stopped feeding the watchdog.
        self._last_accepted = time.monotonic()
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
        self._last_accepted = time.monotonic()

    def _Remember(self, context: Context, discrete_state: DiscreteValues) -> None:
        q = self._position_port.Eval(context)
        q_previous = context.get_discrete_state(self._sent_index).value()[:6]
        discrete_state.set_value(self._sent_index, np.r_[q, (q - q_previous) / self._period])

    def _Send(self, context: Context) -> None:
        status: Ur5eStatus = self._status_port.Eval(context)
        fault = status.fault(self._robot_ip)
        if fault is not None and fault.kind == "script_stopped":
            fault = self._cause(context.get_time(), status)
        if fault is not None:
            self._stop(listening=fault.kind != "disconnected")
            raise fault
        q = np.asarray(self._position_port.Eval(context), float)
        sent = context.get_discrete_state(self._sent_index).value()
        refusal = self._limits.check(q, sent[:6], sent[6:],
                                     status.q if status.current else None, self._period)
        if refusal is not None:
            self._stop(listening=True)
            raise RobotFault(refusal.kind, (
                f"refused the command at t = {context.get_time():.3f} s: {refusal.reason}. "
                f"The arm was stopped. {REFUSAL_ADVICE[refusal.kind]}, {RESUME_HINT}"))
        try:
            accepted = self._robot.servo_j(q.tolist(), SERVOJ_SPEED, SERVOJ_ACCELERATION,
                                           self._period, self._lookahead_time, self._gain)
        except ValueError as e:  # ur_rtde's range checks
            self._stop(listening=True)
            raise RobotFault("driver_error", (
                f"ur_rtde refused servoJ at t = {context.get_time():.3f} s: {e}. The arm was "
                f"stopped. Check hardware.servo_period, servo_lookahead_time and servo_gain "
                f"against ur_rtde's ranges, {RESUME_HINT}")) from e
        except RuntimeError as e:  # the client failed: the status names the cause
            fault = self._cause(context.get_time(), status)
            self._stop(listening=fault is None or fault.kind != "disconnected")
            raise fault or RobotFault("driver_error", (
                f"servoJ to {self._robot_ip} failed at t = {context.get_time():.3f} s: {e}. "
                f"Check the pendant, {RESUME_HINT}")) from e
        if not accepted:  # refused since the status was read: a stop just happened?
            silence = time.monotonic() - self._last_accepted
            fault = self._cause(context.get_time(), status)
            self._stop(listening=fault is None or fault.kind != "disconnected")
            if fault is not None and fault.kind != "script_stopped":
                raise fault
            raise RobotFault("script_stopped", self._refusal(silence))
        self._last_accepted = time.monotonic()

    def _refusal(self, silence: float) -> str:
        """Why servoJ was refused with no stop on the status: the script is not running,
        and, if nothing was sent for `silence` s, longer than the driver feeds the watchdog,
        why."""
        text = (f"{self._robot_ip} did not accept servoJ: ur_rtde's control script is not "
                f"executing commands.")
        if silence > self._watchdog_hold:
            text += (f" The diagram sent nothing for {silence:.1f} s, longer than "
                     f"hardware.watchdog_hold ({self._watchdog_hold:g} s), so the RTDE "
                     f"watchdog stopped the script: one step of the diagram (planning, the box "
                     f"estimate) took that long. Run on a PC that has the cores to itself, or "
                     f"raise hardware.watchdog_hold.")
        return f"{text} Check the pendant, {RESUME_HINT}"

    def _cause(self, time_now: float, status: Ur5eStatus) -> RobotFault | None:
        """The fault behind a stopped script or a servoJ that failed: the status read again
        until it names one other than the stopped script, for at most CAUSE_WAIT."""
        deadline = time.monotonic() + CAUSE_WAIT
        while True:
            status = read_status(self._robot, time_now, status)
            fault = status.fault(self._robot_ip)
            if (fault is not None and fault.kind != "script_stopped") \
                    or time.monotonic() > deadline:
                return fault
            time.sleep(0.002)

    def _stop(self, listening: bool) -> None:
        """Orders a stop; a stop that cannot be delivered is logged, not raised, so that the
        fault that caused it is what the caller sees. servoStop's deceleration is the tool's,
        m/s^2 (the script runs stopl)."""
        if not listening:
            return
        try:
            self._robot.servo_stop(self._stop_deceleration)
        except (RuntimeError, ValueError) as e:
            _log.warning("servoStop on %s failed: %s", self._robot_ip, e)
