"""Sensor poses as 4x4 homogeneous transforms (no Drake), shared by the planners.

The sensor frame follows the camera convention: z along the optical axis, x right, y down.
"""

from __future__ import annotations

import numpy as np


def look_at_batch(eyes: np.ndarray, targets: np.ndarray,
                  up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """(N, 4, 4) X_WS of sensors at `eyes` (N, 3) whose optical axes point at `targets`, with
    image y as close to -`up` as each view allows (so the image is upright)."""
    eyes = np.asarray(eyes, float).reshape(-1, 3)
    z = np.asarray(targets, float).reshape(-1, 3) - eyes
    norm = np.linalg.norm(z, axis=1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("look_at: an eye and its target coincide")
    z = z / norm
    x = np.cross(z, np.asarray(up, float))
    along_up = np.linalg.norm(x, axis=1) < 1e-6  # looking along `up`: any x perpendicular
    x[along_up] = np.cross(z[along_up], [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    X = np.zeros((len(eyes), 4, 4))
    X[:, :3, 0], X[:, :3, 1], X[:, :3, 2], X[:, :3, 3] = x, y, z, eyes
    X[:, 3, 3] = 1.0
    return X


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """X_WS (4x4) of a sensor at `eye` looking at `target` (see `look_at_batch`)."""
    return look_at_batch(eye, target, up)[0]
