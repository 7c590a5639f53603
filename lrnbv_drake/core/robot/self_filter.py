"""Readings of the robot itself: a view from beyond the object, looking back towards the base,
can have the arm's own elbow in its field of view.

Measured (LR-NBV on the gripper, trial 4 of a campaign): from a view at x = 0.71 m the upper
arm passed 5-14 cm above the object, 30 zones read it, the map's object cluster grew to
19.5 cm tall with them, and the box fitted from that cluster came out 0.5 mm wide and 16 cm
tall. The fix is the one robots use for depth cameras: a reading whose point lies on the
robot's own geometry at the capture configuration is the robot, not the scene. Its status
becomes `STATUS_ROBOT` (the distance is kept, the original status goes to the acquisition's
info: `dropped_zones_info`), so the map, the clustering and the box fit, which all gate on the
status, leave it out. The sensor's mount is not in that geometry: its face is the sensor's.

Which points lie on the robot is the caller's (the station asks Drake's SceneGraph for the
UR5e's collision geometry at the captured joints, `MotionPlanner.near_robot`): here is only
the frame's side of it, free of Drake.
"""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Callable

import numpy as np

from lrnbv_drake.core.mapping.scan import frame_scan
from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry

#: Status this package writes for a zone whose reading is the robot itself. Not one of ST's
#: (theirs are 0-13 and 255): a recording shows which zones the filter took out.
STATUS_ROBOT = 254


def robot_zones(frame: ToFFrame, geometry: ZoneGeometry, X_WS: np.ndarray,
                near_robot: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """(res, res) bool in raw zone order: the valid zones whose zone-centre point, in world,
    `near_robot` (n, 3) -> (n,) bool says lies on the robot."""
    _, points_W = frame_scan(frame, geometry, X_WS)  # the valid zones', row-major
    valid = geometry.to_row_major(frame.valid)
    hit = np.zeros(valid.shape, bool)
    if len(points_W):
        hit[valid] = np.asarray(near_robot(points_W), bool)
    return geometry.to_raw(hit)


def drop_robot_zones(frame: ToFFrame, geometry: ZoneGeometry, X_WS: np.ndarray,
                     near_robot: Callable[[np.ndarray], np.ndarray]
                     ) -> tuple[ToFFrame, np.ndarray]:
    """The frame with the zones `robot_zones` finds marked `STATUS_ROBOT`, and that mask."""
    hit = robot_zones(frame, geometry, X_WS, near_robot)
    if not hit.any():
        return frame, hit
    return dc.replace(frame, status=np.where(hit, STATUS_ROBOT, frame.status)), hit


def dropped_zones_info(frame: ToFFrame, hit: np.ndarray) -> dict[str, list[int]]:
    """What an acquisition's `info` keeps of the dropped zones, so the raw frame can be
    restored: their flat indices in the raw (res, res) order and their original statuses."""
    return {"index": np.flatnonzero(hit).tolist(), "status": frame.status[hit].tolist()}
