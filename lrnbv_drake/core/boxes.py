"""Box geometry shared by perception, the planner and the metrics: axis-aligned boxes for the ROI
and workspace, and yaw-oriented boxes for the object estimate and its ground truth.

No Drake here. World frame: z up, objects rest on a horizontal table, so an object box is only
ever rotated about z (`OrientedBox`); the paper's IoU metric compares two such boxes.

The metrics build the ground-truth box the same way as the estimate: `OrientedBox.from_points`
on the object's mesh vertices (e.g. `trimesh.Trimesh.vertices` posed in the world).
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
import shapely


def _as_points(points: np.ndarray) -> np.ndarray:
    """(N, 3) float64 view of `points`, accepting a single (3,) point."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 1:
        pts = pts.reshape(1, -1)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"expected (N, 3) points; got shape {np.shape(points)}")
    return pts


def _as_vec3(value: np.ndarray | float, name: str) -> np.ndarray:
    """A (3,) float64 copy of `value`, broadcasting a scalar."""
    vec = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
    if not np.all(np.isfinite(vec)):
        raise ValueError(f"{name} must be finite; got {vec}")
    return vec


def _normalise_yaw(yaw: float, period: float = math.pi) -> float:
    """Wraps `yaw` into [-period/2, period/2)."""
    wrapped = (yaw + period / 2) % period - period / 2
    # A yaw a rounding step below -period/2 wraps to +period/2 exactly.
    return float(wrapped - period if wrapped >= period / 2 else wrapped)


