"""The frame gate: which frames from the real sensor may be used, and when they began.

Frames from the board carry the MCU's clock, which has nothing to do with the cell's, and a
frame may have been integrated while the arm still moved (servoJ lags the command). A new frame
(a new sequence and board timestamp) first seen at time t was integrated within
[t - latency, t]. The gate passes it, stamped t - latency (the earliest its integration can
have started), only if no joint moved faster than `still_speed` within that window; frames
from a moving arm are counted as seen but never passed. It also measures the silence since the
last new frame, so its caller can stop when the sensor has gone quiet.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np

from lrnbv_drake.core.sensing.sensor import ToFFrame


@dc.dataclass(frozen=True)
class GateState:
    # (sequence, board timestamp) of the last frame seen, None before the first.
    last_key: tuple[int, int] | None
    # Time the last new frame (or the start) was seen at.
    t_new: float
    # Last time the arm was seen moving.
    t_moving: float


@dc.dataclass(frozen=True)
class GateResult:
    state: GateState
    # The frame to use, re-stamped; None when nothing new may be used.
    frame: ToFFrame | None
    # Seconds without a new frame, and whether that exceeds the allowed silence.
    silence: float
    timed_out: bool


@dc.dataclass(frozen=True)
class FrameGate:
    """The gate's parameters; `update` is a pure function of its arguments."""

    latency: float
    still_speed: float
    timeout: float
    # Allowed silence before the first frame (a board may reset when its port opens).
    first_timeout: float

    @staticmethod
    def start(t: float) -> GateState:
        """The state at time t; the arm may have moved just before, so it counts as moving."""
        return GateState(None, t, t)

    def update(self, state: GateState, t: float, frame: ToFFrame,
               joint_speeds: np.ndarray) -> GateResult:
        """Looks at the sensor's current `frame` and the arm's `joint_speeds` at time t."""
        # Still only if every speed is known to be low: a NaN speed counts as moving.
        moving = not bool(np.all(np.abs(joint_speeds) <= self.still_speed))
        t_moving = t if moving else state.t_moving
        key = (frame.sequence, frame.timestamp_us)
        if frame.sequence != 0 and key != state.last_key:
            passed = None
            if t_moving < t - self.latency:
                passed = dc.replace(frame, timestamp_us=round((t - self.latency) * 1e6))
            return GateResult(GateState(key, t, t_moving), passed, 0.0, False)
        silence = t - state.t_new
        allowed = self.timeout if state.last_key else self.first_timeout
        return GateResult(GateState(state.last_key, state.t_new, t_moving), None, silence,
                          silence > allowed)
