"""ToFVisualizer: draws each acquisition's zone rays and measured points in Meshcat.

Rays run from the sensor to each zone's point: green for a valid range, red (a short stub along
the zone's direction) for no target. Each acquisition's rays are shown from its capture until
the next one; its points stay. Every change is also keyed into Meshcat's recording, so the
exported replay shows them appear at the right time.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Meshcat, Rgba
from pydrake.math import RigidTransform
from pydrake.perception import PointCloud
from pydrake.systems.framework import LeafSystem

from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry
from lrnbv_drake.systems.meshcat_steps import show_from

VALID_RGBA = Rgba(0.1, 0.8, 0.2, 1.0)
NO_TARGET_RGBA = Rgba(0.9, 0.1, 0.1, 1.0)
POINT_RGBA = Rgba(0.1, 0.3, 0.9, 1.0)


def zone_rays(frame: ToFFrame, geometry: ZoneGeometry, X_WS: np.ndarray,
              stub_length: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-frame ray segments of a frame: (starts (3, n), ends (3, n), valid (n,))."""
    points_S, valid = geometry.points(frame)
    directions = geometry.directions().reshape(-1, 3)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    ends_S = np.where(valid[:, None], points_S, directions * stub_length)
    ends_W = ends_S @ X_WS[:3, :3].T + X_WS[:3, 3]
    starts_W = np.repeat(X_WS[:3, 3][:, None], len(ends_W), axis=1)
    return starts_W, ends_W.T, valid


class ToFVisualizer(LeafSystem):
    """Input ports `acquired_frame` (ToFFrame) and `acquired_pose` (RigidTransform)."""

    def __init__(self, meshcat: Meshcat, geometry: ZoneGeometry, *, publish_period: float,
                 show_rays: bool = True, show_points: bool = True, prefix: str = "tof"):
        super().__init__()
        self._meshcat = meshcat
        self._geometry = geometry
        self._show_rays = show_rays
        self._show_points = show_points
        self._prefix = prefix
        self._drawn: list[int] = []  # sequence numbers drawn so far (side-effect bookkeeping)
        self.DeclareAbstractInputPort("acquired_frame", AbstractValue.Make(ToFFrame.empty()))
        self.DeclareAbstractInputPort("acquired_pose", AbstractValue.Make(RigidTransform()))
        self.DeclarePeriodicPublishEvent(publish_period, 0.0, self._Publish)
        self.DeclareForcedPublishEvent(self._Publish)

    def _Publish(self, context) -> None:
        frame: ToFFrame = self.get_input_port(0).Eval(context)
        if frame.sequence == 0 or (self._drawn and self._drawn[-1] == frame.sequence):
            return
        X_WS = self.get_input_port(1).Eval(context).GetAsMatrix4()
        t = context.get_time()
        k = len(self._drawn)
        m = self._meshcat
        starts, ends, valid = zone_rays(frame, self._geometry, X_WS)
        if self._show_rays:
            path = f"{self._prefix}/rays/{k:03d}"
            for mask, rgba, name in ((valid, VALID_RGBA, "valid"),
                                     (~valid, NO_TARGET_RGBA, "no_target")):
                if mask.any():
                    m.SetLineSegments(f"{path}/{name}", starts[:, mask], ends[:, mask], 2.0,
                                      rgba)
            show_from(m, path, t, f"{self._prefix}/rays/{k - 1:03d}" if k > 0 else None)
        if self._show_points and valid.any():
            cloud = PointCloud(int(valid.sum()))
            cloud.mutable_xyzs()[:] = ends[:, valid]
            path = f"{self._prefix}/points/{k:03d}"
            m.SetObject(path, cloud, point_size=0.01, rgba=POINT_RGBA)
            show_from(m, path, t)
        self._drawn.append(frame.sequence)
