"""Sensor poses as 4x4 homogeneous transforms (no Drake), shared by the planners.

The sensor frame follows the camera convention: z along the optical axis, x right, y down.
"""

from __future__ import annotations

import numpy as np


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """X_WS (4x4) of a sensor at `eye` whose optical axis points at `target`, with image y as
    close to -`up` as the view allows (so the image is upright)."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    norm = np.linalg.norm(z)
    if norm < 1e-9:
        raise ValueError(f"look_at: eye {eye} and target coincide")
    z /= norm
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-6:  # looking along `up`: any x perpendicular to z will do
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, y, z])
    X[:3, 3] = eye
    return X
