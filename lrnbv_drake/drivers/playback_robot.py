"""A robot that is not there, for the dry run."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import numpy as np

from lrnbv_drake.core.robot.safety import ROBOT_MODE_RUNNING, RobotReading, tcp_pose_from_q


class PlaybackRobot:
    """A robot that is not there: each servoJ target becomes the measured position at once.

    The dry run drives the hardware diagram with it, so every command still goes through the
    sender's checks and Meshcat shows exactly the commanded motion. The velocity is the last
    step over servoJ's `time`; the TCP pose is the forward kinematics of `tool0` in `base`.
    Thread-safe: the simulated sensor board reads the joints from its own thread.
    """

    def __init__(self, q: Sequence[float]) -> None:
        self._lock = threading.Lock()
        self._q = np.array(q, float)
        self._qd = np.zeros(6)
        self._started = time.monotonic()

    def read(self) -> RobotReading:
        with self._lock:
            q, qd = self._q.copy(), self._qd.copy()
        return RobotReading(q=q, qd=qd, tcp_pose=tcp_pose_from_q(q),
                            controller_time=time.monotonic() - self._started,
                            robot_mode=ROBOT_MODE_RUNNING, safety_mode=1,
                            protective_stop=False, emergency_stop=False, connected=True,
                            program_running=True, speed_scaling=1.0,
                            target_speed_fraction=1.0)

    def kick_watchdog(self) -> None:
        """No controller, no watchdog."""

    def servo_j(self, q: Sequence[float], speed: float, acceleration: float, time: float,
                lookahead_time: float, gain: float) -> bool:
        with self._lock:
            q = np.array(q, float)
            self._qd = (q - self._q) / time
            self._q = q
        return True

    def servo_stop(self, deceleration: float) -> bool:
        """The arm is where the last command put it: the velocity drops to zero."""
        with self._lock:
            self._qd = np.zeros(6)
        return True

    def disconnect(self) -> None:
        """Nothing to close."""
