"""A robot that is not there, for the dry run."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import numpy as np

from lrnbv_drake.core.robot_safety import ROBOT_MODE_RUNNING, tcp_pose_from_q


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

    def get_actual_q(self) -> list[float]:
        with self._lock:
            return self._q.tolist()

    def get_actual_qd(self) -> list[float]:
        with self._lock:
            return self._qd.tolist()

    def get_actual_tcp_pose(self) -> list[float]:
        return tcp_pose_from_q(self.get_actual_q()).tolist()

    def get_timestamp(self) -> float:
        return time.monotonic() - self._started

    def get_robot_mode(self) -> int:
        return ROBOT_MODE_RUNNING

    def get_safety_mode(self) -> int:
        return 1

    def is_protective_stopped(self) -> bool:
        return False

    def is_emergency_stopped(self) -> bool:
        return False

    def is_connected(self) -> bool:
        return True

    def is_program_running(self) -> bool:
        return True

    def servo_j(self, q: Sequence[float], speed: float, acceleration: float, time: float,
                lookahead_time: float, gain: float) -> bool:
        with self._lock:
            q = np.array(q, float)
            self._qd = (q - self._q) / time
            self._q = q
        return True

    def servo_stop(self, deceleration: float) -> bool:
        with self._lock:
            self._qd = np.zeros(6)
        return True

    def disconnect(self) -> None:
        """Nothing to close."""
