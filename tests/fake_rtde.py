"""Fakes of ur_rtde's `rtde_control`, `rtde_receive` and `dashboard_client` modules around one
simulated arm, for fast tests (tests/ur_emulator runs the real client against an emulated
controller).

`install(monkeypatch, arm)` puts them in `sys.modules` and runs `RtdeRobot`'s client
(`drivers/rtde_client.serve`) in a thread of the test process instead of a child process, so
the driver talks to them over the same pipes as to the real wheel. They behave as ur_rtde
1.6.5 does against a controller (docs: ../shared/notes/ur-rtde-controller.md, checked against
the emulator):

- `servoJ` takes positional arguments only and range-checks speed [0, 3.14], acceleration
  [0, 40], lookahead time [0.03, 0.2] and gain [100, 2000] (ValueError; the joints are not
  checked); connecting to an unreachable host raises RuntimeError with ur_rtde's message;
- after `arm.drop_link()` (a cable pulled, a controller frozen) the getters keep returning the
  last package, the controller's clock included; `isConnected()` turns false only
  `NOTICE_DELAY` later; `servoJ` still returns True and does nothing; `servoStop`,
  `stopScript` and `disconnect` block (for `arm.block_seconds`, so a test that calls them
  is slow rather than stuck);
- a stopped script or a stop makes `servoJ` and `servoStop` return False at once.
"""

from __future__ import annotations

import contextlib
import dataclasses as dc
import itertools
import os
import sys
import threading
import time
import types
from collections.abc import Callable

import numpy as np

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.safety import SafetyLimits, Ur5eStatus, tcp_pose_from_q
from lrnbv_drake.drivers import rtde_client, rtde_robot

#: How late ur_rtde's isConnected() notices a silent drop, seconds.
NOTICE_DELAY = 2.5


#: The servo period the robot tests use, seconds.
PERIOD = 0.008
# tool0 -> sensor and world -> base of the shipped cell are not needed to test the joint
# checks: identity frames and a box that holds every reachable sensor position.
WIDE_OPEN = dict(X_W_base=np.eye(4), X_tool0_S=np.eye(4), workspace_lower=np.full(3, -2.0),
                 workspace_upper=np.full(3, 2.0), min_sensor_z=-2.0)


def open_limits(speed=0.6, acceleration=0.6, jump=0.002, **overrides) -> SafetyLimits:
    """The command checks with the model's joint limits and the caps as fractions, in a
    workspace that holds every reachable sensor position (for the robot tests)."""
    args = dict(joint_lower=np.asarray(kinematics.JOINT_LOWER),
                joint_upper=np.asarray(kinematics.JOINT_UPPER),
                max_velocity=kinematics.VELOCITY_LIMIT * speed,
                max_acceleration=kinematics.ACCELERATION_LIMIT * acceleration,
                jump_tolerance=jump, tracking_lag=0.1, max_tracking_error=0.05, **WIDE_OPEN)
    args.update(overrides)
    return SafetyLimits(**args)


def ok_status(q=kinematics.HOME, **changes) -> Ur5eStatus:
    """A reading of a controller that lets the arm move, with `changes` (for the robot
    tests)."""
    fields = dict(q=np.asarray(q, float), connected=True, program_running=True, robot_mode=7,
                  safety_mode=1, controller_time=1.0, speed_scaling=1.0,
                  target_speed_fraction=1.0)
    fields.update(changes)
    return Ur5eStatus(**fields)


@dc.dataclass
class Call:
    name: str
    args: tuple
    wall_time: float


def _within(value: float, low: float, high: float) -> None:
    if value < low or value > high:  # NaN passes, as in ur_rtde
        raise ValueError(f"The value is not within [{low:g};{high:g}]")


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
        self.program_running = True
        self.robot_mode = 7
        self.safety_mode = 1
        self.speed_scaling = 1.0
        self.target_speed_fraction = 1.0
        self.dropped_at: float | None = None
        self.block_seconds = 5.0
        self.on_servo: Callable[[FakeArm, np.ndarray], None] | None = None
        self._stale: dict[str, list[float]] = {}
        # One per client `RtdeRobot` started: ends it as a crash of its process would.
        self.client_crashes: list[Callable[[], None]] = []

    def crash_client(self) -> None:
        """The latest ur_rtde client dies (a segfault in the wheel): its pipes close."""
        self.client_crashes[-1]()

    def drop_link(self) -> None:
        """The link goes silent: from now on the client sees the last package."""
        with self.lock:
            self._advance()
            self._stale = {"q": self.q.tolist(), "qd": self._qd().tolist(),
                           "tcp": tcp_pose_from_q(self.q).tolist(),
                           "timestamp": [time.monotonic() - self._started]}
            self.dropped_at = time.monotonic()

    @property
    def dropped(self) -> bool:
        return self.dropped_at is not None

    def connected(self) -> bool:
        return self.dropped_at is None or time.monotonic() - self.dropped_at < NOTICE_DELAY

    def _advance(self) -> None:
        now = time.monotonic()
        alpha = 1.0 - np.exp(-(now - self._last) / self.tau)
        self.q += (self.target - self.q) * alpha
        self._last = now

    def _qd(self) -> np.ndarray:
        return (self.target - self.q) / self.tau

    def read(self, what: str):
        with self.lock:
            if self.dropped:
                return list(self._stale[what])
            self._advance()
            if what == "q":
                return self.q.tolist()
            if what == "qd":
                return self._qd().tolist()
            return tcp_pose_from_q(self.q).tolist()

    def timestamp(self) -> float:
        if self.dropped:
            return self._stale["timestamp"][0]
        return time.monotonic() - self._started

    def record(self, name: str, *args) -> None:
        with self.lock:
            self.calls.append(Call(name, args, time.monotonic()))

    def block_if_dropped(self) -> None:
        """What a waiting call does on a dead link: it waits (here `block_seconds`)."""
        if self.dropped:
            time.sleep(self.block_seconds)

    def servo(self, q, *settings) -> bool:
        q = np.array(q, float)
        self.record("servoJ", q, *settings)
        if self.on_servo is not None:
            self.on_servo(self, q)
        if self.dropped:
            return True  # nothing reaches the controller, and nothing says so
        if not self.program_running or self.protective_stop or self.emergency_stop:
            return False
        with self.lock:
            self._advance()
            self.target = q
        return True

    def stop(self) -> bool:
        self.block_if_dropped()
        if not self.program_running or self.protective_stop or self.emergency_stop:
            return False
        with self.lock:
            self._advance()
            self.target = self.q.copy()
        return True

    def names(self) -> list[str]:
        with self.lock:
            return [c.name for c in self.calls]


