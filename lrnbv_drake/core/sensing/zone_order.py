"""The order a board reports its zones in, against the order the sensor model assumes.

Third-party VL53L8CX boards and drivers rotate or mirror the 8x8 grid (ST's own viewers flip
its rows), and a wrong order scrambles every reading. An order is a flip of the model's grid
followed by a counter-clockwise turn of the array as printed (row 0 on top, `numpy.rot90`):
the eight distinct orders of a square grid, each reachable as (rotate, "none" or "rows").
"""

from __future__ import annotations

import dataclasses as dc
import itertools

import numpy as np

from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry

#: Turns of the grid, degrees counter-clockwise.
ZONE_ROTATIONS = (0, 90, 180, 270)
#: Mirrors of the grid before the turn: none, rows reversed (upside down), columns reversed.
ZONE_FLIPS = ("none", "rows", "cols")


def check_zone_order(rotate: int, flip: str) -> None:
    """Raises ValueError unless (rotate, flip) is a zone order."""
    if rotate not in ZONE_ROTATIONS:
        raise ValueError(f"rotate must be one of {ZONE_ROTATIONS}; got {rotate!r}")
    if flip not in ZONE_FLIPS:
        raise ValueError(f"flip must be one of {ZONE_FLIPS}; got {flip!r}")


def _flip(grid: np.ndarray, flip: str) -> np.ndarray:
    return {"none": grid, "rows": grid[::-1], "cols": grid[:, ::-1]}[flip]


def reorder_zones(grid: np.ndarray, rotate: int = 0, flip: str = "none") -> np.ndarray:
    """`grid` (res, res, ...) in the model's order as a board with this order reports it."""
    check_zone_order(rotate, flip)
    return np.rot90(_flip(grid, flip), rotate // 90, axes=(0, 1))


def restore_zones(grid: np.ndarray, rotate: int = 0, flip: str = "none") -> np.ndarray:
    """`grid` (res, res, ...) a board with this order reported, back in the model's order:
    the inverse of `reorder_zones`."""
    check_zone_order(rotate, flip)
    return _flip(np.rot90(grid, -(rotate // 90), axes=(0, 1)), flip)


def model_flips(rotate: int = 0, flip: str = "none") -> tuple[bool, bool, bool]:
    """(flip_x, flip_y, transpose) of the `ZoneGeometry` that reads a board with this zone
    order in the model's row-major order."""
    zones = np.arange(16).reshape(4, 4)
    board = reorder_zones(zones, rotate, flip)
    [flags] = [f for f in itertools.product((False, True), repeat=3)
               if np.array_equal(ZoneGeometry(4, flip_x=f[0], flip_y=f[1], transpose=f[2])
                                 .to_raw(zones), board)]
    return flags


def _map_frame(frame: ToFFrame, zones, rotate: int, flip: str) -> ToFFrame:
    return dc.replace(frame, **{name: zones(getattr(frame, name), rotate, flip).copy()
                                for name in ("distance_mm", "status", "sigma_mm")})


def reorder_frame(frame: ToFFrame, rotate: int = 0, flip: str = "none") -> ToFFrame:
    """`frame` (model's order) as a board with this order reports it; sequence and timestamp
    unchanged."""
    return _map_frame(frame, reorder_zones, rotate, flip)


def restore_frame(frame: ToFFrame, rotate: int = 0, flip: str = "none") -> ToFFrame:
    """`frame` a board with this order reported, in the model's order."""
    return _map_frame(frame, restore_zones, rotate, flip)
