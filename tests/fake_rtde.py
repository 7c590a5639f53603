"""Fakes of ur_rtde's `rtde_control` and `rtde_receive` modules around one simulated arm.

`install(monkeypatch, arm)` puts them in `sys.modules`, so `RtdeRobot` imports them as it would
the real wheel. Only the calls the drivers use exist, with the wheel's signatures: `servoJ`
takes positional arguments only, and connecting to an unreachable host raises RuntimeError
with ur_rtde's message.
"""

from __future__ import annotations

import dataclasses as dc
import sys
import threading
import time
import types
from collections.abc import Callable

import numpy as np

from lrnbv_drake.core.robot_safety import tcp_pose_from_q


@dc.dataclass
class Call:
    name: str
    args: tuple
    wall_time: float


class FakeArm:
    """A UR5e whose joints follow the latest servoJ target with a first-order lag (time
    constant `tau`, wall clock), like a servo with lookahead smoothing. The flags are what
    the receive interface reports; tests flip them to inject faults. `on_servo(arm, q)` runs
    on every servoJ call."""

    def __init__(self, q, tau: float = 0.02) -> None:
        self.lock = threading.Lock()
        self.q = np.array(q, float)
        self.target = self.q.copy()
        self.tau = tau
        self._last = time.monotonic()
        self._started = self._last
        self.calls: list[Call] = []
        self.connections: list[tuple[str, tuple]] = []
        self.unreachable: set[str] = set()
        self.protective_stop = False
        self.emergency_stop = False
        self.connected = True
        self.program_running = True
        self.robot_mode = 7
        self.safety_mode = 1
        self.frozen_timestamp: float | None = None
        self.on_servo: Callable[[FakeArm, np.ndarray], None] | None = None

    def _advance(self) -> None:
        now = time.monotonic()
        alpha = 1.0 - np.exp(-(now - self._last) / self.tau)
        self.q += (self.target - self.q) * alpha
        self._last = now

    def read(self, what: str):
        with self.lock:
            self._advance()
            if what == "q":
                return self.q.tolist()
            if what == "qd":
                return ((self.target - self.q) / self.tau).tolist()
            return tcp_pose_from_q(self.q).tolist()

    def timestamp(self) -> float:
        if self.frozen_timestamp is not None:
            return self.frozen_timestamp
        return time.monotonic() - self._started

    def record(self, name: str, *args) -> None:
        with self.lock:
            self.calls.append(Call(name, args, time.monotonic()))

    def servo(self, q, *settings) -> bool:
        q = np.array(q, float)
        self.record("servoJ", q, *settings)
        if self.on_servo is not None:
            self.on_servo(self, q)
        if not self.program_running or self.protective_stop or self.emergency_stop:
            return False
        with self.lock:
            self._advance()
            self.target = q
        return True

    def stop(self) -> None:
        with self.lock:
            self._advance()
            self.target = self.q.copy()

    def servo_targets(self) -> list[np.ndarray]:
        with self.lock:
            return [c.args[0] for c in self.calls if c.name == "servoJ"]


def _connect(arm: FakeArm, kind: str, hostname: str, *args) -> None:
    if hostname in arm.unreachable:
        raise RuntimeError(f"Error: Could not connect to: {hostname} at 30004, verify the IP")
    arm.connections.append((kind, (hostname, *args)))


def make_modules(arm: FakeArm) -> tuple[types.ModuleType, types.ModuleType]:
    """(rtde_control, rtde_receive) bound to `arm`."""

    class RTDEControlInterface:
        def __init__(self, hostname, frequency=-1.0, flags=1, ur_cap_port=50002,
                     rt_priority=0):
            _connect(arm, "control", hostname, frequency, flags)

        def servoJ(self, q, speed, acceleration, time, lookahead_time, gain, /):
            return arm.servo(q, speed, acceleration, time, lookahead_time, gain)

        def servoStop(self, a=10.0):
            arm.record("servoStop", a)
            arm.stop()
            return True

        def stopScript(self):
            arm.record("stopScript")

        def disconnect(self):
            arm.record("disconnect-control")

        def isConnected(self):
            return arm.connected

        def isProgramRunning(self):
            return arm.program_running

    class RTDEReceiveInterface:
        def __init__(self, hostname, frequency=-1.0, variables=(), verbose=False,
                     use_upper_range_registers=False, rt_priority=0):
            _connect(arm, "receive", hostname, frequency, use_upper_range_registers)

        def getActualQ(self):
            return arm.read("q")

        def getActualQd(self):
            return arm.read("qd")

        def getActualTCPPose(self):
            return arm.read("tcp")

        def getTimestamp(self):
            return arm.timestamp()

        def getRobotMode(self):
            return arm.robot_mode

        def getSafetyMode(self):
            return arm.safety_mode

        def isProtectiveStopped(self):
            return arm.protective_stop

        def isEmergencyStopped(self):
            return arm.emergency_stop

        def isConnected(self):
            return arm.connected

        def disconnect(self):
            arm.record("disconnect-receive")

    control = types.ModuleType("rtde_control")
    control.RTDEControlInterface = RTDEControlInterface
    receive = types.ModuleType("rtde_receive")
    receive.RTDEReceiveInterface = RTDEReceiveInterface
    return control, receive


def install(monkeypatch, arm: FakeArm) -> None:
    """Makes `import rtde_control` / `import rtde_receive` give the fakes around `arm`."""
    control, receive = make_modules(arm)
    monkeypatch.setitem(sys.modules, "rtde_control", control)
    monkeypatch.setitem(sys.modules, "rtde_receive", receive)
