"""From a VL53L8CX frame to the point cloud OctoMap would be given: the map's input."""

from __future__ import annotations

import numpy as np

from lrnbv_drake.core.sensing.sensor import STATUS_NO_TARGET, ToFFrame, ZoneGeometry


def frame_scan(frame: ToFFrame, geometry: ZoneGeometry, X_WS: np.ndarray, mode: str = "ray",
               max_range: float | None = None, cone_k: int = 5,
               free_no_target: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The world-frame scan (origin, points) a frame stands for; `insert_scan` it.

    Modes:
        "ray": one point per valid zone, at the zone centre's direction and the reported
            perpendicular depth (what OctoMap gets from 64 points).
        "cone": k x k points per valid zone, on the sub-ray directions of
            `ZoneGeometry.sub_directions(cone_k)`, all at the zone's perpendicular depth. As one
            scan they free every sub-ray up to the surface and hit the cells holding the
            sub-ray end points: the zone's footprint on the plane z = depth (sensor frame).

    Zones with status 255 (no target) free nothing unless `free_no_target`: then each of their
    (sub-)rays gets a point beyond `max_range`, which frees the ray up to `max_range` only.
    Other invalid zones are ignored.

    Args:
        frame: the frame (raw zone order).
        geometry: zone layout and raw-order flips.
        X_WS: (4, 4) sensor pose in world at capture.
        mode: "ray" or "cone".
        max_range: needed with `free_no_target`.
        cone_k: sub-rays per zone side in cone mode.
        free_no_target: let no-target zones free their rays up to `max_range`.

    Returns:
        (origin, points): (3,) sensor position and (M, 3) points in world.
    """
    if frame.resolution != geometry.resolution:
        raise ValueError(f"frame has {frame.resolution}x{frame.resolution} zones; the geometry "
                         f"expects {geometry.resolution}x{geometry.resolution}")
    if mode not in ("ray", "cone"):
        raise ValueError(f"mode must be 'ray' or 'cone'; got {mode!r}")
    if free_no_target and (max_range is None or max_range < 0):
        raise ValueError("free_no_target needs a max_range")
    T = np.asarray(X_WS, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"X_WS must be a 4x4 matrix; got shape {T.shape}")
    k = 1 if mode == "ray" else int(cone_k)
    if k < 1:
        raise ValueError(f"cone_k must be >= 1; got {cone_k}")
    dirs = _sub_directions(geometry, k)
    depth = geometry.to_row_major(frame.distance_mm).astype(np.float64) / 1000.0
    valid = geometry.to_row_major(frame.valid)
    if free_no_target:
        no_target = geometry.to_row_major(frame.status == STATUS_NO_TARGET) & ~valid
        # Beyond max_range along every sub-ray (the unit-depth direction is at least 1 long).
        depth = np.where(no_target, 2.0 * max_range + 1.0, depth)
        valid = valid | no_target
    pts_S = (dirs * depth[:, :, None, None, None])[valid].reshape(-1, 3)
    return T[:3, 3].copy(), pts_S @ T[:3, :3].T + T[:3, 3]


_DIRECTIONS: dict[tuple, np.ndarray] = {}


def _sub_directions(geometry: ZoneGeometry, k: int) -> np.ndarray:
    """`geometry.sub_directions(k)`, memoised on the geometry's value: recomputing it costs more
    than inserting a frame."""
    key = (type(geometry), repr(geometry), k)
    dirs = _DIRECTIONS.get(key)
    if dirs is None:
        if len(_DIRECTIONS) > 64:
            _DIRECTIONS.clear()
        dirs = geometry.directions()[:, :, None, None, :] if k == 1 else geometry.sub_directions(k)
        dirs.setflags(write=False)
        _DIRECTIONS[key] = dirs
    return dirs
