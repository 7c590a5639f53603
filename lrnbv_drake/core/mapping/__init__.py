"""The occupancy map (OctoMap's semantics on a dense grid, docs/mapping.md), one module per idea;
importers use the names re-exported here."""

from lrnbv_drake.core.mapping.keys import KEY_OFFSET, TREE_DEPTH
from lrnbv_drake.core.mapping.occupancy_map import BoundsLike, CellCounts, OccupancyMap
from lrnbv_drake.core.mapping.occupancy_update import OccupancyUpdate, logodds
from lrnbv_drake.core.mapping.query_kernels import ray_box_interval, walk_start, walk_step
from lrnbv_drake.core.mapping.scan import frame_scan

__all__ = [
    "KEY_OFFSET",
    "TREE_DEPTH",
    "BoundsLike",
    "CellCounts",
    "OccupancyMap",
    "OccupancyUpdate",
    "frame_scan",
    "logodds",
    "ray_box_interval",
    "walk_start",
    "walk_step",
]
