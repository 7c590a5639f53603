"""Sensor poses as 4x4 homogeneous transforms (no Drake), shared by the planners.

The sensor frame follows the camera convention: z along the optical axis, x right, y down.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy.spatial.transform import Rotation


@numba.njit(cache=True)
def _norm(v0, v1, v2):
    """|v| of a 3-vector, summed in np.linalg.norm's order (so bit for bit its value)."""
    return math.sqrt((v0 * v0 + v1 * v1) + v2 * v2)


@numba.njit(cache=True)
def _look_at_kernel(eyes, targets, up, X):
    """Fills X (N, 4, 4) as `look_at_batch` defines it; False if an eye is on its target.
    Scalar loops: the planner orients ~50 views a call, which numpy spent in per-call overhead
    (the arithmetic is numpy's, operation for operation, so the poses are bit for bit the same).
    """
    u0, u1, u2 = up[0], up[1], up[2]
    for p in range(eyes.shape[0]):
        z0, z1, z2 = (targets[p, 0] - eyes[p, 0], targets[p, 1] - eyes[p, 1],
                      targets[p, 2] - eyes[p, 2])
        n = _norm(z0, z1, z2)
        if n < 1e-9:
            return False
        z0, z1, z2 = z0 / n, z1 / n, z2 / n
        x0, x1, x2 = z1 * u2 - z2 * u1, z2 * u0 - z0 * u2, z0 * u1 - z1 * u0
        if _norm(x0, x1, x2) < 1e-6:
            # Looking along `up`: any x perpendicular, z x [0, 1, 0] (z x [1, 0, 0] if z is
            # along y too).
            x0, x1, x2 = (-z2, 0.0, z0) if abs(z1) < 0.9 else (0.0, z2, -z1)
        n = _norm(x0, x1, x2)
        x0, x1, x2 = x0 / n, x1 / n, x2 / n
        y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
        X[p] = 0.0
        X[p, 0, 0], X[p, 1, 0], X[p, 2, 0] = x0, x1, x2
        X[p, 0, 1], X[p, 1, 1], X[p, 2, 1] = y0, y1, y2
        X[p, 0, 2], X[p, 1, 2], X[p, 2, 2] = z0, z1, z2
        X[p, 0, 3], X[p, 1, 3], X[p, 2, 3] = eyes[p, 0], eyes[p, 1], eyes[p, 2]
        X[p, 3, 3] = 1.0
    return True


def look_at_batch(eyes: np.ndarray, targets: np.ndarray,
                  up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """(N, 4, 4) X_WS of sensors at `eyes` (N, 3) whose optical axes point at `targets`, with
    image y as close to -`up` as each view allows (so the image is upright)."""
    eyes = np.ascontiguousarray(eyes, dtype=float).reshape(-1, 3)
    targets = np.broadcast_to(np.asarray(targets, float).reshape(-1, 3), eyes.shape)
    X = np.empty((len(eyes), 4, 4))
    if not _look_at_kernel(eyes, np.ascontiguousarray(targets), np.asarray(up, float), X):
        raise ValueError("look_at: an eye and its target coincide")
    return X


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """X_WS (4x4) of a sensor at `eye` looking at `target` (see `look_at_batch`)."""
    return look_at_batch(eye, target, up)[0]


def offset_transform(xyz_mm, rpy_deg) -> np.ndarray:
    """(4, 4) pose of an offset given as millimetres and Drake's roll-pitch-yaw in degrees
    (R = Rz(yaw) Ry(pitch) Rx(roll)): a sensor's mount against its CAD frame."""
    X = np.eye(4)
    X[:3, :3] = Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()
    X[:3, 3] = np.asarray(xyz_mm, float) / 1000
    return X


def compile_kernels() -> None:
    """Compiles the look-at kernel into numba's on-disk cache, so that the first planning
    iteration of a process does not wait for it (`python -m lrnbv_drake.core.kernels`)."""
    look_at([0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
