"""The emulated UR5e: DH forward kinematics for actual_TCP_pose and joints that follow their
target with a first-order lag, so a test can predict where the arm is from what it streamed."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

# UR5e DH parameters (Universal Robots' published table); the pose is in the DH base frame.
UR5E_D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
UR5E_A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
UR5E_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
MAX_JOINT_SPEED = math.pi  # rad/s, UR5e: 180 deg/s on every joint
HOME = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)


def forward_kinematics(q: Sequence[float]) -> np.ndarray:
    """Base -> flange (tool0, zero TCP offset) as a 4x4 transform."""
    transform = np.eye(4)
    for theta, d, a, alpha in zip(q, UR5E_D, UR5E_A, UR5E_ALPHA, strict=True):
        ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
        transform = transform @ np.array([
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ])
    return transform


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """Axis times angle (UR's rx, ry, rz) of a rotation matrix, angle in [0, pi]."""
    angle = math.acos(min(1.0, max(-1.0, (float(np.trace(rotation)) - 1.0) / 2.0)))
    skew = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                     rotation[1, 0] - rotation[0, 1]])
    if angle < 1e-9:
        return skew / 2.0
    if angle < math.pi - 1e-4:
        return skew * (angle / (2.0 * math.sin(angle)))
    # Near pi the skew part vanishes: take the axis from the symmetric part.
    symmetric = (rotation + np.eye(3)) / 2.0
    k = int(np.argmax(np.diag(symmetric)))
    axis = symmetric[:, k] / math.sqrt(max(symmetric[k, k], 1e-12))
    if float(axis @ skew) < 0.0:
        axis = -axis
    return axis / np.linalg.norm(axis) * angle


def tcp_pose(q: Sequence[float]) -> list[float]:
    """actual_TCP_pose: [x, y, z, rx, ry, rz] of the flange in the base frame."""
    transform = forward_kinematics(q)
    return [*transform[:3, 3].tolist(), *rotation_vector(transform[:3, :3]).tolist()]


class ArmModel:
    """Six joints that move toward `target` as a first-order lag with time constant `tau`
    (a servo with lookahead smoothing), slowed by the speed scaling and capped at the joint
    speed limit. A ramp at v rad/s is followed tau * v behind; a step decays as exp(-t/tau)."""

    def __init__(self, q0: Sequence[float], tau: float = 0.03,
                 max_speed: float = MAX_JOINT_SPEED) -> None:
        if len(q0) != 6 or tau <= 0.0:
            raise ValueError("q0 needs six joints and tau must be positive")
        self.q = np.array(q0, float)
        self.target = self.q.copy()
        self.qd = np.zeros(6)
        self.tau = tau
        self.max_speed = max_speed
        self.speed_scaling = 1.0

    def step(self, dt: float) -> None:
        """Advance by dt seconds of controller time."""
        if dt <= 0.0:
            return
        scaled = dt * self.speed_scaling
        delta = (self.target - self.q) * (1.0 - math.exp(-scaled / self.tau))
        limit = self.max_speed * scaled
        delta = np.clip(delta, -limit, limit)
        self.q += delta
        self.qd = delta / dt

    def hold(self) -> None:
        """Stop where the arm is (a program stop or a safety stop)."""
        self.target = self.q.copy()

    def servo(self, target: Sequence[float]) -> None:
        """Follow a new joint target."""
        self.target = np.array(target, float)
