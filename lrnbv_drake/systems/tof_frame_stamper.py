"""`ToFFrameStamper`: the serial sensor's frames on the diagram's clock, without those the arm
may have moved during.

Frames from the board carry the MCU's clock, which has nothing to do with the diagram's, and a
frame may have been integrated while the arm still moved (servoJ lags the command).
"""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem, State

from lrnbv_drake.core.sensor import ToFFrame
from lrnbv_drake.drivers.tof_serial import SensorTimeout


@dc.dataclass
class _StamperState:
    # (sequence, board timestamp) of the last frame seen, None before the first.
    last_key: tuple[int, int] | None
    # Diagram time the last new frame (or the start) was seen at.
    t_new: float
    # Last diagram time the arm was seen moving.
    t_moving: float


class ToFFrameStamper(LeafSystem):
    """Re-stamps the serial sensor's frames with diagram time and drops those the arm may have
    moved during.

    @system
    name: ToFFrameStamper
    input_ports:
    - tof_frame
    - velocity
    @endsystem

    Output port `tof_frame` (state). Every `period` an unrestricted update looks at the input:
    a new frame (a new sequence and board timestamp) seen at time t was integrated within
    [t - latency, t]; unless the arm moved (some joint faster than `still_speed` on the
    `velocity` input) within that window, the output becomes the frame stamped t - latency,
    the earliest its integration can have started. Frames from a moving arm are counted as
    seen but never output.

    Raises SensorTimeout from the update when no new frame came for `timeout` seconds
    (`first_timeout` before the first frame); `diagnose()` adds what the driver knows.
    """

    def __init__(self, *, period: float, latency: float, still_speed: float, timeout: float,
                 first_timeout: float | None = None, resolution: int = 8,
                 diagnose: Callable[[], str] = lambda: "") -> None:
        super().__init__()
        self._latency = latency
        self._still_speed = still_speed
        self._timeout = timeout
        self._first_timeout = timeout if first_timeout is None else first_timeout
        self._diagnose = diagnose
        self._frame_port = self.DeclareAbstractInputPort(
            "tof_frame", AbstractValue.Make(ToFFrame.empty(resolution)))
        self._velocity_port = self.DeclareVectorInputPort("velocity", 6)
        self._frame_index = self.DeclareAbstractState(
            AbstractValue.Make(ToFFrame.empty(resolution)))
        self._book_index = self.DeclareAbstractState(
            AbstractValue.Make(_StamperState(None, 0.0, 0.0)))
        self.DeclareInitializationUnrestrictedUpdateEvent(self._Start)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._Update)
        self.DeclareStateOutputPort("tof_frame", self._frame_index)

    def _Start(self, context: Context, state: State) -> None:
        # The arm may have moved just before the diagram started: treat it as moving then.
        t = context.get_time()
        state.get_mutable_abstract_state(self._book_index).set_value(_StamperState(None, t, t))

    def _Update(self, context: Context, state: State) -> None:
        t = context.get_time()
        book: _StamperState = dc.replace(context.get_abstract_state(self._book_index).get_value())
        if np.max(np.abs(self._velocity_port.Eval(context))) > self._still_speed:
            book.t_moving = t
        frame: ToFFrame = self._frame_port.Eval(context)
        key = (frame.sequence, frame.timestamp_us)
        if frame.sequence != 0 and key != book.last_key:
            book.last_key, book.t_new = key, t
            if book.t_moving < t - self._latency:
                stamped = dc.replace(frame, timestamp_us=round((t - self._latency) * 1e6))
                state.get_mutable_abstract_state(self._frame_index).set_value(stamped)
        elif t - book.t_new > (self._timeout if book.last_key else self._first_timeout):
            details = self._diagnose()
            raise SensorTimeout(
                f"no new frame from the ToF sensor for {t - book.t_new:.1f} s"
                + (f" ({details})" if details else "")
                + ". Check the board's USB cable and that it streams (`lrnbv sensor stream "
                  "--port PORT`), then continue with `lrnbv hardware --resume OUT_DIR`")
        state.get_mutable_abstract_state(self._book_index).set_value(book)
