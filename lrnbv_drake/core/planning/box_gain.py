"""The box gain: how much a view would bound the sides of the reported box that the readings
have not bounded yet (`planner.utility: box`).

Each side of the estimate may lie anywhere in a band: between where its interval's lower and
upper dimensions put it (half the interval's width each for the four walls, all of it for
the top; the bottom is the table). A zone ray that passes through a band before it meets the
table or the part of the object the readings already bound (the box of the interval's lower
dimensions) either ends on that side, fixing it, or passes it by, showing the side is not
there; both narrow the band. A view's box gain is the sum over its rays and the bands they
cross of the band's width, in metres: a view of sides already bounded (narrow bands) gains
little, one past a side no reading has bounded gains its width per ray.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numba
import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.mapping import ray_box_interval


@dc.dataclass(frozen=True)
class SideBands:
    """The bands where each side of an estimate may lie, in the estimate's frame (origin at
    its footprint's centre on the table, x along its length, z up).

    Args:
        X_BW: (4, 4) the world in the estimate's frame.
        lower: (5, 3) each band's lower corner: +x, -x, +y, -y walls, then the top.
        upper: (5, 3) each band's upper corner.
        widths: (5,) each band's width across its side, metres.
        inner: (2, 3) the lower and upper corner of the bound part of the object (the box of
            the interval's lower dimensions), which hides what lies behind it.
    """

    X_BW: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    widths: np.ndarray
    inner: np.ndarray

    @staticmethod
    def of(box: OrientedBox, dims_lower: np.ndarray, dims_upper: np.ndarray,
           table_height: float) -> SideBands:
        """The bands of `box` whose (length, width, height) interval is [`dims_lower`,
        `dims_upper`] (each side moves by half its dimension's spread; the top by all of
        it, the bottom standing on the table)."""
        lo = np.minimum(np.asarray(dims_lower, float), box.dims)
        hi = np.maximum(np.asarray(dims_upper, float), box.dims)
        (ll, wl, hl), (lu, wu, hu) = lo, hi
        X_BW = np.eye(4)
        c, s = math.cos(box.yaw), math.sin(box.yaw)
        X_BW[:2, :2] = [[c, s], [-s, c]]
        X_BW[:3, 3] = -X_BW[:3, :3] @ [box.center[0], box.center[1], table_height]
        lower = np.array([[ll / 2, -wu / 2, 0.0], [-lu / 2, -wu / 2, 0.0],
                          [-lu / 2, wl / 2, 0.0], [-lu / 2, -wu / 2, 0.0],
                          [-lu / 2, -wu / 2, hl]])
        upper = np.array([[lu / 2, wu / 2, hu], [-ll / 2, wu / 2, hu],
                          [lu / 2, wu / 2, hu], [lu / 2, -wl / 2, hu],
                          [lu / 2, wu / 2, hu]])
        widths = np.array([(lu - ll) / 2] * 2 + [(wu - wl) / 2] * 2 + [hu - hl])
        inner = np.array([[-ll / 2, -wl / 2, 0.0], [ll / 2, wl / 2, hl]])
        return SideBands(X_BW, lower, upper, widths, inner)


@numba.njit(cache=True)
def _box_gain_kernel(poses_B, rays, max_range, lower, upper, widths, inner, out):
    d = np.empty(3)
    for p in range(poses_B.shape[0]):
        X = poses_B[p]
        o = X[:3, 3]
        gain = 0.0
        for r in range(rays.shape[0]):
            for a in range(3):
                d[a] = X[a, 0] * rays[r, 0] + X[a, 1] * rays[r, 1] + X[a, 2] * rays[r, 2]
            end = max_range
            if d[2] < 0.0:
                end = min(end, -o[2] / d[2])  # the table, z = 0 in the estimate's frame
            t0, t1 = ray_box_interval(o, d, 0.0, end, inner[0], inner[1])
            if t1 > t0:
                end = t0  # hidden behind the part already bound
            for b in range(lower.shape[0]):
                t0, t1 = ray_box_interval(o, d, 0.0, end, lower[b], upper[b])
                if t1 > t0:
                    gain += widths[b]
        out[p] = gain


def box_gains(poses: np.ndarray, bands: SideBands, rays: np.ndarray,
              max_range: float) -> np.ndarray:
    """(P,) the box gain of each sensor pose (P, 4, 4) whose zone rays (R, 3, unit vectors
    in the sensor frame) reach `max_range`."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    poses_B = np.ascontiguousarray(bands.X_BW @ poses)
    out = np.zeros(len(poses))
    _box_gain_kernel(poses_B, np.ascontiguousarray(rays, float), float(max_range),
                     bands.lower, bands.upper, bands.widths, bands.inner, out)
    return out
