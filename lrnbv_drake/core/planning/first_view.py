"""The product's first view: straight down over the drop zone, where the conveyor or the
operator puts the item, high enough that the sensor's zones hold the whole zone.

The paper starts from HOME, whose frame need not see all of the table where items lie; a cell
knows where items are put, so its first frame finds the object wherever in the zone it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import ZoneGeometry


def drop_zone_view(zone: Sequence[float], table_height: float, geometry: ZoneGeometry,
                   min_height: float) -> np.ndarray:
    """X_WS (4x4) of a sensor over the centre of `zone` ([x_min, y_min, x_max, y_max] on the
    table, metres) looking straight down, its image axes along the world's x and y: at the
    height where the corner zones' centre rays meet the zone's farther sides (each corner
    read by a zone of its own), or at `min_height` above the table where that is higher (the
    tallest item's top plus a clearance: the item is not known yet).

    Raises:
        ValueError: a zone whose maximum is not above its minimum.
    """
    x0, y0, x1, y1 = (float(v) for v in zone)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"drop zone {list(zone)}: expected [x_min, y_min, x_max, y_max] with "
                         "each maximum above its minimum")
    outer = float(geometry.zone_centres_rad()[-1])  # the corner zones' centre angle
    height = max(max(x1 - x0, y1 - y0) / 2 / math.tan(outer), min_height)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, table_height])
    return look_at(centre + np.array([0.0, 0.0, height]), centre, up=(1.0, 0.0, 0.0))
