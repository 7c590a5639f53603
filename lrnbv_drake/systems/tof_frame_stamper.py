"""`ToFFrameStamper`: the serial sensor's frames on the diagram's clock, without those the arm
may have moved during; a thin wrapper of `core.sensing.frame_gate.FrameGate`."""

from __future__ import annotations

from collections.abc import Callable

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem, State

from lrnbv_drake.core.sensing.frame_gate import FrameGate, GateState
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.drivers.tof_serial import SensorTimeout


class ToFFrameStamper(LeafSystem):
    """Re-stamps the serial sensor's frames with diagram time and drops those the arm may have
    moved during.

    @system
    name: ToFFrameStamper
    input_ports:
    - tof_frame
    - velocity
    output_ports:
    - tof_frame
    @endsystem

    Every `period` an unrestricted update passes the `tof_frame` input and the joint
    `velocity` (6) through the gate (`FrameGate.update`); the output (state) becomes each frame
    the gate passes. An initialization event starts the gate with the arm counted as moving.

    Raises SensorTimeout from the update when no new frame came for `timeout` seconds
    (`first_timeout` before the first frame); `diagnose()` adds what the driver knows.
    """

    def __init__(self, *, period: float, latency: float, still_speed: float, timeout: float,
                 first_timeout: float | None = None, resolution: int = 8,
                 diagnose: Callable[[], str] = lambda: "") -> None:
        super().__init__()
        self._gate = FrameGate(latency=latency, still_speed=still_speed, timeout=timeout,
                               first_timeout=timeout if first_timeout is None else first_timeout)
        self._diagnose = diagnose
        self._frame_port = self.DeclareAbstractInputPort(
            "tof_frame", AbstractValue.Make(ToFFrame.empty(resolution)))
        self._velocity_port = self.DeclareVectorInputPort("velocity", 6)
        self._frame_index = self.DeclareAbstractState(
            AbstractValue.Make(ToFFrame.empty(resolution)))
        self._gate_index = self.DeclareAbstractState(AbstractValue.Make(FrameGate.start(0.0)))
        self.DeclareInitializationUnrestrictedUpdateEvent(self._Start)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._Update)
        self.DeclareStateOutputPort("tof_frame", self._frame_index)

    def _Start(self, context: Context, state: State) -> None:
        state.get_mutable_abstract_state(self._gate_index).set_value(
            FrameGate.start(context.get_time()))

    def _Update(self, context: Context, state: State) -> None:
        gate_state: GateState = context.get_abstract_state(self._gate_index).get_value()
        result = self._gate.update(gate_state, context.get_time(),
                                   self._frame_port.Eval(context),
                                   self._velocity_port.Eval(context))
        if result.timed_out:
            details = self._diagnose()
            raise SensorTimeout(
                f"no new frame from the ToF sensor for {result.silence:.1f} s"
                + (f" ({details})" if details else "")
                + ". Check the board's USB cable and that it streams (`lrnbv sensor stream "
                  "--port PORT`), then continue with `lrnbv hardware --resume OUT_DIR`")
        state.get_mutable_abstract_state(self._gate_index).set_value(result.state)
        if result.frame is not None:
            state.get_mutable_abstract_state(self._frame_index).set_value(result.frame)