@dc.dataclass
class AlignedBox:
    """Axis-aligned box [lower, upper] in the world frame (workspace, ROI, collision volume).

    Args:
        lower: (3,) minimum corner, metres.
        upper: (3,) maximum corner, metres; must be >= lower (zero thickness is allowed).
    """

    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self) -> None:
        self.lower = _as_vec3(self.lower, "AlignedBox.lower")
        self.upper = _as_vec3(self.upper, "AlignedBox.upper")
        if np.any(self.upper < self.lower):
            raise ValueError(f"AlignedBox upper {self.upper} is below lower {self.lower}")

    @staticmethod
    def from_points(points: np.ndarray) -> AlignedBox:
        """The tightest box holding all `points` (at least one)."""
        pts = _as_points(points)
        if len(pts) == 0:
            raise ValueError("AlignedBox.from_points needs at least one point")
        return AlignedBox(pts.min(axis=0), pts.max(axis=0))

    @property
    def center(self) -> np.ndarray:
        """(3,) centre."""
        return (self.lower + self.upper) / 2

    @property
    def size(self) -> np.ndarray:
        """(3,) edge lengths along x, y, z."""
        return self.upper - self.lower

    @property
    def volume(self) -> float:
        """Volume, m^3."""
        return float(np.prod(self.size))

    def contains(self, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """(N,) bool: points inside the box grown by `tol` (the boundary counts as inside)."""
        pts = _as_points(points)
        return np.all((pts >= self.lower - tol) & (pts <= self.upper + tol), axis=1)

    def inflate(self, margin: float | np.ndarray) -> AlignedBox:
        """The box grown by `margin` (scalar or per-axis (3,)) on every side.

        A negative margin shrinks it; an axis shrunk past zero collapses to its centre line
        rather than turning inside out.
        """
        m = _as_vec3(margin, "margin")
        lower, upper = self.lower - m, self.upper + m
        collapsed = upper < lower
        return AlignedBox(
            np.where(collapsed, self.center, lower), np.where(collapsed, self.center, upper)
        )

    def clip(self, other: AlignedBox) -> AlignedBox | None:
        """The part of this box inside `other`; None when they do not overlap at all (boxes that
        only touch give a zero-thickness box)."""
        lower = np.maximum(self.lower, other.lower)
        upper = np.minimum(self.upper, other.upper)
        if np.any(upper < lower):
            return None
        return AlignedBox(lower, upper)

    def intersection_volume(self, other: AlignedBox) -> float:
        """Volume shared with `other`, m^3."""
        overlap = np.minimum(self.upper, other.upper) - np.maximum(self.lower, other.lower)
        return float(np.prod(np.clip(overlap, 0.0, None)))

    def iou(self, other: AlignedBox) -> float:
        """Intersection over union of the volumes; 0 when both boxes are flat."""
        inter = self.intersection_volume(other)
        union = self.volume + other.volume - inter
        return inter / union if union > 0 else 0.0

    def corners(self) -> np.ndarray:
        """(8, 3) corners; bit i of the row index picks upper on axis i (x fastest)."""
        bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
        return np.where(bits == 1, self.upper, self.lower)


@dc.dataclass
class OrientedBox:
    """Box standing on a horizontal surface, rotated by `yaw` about the world z axis.

    The representation is canonical, so the same box always has the same fields: on construction
    the dims are ordered so length >= width (swapping them turns the yaw by 90 degrees) and the
    yaw, the angle from world x to the length axis, is wrapped to [-pi/2, pi/2) since a box is
    symmetric under a half turn. A square footprint (length == width) further wraps the yaw to
    [-pi/4, pi/4).

    Args:
        center: (3,) centre, metres.
        dims: (3,) (length, width, height), metres, non-negative.
        yaw: rotation about z, radians.
    """

    center: np.ndarray
    dims: np.ndarray
    yaw: float = 0.0

    def __post_init__(self) -> None:
        self.center = _as_vec3(self.center, "OrientedBox.center")
        self.dims = _as_vec3(self.dims, "OrientedBox.dims")
        if np.any(self.dims < 0):
            raise ValueError(f"OrientedBox.dims must be non-negative; got {self.dims}")
        yaw = float(self.yaw)
        if self.dims[1] > self.dims[0]:
            self.dims = self.dims[[1, 0, 2]]
            yaw += math.pi / 2
        period = math.pi / 2 if self.dims[0] == self.dims[1] else math.pi
        self.yaw = _normalise_yaw(yaw, period)

    @staticmethod
    def from_points(points: np.ndarray, floor_z: float | None = None) -> OrientedBox:
        """The minimum-footprint yaw-oriented box holding `points` (at least one).

        The footprint is the exact minimum-area rectangle of the points' xy: it has a side on an
        edge of their convex hull (Freeman and Shapira, 1975), so every hull edge direction is
        tried. Height runs from `floor_z` (the table the object stands on, which hides its
        underside) or else the lowest point, to the highest point; points below `floor_z` are
        left outside the box.
        """
        pts = _as_points(points)
        if len(pts) == 0:
            raise ValueError("OrientedBox.from_points needs at least one point")
        top = float(pts[:, 2].max())
        bottom = float(pts[:, 2].min()) if floor_z is None else float(floor_z)
        if top < bottom:
            raise ValueError(f"all points lie below floor_z={floor_z} (highest z is {top})")
        center_xy, length, width, yaw = _min_area_rectangle(pts[:, :2])
        return OrientedBox(
            np.array([*center_xy, (top + bottom) / 2]), np.array([length, width, top - bottom]), yaw
        )

    @property
    def volume(self) -> float:
        """Volume, m^3."""
        return float(np.prod(self.dims))

    def rotation_xy(self) -> np.ndarray:
        """2x2 rotation whose columns are the length and width axes in world xy."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s], [s, c]])

    def footprint_vertices(self) -> np.ndarray:
        """(4, 2) xy corners of the footprint, counter-clockwise."""
        half = self.dims[:2] / 2
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return self.center[:2] + local @ self.rotation_xy().T

    def footprint(self) -> shapely.Polygon:
        """The footprint as a shapely polygon (for areas and overlaps)."""
        return shapely.Polygon(self.footprint_vertices())

    def corners(self) -> np.ndarray:
        """(8, 3) corners: the footprint at the bottom, then at the top."""
        xy = np.tile(self.footprint_vertices(), (2, 1))
        z = self.center[2] + np.repeat([-1.0, 1.0], 4) * self.dims[2] / 2
        return np.column_stack([xy, z])

    def aligned(self) -> AlignedBox:
        """The smallest axis-aligned box enclosing this one."""
        half_xy = np.abs(self.rotation_xy()) @ (self.dims[:2] / 2)
        half = np.array([*half_xy, self.dims[2] / 2])
        return AlignedBox(self.center - half, self.center + half)

    def contains(self, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """(N,) bool: points inside the box grown by `tol` (the boundary counts as inside)."""
        pts = _as_points(points)
        local_xy = (pts[:, :2] - self.center[:2]) @ self.rotation_xy()
        local = np.column_stack([local_xy, pts[:, 2] - self.center[2]])
        return np.all(np.abs(local) <= self.dims / 2 + tol, axis=1)

    def _footprint_overlap(self, other: OrientedBox) -> float:
        """The area the two footprints share. Snapped to a 1e-12 m grid: with nearly
        coincident edges GEOS can return a point (area 0) for two overlapping rectangles."""
        return shapely.intersection(self.footprint(), other.footprint(), grid_size=1e-12).area

    def footprint_iou(self, other: OrientedBox) -> float:
        """Intersection over union of the two footprints, whatever the heights: whether two
        boxes describe the same place on the table."""
        inter = self._footprint_overlap(other)
        union = self.dims[0] * self.dims[1] + other.dims[0] * other.dims[1] - inter
        return inter / union if union > 0 else 0.0

    def footprint_share(self, other: OrientedBox) -> float:
        """The share of this box's footprint that lies inside `other`'s: whether it lies
        within a larger box that describes the same place (1 inside, 0 apart)."""
        area = self.dims[0] * self.dims[1]
        return self._footprint_overlap(other) / area if area > 0 else 0.0

    def iou(self, other: OrientedBox) -> float:
        """Exact 3-D intersection over union: since both boxes are only yawed, the intersection is
        a prism, footprint overlap area times the overlap of the z ranges. 0 when both are flat."""
        z_overlap = min(self.center[2] + self.dims[2] / 2, other.center[2] + other.dims[2] / 2)
        z_overlap -= max(self.center[2] - self.dims[2] / 2, other.center[2] - other.dims[2] / 2)
        inter = 0.0
        if z_overlap > 0:
            inter = self._footprint_overlap(other) * z_overlap
        union = self.volume + other.volume - inter
        return inter / union if union > 0 else 0.0


def _min_area_rectangle(xy: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """Exact minimum-area rectangle of 2-D points: (center_xy, side along yaw, other side, yaw).

    Degenerate inputs work: collinear points give a zero-width rectangle, coincident points a
    zero-size one with yaw 0.
    """
    hull = shapely.MultiPoint(xy).convex_hull
    ring = shapely.get_coordinates(hull)
    if len(ring) > 1 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]  # a polygon's exterior repeats its first vertex
    edges = np.roll(ring, -1, axis=0) - ring
    lengths = np.linalg.norm(edges, axis=1)
    if not np.any(lengths > 0):
        return ring[0].copy(), 0.0, 0.0, 0.0
    u = edges[lengths > 0] / lengths[lengths > 0, None]  # (E, 2) candidate side directions
    v = np.column_stack([-u[:, 1], u[:, 0]])
    proj_u, proj_v = u @ ring.T, v @ ring.T  # (E, M) hull vertices in each candidate frame
    extent_u = proj_u.max(axis=1) - proj_u.min(axis=1)
    extent_v = proj_v.max(axis=1) - proj_v.min(axis=1)
    best = int(np.argmin(extent_u * extent_v))
    mid_u = (proj_u[best].max() + proj_u[best].min()) / 2
    mid_v = (proj_v[best].max() + proj_v[best].min()) / 2
    center = mid_u * u[best] + mid_v * v[best]
    yaw = math.atan2(u[best, 1], u[best, 0])
    return center, float(extent_u[best]), float(extent_v[best]), yaw
