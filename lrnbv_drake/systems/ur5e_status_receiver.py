"""`Ur5eStatusReceiver`: the UR5e's state read into the diagram, like Drake's LcmSubscriber."""

from __future__ import annotations

import contextlib

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem, State

from lrnbv_drake.core.robot.safety import RobotInterface, Ur5eStatus, read_status


class Ur5eStatusReceiver(LeafSystem):
    """Reads the UR5e's state into the context, like Drake's LcmSubscriberSystem.

    @system
    name: Ur5eStatusReceiver
    output_ports:
    - position_measured
    - velocity_estimated
    - status
    @endsystem

    An initialization event and a periodic unrestricted update (every `period`) read the
    controller (`read_status`) into state; the outputs are that state. `position_measured` (6)
    and `velocity_estimated` (6) are the actual joints and speeds; `status` is the whole
    `Ur5eStatus`. The receiver reports faults; the command sender acts on them.

    Each read also kicks the control script's RTDE watchdog (`RobotInterface.kick_watchdog`):
    the reads run at rest and in motion alike, so the watchdog hears from the diagram as long
    as it runs, and stops the script when it does not (the driver covers a held diagram, such
    as a planning step, for `hardware.watchdog_hold`).
    """

    def __init__(self, robot: RobotInterface, period: float = 0.008,
                 rtde_timeout: float = 0.5) -> None:
        super().__init__()
        self._robot = robot
        self._rtde_timeout = rtde_timeout
        self._q_index = self.DeclareDiscreteState(6)
        self._qd_index = self.DeclareDiscreteState(6)
        self._status_index = self.DeclareAbstractState(AbstractValue.Make(Ur5eStatus()))
        self.DeclareInitializationUnrestrictedUpdateEvent(self._Read)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._Read)
        self.DeclareStateOutputPort("position_measured", self._q_index)
        self.DeclareStateOutputPort("velocity_estimated", self._qd_index)
        self.DeclareStateOutputPort("status", self._status_index)

    def _Read(self, context: Context, state: State) -> None:
        status = read_status(self._robot, context.get_time(),
                             context.get_abstract_state(self._status_index).get_value(),
                             self._rtde_timeout)
        with contextlib.suppress(RuntimeError):  # the client is gone: the next read says so
            self._robot.kick_watchdog()
        state.get_mutable_abstract_state(self._status_index).set_value(status)
        discrete = state.get_mutable_discrete_state()
        discrete.set_value(self._q_index, status.q)
        discrete.set_value(self._qd_index, status.qd)