def _connect(arm: FakeArm, kind: str, hostname: str, *args) -> None:
    if hostname in arm.unreachable:
        raise RuntimeError(f"Error: Could not connect to: {hostname} at 30004, verify the IP")
    arm.connections.append((kind, (hostname, *args)))


def make_modules(arm: FakeArm) -> dict[str, types.ModuleType]:
    """rtde_control, rtde_receive and dashboard_client bound to `arm`, by name."""

    class RTDEControlInterface:
        def __init__(self, hostname, frequency=-1.0, flags=1, ur_cap_port=50002,
                     rt_priority=0):
            _connect(arm, "control", hostname, frequency, flags)

        def servoJ(self, q, speed, acceleration, time, lookahead_time, gain, /):
            _within(speed, 0.0, 3.14)
            _within(acceleration, 0.0, 40.0)
            _within(lookahead_time, 0.03, 0.2)
            _within(gain, 100.0, 2000.0)
            return arm.servo(q, speed, acceleration, time, lookahead_time, gain)

        def servoStop(self, a=10.0):
            arm.record("servoStop", a)
            return arm.stop()

        def setWatchdog(self, min_frequency=10.0):
            arm.record("setWatchdog", min_frequency)
            return arm.program_running  # a command to a stopped script fails

        def kickWatchdog(self):
            arm.record("kickWatchdog")
            return True

        def stopScript(self):
            arm.record("stopScript")
            arm.block_if_dropped()

        def disconnect(self):
            arm.record("disconnect-control")
            arm.block_if_dropped()

        def isConnected(self):
            return arm.connected()

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

        def getSpeedScaling(self):
            return arm.speed_scaling

        def getTargetSpeedFraction(self):
            return arm.target_speed_fraction

        def isProtectiveStopped(self):
            return arm.protective_stop

        def isEmergencyStopped(self):
            return arm.emergency_stop

        def isConnected(self):
            return arm.connected()

        def disconnect(self):
            arm.record("disconnect-receive")
            arm.block_if_dropped()

    class DashboardClient:
        def __init__(self, hostname, port=29999, verbose=False):
            self.hostname = hostname

        def connect(self, timeout_ms=2000):
            arm.block_if_dropped()
            _connect(arm, "dashboard", self.hostname)

        def stop(self):
            arm.record("dashboard-stop")
            arm.program_running = False

        def disconnect(self):
            arm.record("disconnect-dashboard")

    modules = {name: types.ModuleType(name)
               for name in ("rtde_control", "rtde_receive", "dashboard_client")}
    modules["rtde_control"].RTDEControlInterface = RTDEControlInterface
    modules["rtde_receive"].RTDEReceiveInterface = RTDEReceiveInterface
    modules["dashboard_client"].DashboardClient = DashboardClient
    return modules


def spawn_in_thread(arm: FakeArm) -> rtde_robot.ClientLink:
    """`rtde_robot.spawn_client`, with the client in a thread of this process (where the
    fake modules are), over the same kind of pipes; `arm.crash_client()` ends it."""
    requests, to_client = os.pipe()
    from_client, answers = os.pipe()
    request_file, answer_file = os.fdopen(requests, "rb"), os.fdopen(answers, "wb")

    crashed: list[bool] = []

    def run() -> None:
        with contextlib.suppress(OSError, ValueError):  # the test side closed its ends
            # A crashed client reads no further request.
            rtde_client.serve(itertools.takewhile(lambda line: not crashed, request_file),
                              answer_file)
        for file in (request_file, answer_file):
            with contextlib.suppress(OSError):
                file.close()

    thread = threading.Thread(target=run, name="fake ur_rtde client", daemon=True)
    thread.start()
    closed = []

    def crash() -> None:  # its answers end, and a line wakes it to end its thread and keeper
        crashed.append(True)
        with contextlib.suppress(OSError):
            answer_file.close()
        with contextlib.suppress(OSError):  # one line, atomic beside the driver's requests
            os.write(to_client, b"\n")
        thread.join(timeout=5.0)
    arm.client_crashes.append(crash)

    def kill() -> None:
        if not closed:
            closed.append(True)
            os.close(to_client)
            os.close(from_client)

    return rtde_robot.ClientLink(
        to_client, from_client, kill,
        lambda: "crashed" if crashed else None if thread.is_alive() else "ended")


def install(monkeypatch, arm: FakeArm) -> None:
    """Makes `import rtde_control` (and the others) give the fakes around `arm`, and
    `RtdeRobot` run its client in this process."""
    for name, module in make_modules(arm).items():
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setattr(rtde_robot, "spawn_client", lambda: spawn_in_thread(arm))

