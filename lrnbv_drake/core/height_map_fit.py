"""The object as a height map over the table, fitted to the raw zone readings through the sensor
model: the shape-agnostic estimate, whose bounding box is reported for objects that are not
boxes (a gripper's finger gap, a flange's thin plate around a hub).

Why: the box fit (`box_fit`) explains every reading with one solid box, so a part whose
readings a box cannot explain comes out short: the gripper 3-4 cm (its fingers are lower than
its housing), the flange 4-7 cm (its 20 mm plate around a 50 mm hub). Here the object is a
grid of columns standing on the table plane, one height each, and the readings are predicted
exactly as the box fit predicts them: each zone's k x k sub-rays cast against the columns and
the table top, reduced by the sensor model's rule, a soft-L1 residual in the model's sigma
(capped at `no_return_residual`, so that a reading of something else, the arm or the table's
edge, does not raise a column to explain it). The table is the plane the readings are
explained against, not a height band that deletes what lies low.

How:
- Coordinate descent over the columns' heights, 2 cm cells then 1 cm. Each cell tries a few
  heights (the table, its neighbours', and the heights at which the readings' sub-rays land in
  it), and a trial re-predicts only the zones whose sub-rays cross that column: every sub-ray
  keeps the list of columns it crosses, and its depth changes only if the cell lies before
  (or is) its current first hit.
- The prior is the box fit, not the empty table: a column costs `column_cost` where it departs
  from the box's height, plus its walls to its neighbours. So a cell departs only where the
  readings pay for it.
- Two starts, the lower cost kept (`_descend_levels`): the box's columns, where what no view
  saw stays as the box has it, and where the readings put surfaces (`_back_projection`), which
  raises a part the box lacks that single columns could not (a flange's plate, a gripper's
  fingers); there a cell no view saw is table, and pays the prior for it.
- A group of columns raised outside the box stays only if the readings need it
  (`_needed_parts`), and lone groups far smaller than the object are dropped
  (`_object_columns`).
- The box is a clip of the columns (`_Clip`): its sides and top are searched continuously, so
  it is not quantised to the cells, and its height is the top plateau's common height.
"""

from __future__ import annotations

import concurrent.futures
import copy
import dataclasses as dc
import math
from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np
import scipy.ndimage

from lrnbv_drake.core.box_fit import (
    BoxEstimator,
    BoxFit,
    BoxFitParams,
    ZoneRays,
    _as_vector,
    _reduce_sorted,
    _swapped,
    _table_depths,
    fit_box,
    near_box,
    predicted_depths,
    profile_move,
    reduction_rule,
    zone_rays,
)
from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.poses import look_at
from lrnbv_drake.core.sensor import SensorModelParams, ToFFrame


@dc.dataclass(frozen=True)
class HeightMapParams:
    """Settings of the height-map fit; lengths in metres."""

    # The grid covers the starting box grown by this on every side (the part of an object a
    # box fit leaves out), and the zones whose sub-rays pass within it are fitted.
    margin: float = 0.06
    # Cell sizes, coarse to fine; sweeps of the coordinate descent at each.
    cells: tuple[float, ...] = (0.02, 0.01)
    max_sweeps: int = 4
    # Columns lower than this are table: below it a column and the table give the same
    # readings within the noise.
    min_height: float = 0.004
    # Cost per square metre of wall between neighbouring columns (the height step times the
    # shared side) and per cubic metre of column volume, in the units of the zone costs
    # (soft-L1 sigma squared): a lone 2 cm column 10 cm tall costs what a zone misfit by
    # about three sigmas does, so noise does not raise spikes or dig holes, and of heights the
    # readings cannot tell apart the lowest wins.
    wall_cost: float = 2000.0
    volume_cost: float = 5000.0
    # Cost of each column above `min_height`: a free parameter must explain more than noise
    # (a least-squares fit gains about one unit of chi-square per parameter from noise alone).
    column_cost: float = 3.0
    # What each column of a part outside the box must gain to stay (`_needed_parts`).
    part_cost: float = 8.0
    # How far the box's sides may move in from the columns' bounding box when refined.
    clip_span: float = 0.03
    # Columns this close to the highest, and connected to it, form the top refitted as one.
    plateau: float = 0.015
    # The outline (`_outlined`): its cells (0: no outline, the columns' own cells), how far
    # each side may move from the columns' bounding box, and the exponents tried.
    outline_cell: float = 0.005
    outline_reach: float = 0.03
    outline_exponents: tuple[float, ...] = (2.0, 2.5, 3.0, 4.0, 6.0, 10.0, 50.0)
    # What the outline's fill must gain over the outline that only cuts, scaled as
    # `part_cost` is: measured, a flange's plate gains 35-340, the fill that grew a gripper
    # 2-4 cm (over its finger gap and beyond) 4-26.
    fill_cost: float = 30.0
    # The lowest fill: thinner, a fill is a skirt of the table's noise (two sigmas of the
    # nominal model at working range); at 5 mm one grew a gripper 36 mm.
    fill_min: float = 0.01
    # No fill where the cut leaves more than this cost per zone: the misfit is then the
    # model's, not the shape's (the flange on the modelled device: at most 2.4; the datasheet
    # device under the nominal model: 3-16, where fills grew boxes 4-9 cm).
    fill_misfit: float = 3.0


@dc.dataclass(frozen=True)
class HeightMap:
    """A fitted height map and its bounding box."""

    # (nx, ny) column heights above the table; cell edges along the grid's x and y axes.
    heights: np.ndarray
    edges_x: np.ndarray
    edges_y: np.ndarray
    # The grid's frame in the world: its origin (x, y) and yaw.
    origin: np.ndarray
    yaw: float
    # The object's box (the object's columns cut by the clip `_Clip` fits; None if no column
    # stands above `min_height`) and the (3,) bounds of its dimensions.
    box: OrientedBox | None
    dims_lower: np.ndarray
    dims_upper: np.ndarray
    # The box's sides along the grid's x and y and its height (the box's dims before they are
    # ordered length first): what compares with the box fit the grid is aligned with.
    extents: np.ndarray | None
    # The readings' cost for the box's columns (or the whole map when there is no box), in
    # the box fit's units: the soft-L1 sum, uncapped, without the prior.
    cost: float
    zones: int
    # (nx, ny) the cells the outline raised (`_outlined`), not fitted column by column.
    filled: np.ndarray


@numba.njit(cache=True)
def _crossings(o, d, edges_x, edges_y, hmax, start, cell, t_in, t_out):
    """The columns each ray (origin o[r], direction d[r], grid frame) crosses while it is
    between the table (z = 0) and hmax, in order: ray r's are [start[r], start[r+1]) of `cell`
    (flat index), `t_in`, `t_out`. First call with `cell` of length 0 to count."""
    nx, ny = edges_x.shape[0] - 1, edges_y.shape[0] - 1
    count = 0
    fill = cell.shape[0] > 0
    for r in range(o.shape[0]):
        start[r] = count
        dz = d[r, 2]
        if dz < 0.0:  # down: from hmax to the table
            ta, tb = max((hmax - o[r, 2]) / dz, 0.0), -o[r, 2] / dz
        elif dz > 0.0:  # up (a low view): from the table to hmax
            ta, tb = max(-o[r, 2] / dz, 0.0), (hmax - o[r, 2]) / dz
        elif 0.0 <= o[r, 2] <= hmax:  # level, within the columns' height
            ta, tb = 0.0, np.inf
        else:
            continue
        for axis, edges in ((0, edges_x), (1, edges_y)):
            lo, hi, dv, ov = edges[0], edges[-1], d[r, axis], o[r, axis]
            if dv == 0.0:
                if not lo <= ov <= hi:
                    ta = np.inf
            else:
                t1, t2 = (lo - ov) / dv, (hi - ov) / dv
                ta, tb = max(ta, min(t1, t2)), min(tb, max(t1, t2))
        if not ta < tb:
            continue
        t = ta
        px, py = o[r, 0] + t * d[r, 0], o[r, 1] + t * d[r, 1]
        ix = min(max(np.searchsorted(edges_x, px, side="right") - 1, 0), nx - 1)
        iy = min(max(np.searchsorted(edges_y, py, side="right") - 1, 0), ny - 1)
        sx = 1 if d[r, 0] > 0 else -1
        sy = 1 if d[r, 1] > 0 else -1
        while t < tb and 0 <= ix < nx and 0 <= iy < ny:
            bx = edges_x[ix + 1] if sx > 0 else edges_x[ix]
            by = edges_y[iy + 1] if sy > 0 else edges_y[iy]
            tx = (bx - o[r, 0]) / d[r, 0] if d[r, 0] != 0.0 else np.inf
            ty = (by - o[r, 1]) / d[r, 1] if d[r, 1] != 0.0 else np.inf
            t_next = min(tx, ty, tb)
            if t_next > t:
                if fill:
                    cell[count], t_in[count], t_out[count] = ix * ny + iy, t, t_next
                count += 1
            t = t_next
            if tx <= ty:
                ix += sx
            else:
                iy += sy
    start[o.shape[0]] = count
    return count


@numba.njit(cache=True)
def _hit(oz, dz, ta, tb, h):
    """Depth at which a ray crossing a column over [ta, tb] meets its side (it enters below
    h) or, going down, its top at height h; inf if it passes over."""
    if h <= 0.0:
        return np.inf
    z_a = oz + ta * dz
    if h >= z_a:
        return ta
    if dz < 0.0 and h >= oz + tb * dz:
        return (h - oz) / dz
    return np.inf


@numba.njit(cache=True)
def _first_hit(r, first, o, d, start, cell, t_in, t_out, heights, table_t):
    """Ray r's first hit from its crossing `first` on: (crossing index or -1, depth)."""
    for k in range(first, start[r + 1]):
        t = _hit(o[r, 2], d[r, 2], t_in[k], t_out[k], heights[cell[k]])
        if t < np.inf:
            return k, t
    return -1, table_t[r]


@numba.njit(cache=True)
def _zone_cost(zone, m, depth, measured, sigma, rule_args, loss_scale, no_return, cap, buf,
               signal, ones, foreign, target):
    """A zone's soft-L1 cost (as `box_fit`'s), its residual capped at `cap` sigmas."""
    for j in range(m):
        buf[j] = depth[zone * m + j]
    buf.sort()
    min_count, gap_m, slope, merge_m, strongest, merged_mode = rule_args
    r = (measured[zone] - _reduce_sorted(buf, min_count, gap_m, slope, merge_m, strongest,
                                         merged_mode, signal, ones, foreign, target)) \
        / sigma[zone]
    if math.isnan(r):
        r = no_return
    r = min(abs(r), cap)
    q = r / loss_scale
    return 2.0 * (math.sqrt(1.0 + q * q) - 1.0) * loss_scale * loss_scale


@numba.njit(cache=True)
def _prior(c, h, heights, expected, ny, size, wall_cost, volume_cost, column_cost,
           min_height):
    """Cell c's share of the shape's cost at height h: its walls to its four neighbours
    (outside the grid: the table), and its departure from the `expected` height."""
    n = heights.shape[0]
    walls = 0.0
    for nb, same_row in ((c - ny, True), (c + ny, True), (c - 1, False), (c + 1, False)):
        inside = 0 <= nb < n and (same_row or nb // ny == c // ny)
        walls += abs(h - (heights[nb] if inside else 0.0))
    departure = abs(h - expected[c])
    return (wall_cost * size * walls + volume_cost * size * size * departure
            + (column_cost if departure > min_height else 0.0))


@numba.njit(cache=True, nogil=True)
def _descend(o, d, measured, sigma, m, table_t, start, cell, t_in, t_out, cell_start,
             cell_cross, cross_ray, heights, expected, candidates, cand_start, ny, rule_args,
             loss_scale, no_return, wall_cost, volume_cost, column_cost, min_height, size,
             max_sweeps, active):
    """Coordinate descent over the `active` column heights (see the module doc); returns
    the cost."""
    n_rays, n_zones = o.shape[0], measured.shape[0]
    hit_k, depth = np.empty(n_rays, np.int64), np.empty(n_rays)
    for r in range(n_rays):
        hit_k[r], depth[r] = _first_hit(r, start[r], o, d, start, cell, t_in, t_out,
                                        heights, table_t)
    buf, signal = np.empty(m), np.empty(m)
    ones, foreign, target = np.ones(m), np.zeros(m, np.bool_), np.empty(4)
    zone_cost = np.empty(n_zones)
    for z in range(n_zones):
        zone_cost[z] = _zone_cost(z, m, depth, measured, sigma, rule_args, loss_scale,
                                  no_return, no_return, buf, signal, ones, foreign, target)
    stamp = np.full(n_zones, -1, np.int64)
    zones = np.empty(n_zones, np.int64)
    saved = np.empty(n_rays)
    changed = np.empty(n_rays, np.int64)
    n_cells = heights.shape[0]
    trial = 0
    for _ in range(max_sweeps):
        moved = False
        for c in range(n_cells):
            lo, hi = cell_start[c], cell_start[c + 1]
            if lo == hi or not active[c]:
                continue
            # The zones whose rays cross this column.
            trial += 1
            n_z = 0
            for q in range(lo, hi):
                z = cross_ray[cell_cross[q]] // m
                if stamp[z] != trial:
                    stamp[z] = trial
                    zones[n_z] = z
                    n_z += 1
            base = 0.0
            for a in range(n_z):
                base += zone_cost[zones[a]]
            h0 = heights[c]
            best_h = h0
            best = base + _prior(c, h0, heights, expected, ny, size, wall_cost, volume_cost,
                                 column_cost, min_height)
            neighbours = (c - ny, c + ny, c - 1, c + 1)
            n_cand = cand_start[c + 1] - cand_start[c]
            for e in range(n_cand + 5):
                if e < n_cand:
                    h = candidates[cand_start[c] + e]
                elif e == n_cand:
                    h = 0.0
                else:
                    nb = neighbours[e - n_cand - 1]
                    if nb < 0 or nb >= n_cells or (e - n_cand - 1 >= 2
                                                   and nb // ny != c // ny):
                        continue
                    h = heights[nb]
                if h == h0:
                    continue
                # Re-predict the rays this column can change.
                heights[c] = h
                n_changed = 0
                for q in range(lo, hi):
                    k = cell_cross[q]
                    r = cross_ray[k]
                    if hit_k[r] != -1 and k > hit_k[r]:
                        continue
                    if k == hit_k[r]:
                        _, t = _first_hit(r, k, o, d, start, cell, t_in, t_out, heights,
                                          table_t)
                    else:
                        t = _hit(o[r, 2], d[r, 2], t_in[k], t_out[k], h)
                        if t == np.inf:
                            continue
                    saved[n_changed], changed[n_changed] = depth[r], r
                    n_changed += 1
                    depth[r] = t
                # Only the zones of rays that changed can change their cost.
                total = base + _prior(c, h, heights, expected, ny, size, wall_cost, volume_cost,
                                      column_cost, min_height)
                trial += 1
                for a in range(n_changed):
                    z = changed[a] // m
                    if stamp[z] != trial:
                        stamp[z] = trial
                        total += _zone_cost(z, m, depth, measured, sigma, rule_args,
                                            loss_scale, no_return, no_return, buf, signal,
                                            ones, foreign, target) - zone_cost[z]
                for a in range(n_changed):
                    depth[changed[a]] = saved[a]
                heights[c] = h0
                if total < best - 1e-9:
                    best_h, best = h, total
            if best_h != h0:
                heights[c] = best_h
                moved = True
                for q in range(lo, hi):
                    r = cross_ray[cell_cross[q]]
                    hit_k[r], depth[r] = _first_hit(r, start[r], o, d, start, cell, t_in,
                                                    t_out, heights, table_t)
                for a in range(n_z):
                    zone_cost[zones[a]] = _zone_cost(zones[a], m, depth, measured, sigma,
                                                     rule_args, loss_scale, no_return,
                                                     no_return, buf, signal, ones, foreign,
                                                     target)
        if not moved:
            break
    prior = 0.0
    nx = n_cells // ny
    for c in range(n_cells):  # each inner wall counted from both sides, so at half its cost
        prior += _prior(c, heights[c], heights, expected, ny, size, wall_cost / 2, volume_cost,
                        column_cost, min_height)
        # A wall to the table beyond the grid is counted from this side only: its other half.
        i, j = c // ny, c % ny
        border = (i == 0) + (i == nx - 1) + (j == 0) + (j == ny - 1)
        prior += wall_cost / 2 * size * border * heights[c]
    return zone_cost.sum() + prior


@numba.njit(cache=True, nogil=True)
def _all_crossings(o, d, edges_x, edges_y, hmax):
    """`_crossings` counted, then filled: (start, cell, t_in, t_out)."""
    start = np.empty(o.shape[0] + 1, np.int64)
    empty_i, empty_f = np.empty(0, np.int64), np.empty(0)
    total = _crossings(o, d, edges_x, edges_y, hmax, start, empty_i, empty_f, empty_f)
    cell, t_in, t_out = np.empty(total, np.int64), np.empty(total), np.empty(total)
    _crossings(o, d, edges_x, edges_y, hmax, start, cell, t_in, t_out)
    return start, cell, t_in, t_out


@numba.njit(cache=True)
def _data_cost(o, d, table_t, measured, sigma, m, edges_x, edges_y, heights, hmax, rule_args,
               loss_scale, no_return):
    """The zones' summed cost for the columns `heights` (flat) on the grid `edges_x`,
    `edges_y`, which need not be uniform."""
    start, cell, t_in, t_out = _all_crossings(o, d, edges_x, edges_y, hmax)
    return _crossed_cost(o, d, table_t, measured, sigma, m, start, cell, t_in, t_out, heights,
                         rule_args, loss_scale, no_return)


@numba.njit(cache=True)
def _crossed_cost(o, d, table_t, measured, sigma, m, start, cell, t_in, t_out, heights,
                  rule_args, loss_scale, no_return):
    """`_data_cost` with the rays' crossings (`_all_crossings`) already walked."""
    n_rays = o.shape[0]
    depth = np.empty(n_rays)
    for r in range(n_rays):
        depth[r] = _first_hit(r, start[r], o, d, start, cell, t_in, t_out, heights,
                              table_t)[1]
    buf, signal = np.empty(m), np.empty(m)
    ones, foreign, target = np.ones(m), np.zeros(m, np.bool_), np.empty(4)
    cost = 0.0
    for z in range(measured.shape[0]):
        cost += _zone_cost(z, m, depth, measured, sigma, rule_args, loss_scale, no_return,
                           np.inf, buf, signal, ones, foreign, target)
    return cost


def _landing_points(landing: np.ndarray, edges_x: np.ndarray, edges_y: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Where on the grid the sub-rays land (`_Readings.landing`): each one's cell (flat index,
    -1 outside the grid's footprint) and height."""
    ix = np.searchsorted(edges_x, landing[:, 0], side="right") - 1
    iy = np.searchsorted(edges_y, landing[:, 1], side="right") - 1
    nx, ny = len(edges_x) - 1, len(edges_y) - 1
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    return np.where(inside, ix * ny + iy, -1), landing[:, 2]


def _landing_heights(landing: np.ndarray, edges_x: np.ndarray, edges_y: np.ndarray,
                     hmax: float) -> tuple[np.ndarray, np.ndarray]:
    """Each grid cell's candidate heights: where the sub-rays, taken to their zone's reading,
    land in it (5 mm steps), as CSR (start, values)."""
    cell, z = _landing_points(landing, edges_x, edges_y)
    ok = (cell >= 0) & (z > 0) & (z <= hmax)
    pairs = np.unique(np.stack([cell[ok], np.round(z[ok] / 0.005) * 0.005], axis=1), axis=0)
    n_cells = (len(edges_x) - 1) * (len(edges_y) - 1)
    start = np.searchsorted(pairs[:, 0], np.arange(n_cells + 1))
    return start.astype(np.int64), pairs[:, 1].copy()


def _lands_inside(rays: ZoneRays, origin: np.ndarray, to_grid: np.ndarray, half: np.ndarray,
                  hmax: float) -> np.ndarray:
    """(n,) zones with a sub-ray whose point at the measured depth lies in the grid's volume
    (down to 3 sigmas below the table). The others saw something else nearer (the arm, the
    table's edge from below): no column over the table can explain them, and fitted they
    would raise walls at the grid's border."""
    p = (rays.origins[:, None, :] + rays.measured[:, None, None] * rays.directions - origin) \
        @ to_grid.T
    inside = ((np.abs(p[..., 0]) <= half[0]) & (np.abs(p[..., 1]) <= half[1])
              & (p[..., 2] <= hmax) & (p[..., 2] >= -3 * rays.sigma[:, None]))
    return inside.any(axis=1)


def _grid_edges(lo: float, hi: float, size: float) -> np.ndarray:
    n = max(1, math.ceil((hi - lo) / size - 1e-9))
    return lo + size * np.arange(n + 1)


class _Readings:
    """The readings in the grid's frame with the model's rule: what every evaluation needs."""

    def __init__(self, rays: ZoneRays, origin: np.ndarray, to_grid: np.ndarray,
                 table_height: float, hmax: float, model: SensorModelParams,
                 fit_params: BoxFitParams) -> None:
        n, m = rays.directions.shape[:2]
        self.m, self.zones, self.hmax = m, n, hmax
        self.o = np.repeat((rays.origins - origin) @ to_grid.T, m, axis=0)
        self.d = (rays.directions @ to_grid.T).reshape(-1, 3)
        table_t = np.empty((n, m))
        for i in range(n):
            _table_depths(rays.origins, rays.directions, i, table_height, fit_params.extent(),
                          table_t[i])
        self.table_t = table_t.reshape(-1)
        # The sub-rays' points at their zone's reading: where the readings put surfaces.
        self.landing = self.o + np.repeat(rays.measured, m)[:, None] * self.d
        self.measured, self.sigma = rays.measured, rays.sigma
        self.rule = reduction_rule(model, fit_params.behaviour, m)
        self.loss = (fit_params.loss_scale, fit_params.no_return_residual)

    def crossing(self, edges_x: np.ndarray, edges_y: np.ndarray, top: float) -> np.ndarray:
        """(zones,) the zones with a sub-ray through the region edges_x x edges_y, between
        the table and `top`: the only ones a change of columns there can change."""
        start = np.empty(len(self.o) + 1, np.int64)
        empty_i, empty_f = np.empty(0, np.int64), np.empty(0)
        _crossings(self.o, self.d, edges_x, edges_y, top, start, empty_i, empty_f, empty_f)
        return (np.diff(start) > 0).reshape(self.zones, self.m).any(axis=1)

    def take(self, zones: np.ndarray, hmax: float) -> _Readings:
        """These readings restricted to the (zones,) mask `zones`, for columns no higher than
        `hmax`."""
        out = copy.copy(self)
        out.hmax = hmax
        rays = np.repeat(zones, self.m)
        out.o, out.d, out.table_t, out.landing = (self.o[rays], self.d[rays],
                                                  self.table_t[rays], self.landing[rays])
        out.measured, out.sigma = self.measured[zones], self.sigma[zones]
        out.zones = int(zones.sum())
        return out

    def cost(self, edges_x: np.ndarray, edges_y: np.ndarray, heights: np.ndarray) -> float:
        """The zones' summed cost for the (nx, ny) columns `heights` on these edges."""
        return float(_data_cost(self.o, self.d, self.table_t, self.measured, self.sigma,
                                self.m, edges_x, edges_y, heights.reshape(-1), self.hmax,
                                self.rule, *self.loss))

    def cost_on(self, edges_x: np.ndarray, edges_y: np.ndarray
                ) -> Callable[[np.ndarray], float]:
        """`cost` on these edges as a function of the columns, the rays' crossings walked
        once: for a search that tries many columns on one grid."""
        crossings = _all_crossings(self.o, self.d, edges_x, edges_y, self.hmax)
        return lambda heights: float(_crossed_cost(
            self.o, self.d, self.table_t, self.measured, self.sigma, self.m, *crossings,
            heights.reshape(-1), self.rule, *self.loss))

    def descend(self, edges_x: np.ndarray, edges_y: np.ndarray, heights: np.ndarray,
                expected: np.ndarray, active: np.ndarray, params: HeightMapParams) -> float:
        """Coordinate descent over the flat `heights` where `active`, in place (`_descend`);
        the cost."""
        nx, ny = len(edges_x) - 1, len(edges_y) - 1
        ray_start, cell, t_in, t_out = _all_crossings(self.o, self.d, edges_x, edges_y,
                                                      self.hmax)
        order = np.argsort(cell, kind="stable").astype(np.int64)
        cell_start = np.searchsorted(cell[order], np.arange(nx * ny + 1)).astype(np.int64)
        cross_ray = np.repeat(np.arange(len(self.o)), np.diff(ray_start))
        cand_start, candidates = _landing_heights(self.landing, edges_x, edges_y, self.hmax)
        return float(_descend(self.o, self.d, self.measured, self.sigma, self.m, self.table_t,
                              ray_start, cell, t_in, t_out, cell_start, order, cross_ray,
                              heights, expected, candidates, cand_start, ny, self.rule,
                              *self.loss,
                              params.wall_cost, params.volume_cost, params.column_cost,
                              params.min_height, float(edges_x[1] - edges_x[0]),
                              params.max_sweeps, active))


def fit_height_map(rays: ZoneRays, start: OrientedBox, table_height: float,
                   model: SensorModelParams, fit_params: BoxFitParams | None = None,
                   params: HeightMapParams | None = None, interval: bool = True,
                   screen: bool = False) -> HeightMap | None:
    """The height map that best explains the readings `rays` around `start` (a box fit's or
    the cell box: it sets the grid's yaw and extent); None when no reading sees it. Without
    `interval` the box's dimension bounds are NaN (they cost about 100 evaluations). With
    `screen` there is no box when no column stands outside `start` (the object is then
    `start`), and the descent from the box stops after the coarsest level if none is needed
    there."""
    params = params or HeightMapParams()
    fit_params = fit_params or BoxFitParams()
    readings, origin, to_grid, half = _readings_around(rays, start, table_height, model,
                                                       fit_params, params)
    if readings is None:
        return None
    # Two starts, the lower cost of those that reach the finest cells kept: the box fit, and
    # where the readings put surfaces (never screened: a gripper's 18 mm fingers need the
    # fine cells to stand).
    # The two are independent and the descent releases the GIL: side by side on two cores.
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        fits = list(pool.map(lambda initial: _descend_levels(
            readings, start, table_height, origin, to_grid, half, params,
            screen and initial == "box", initial), ("box", "readings")))
    finished = [f for f in fits if not f.screened]
    edges_x, edges_y, grid, expected = min(finished, key=lambda f: f.cost)[:4]
    grid = _needed_parts(readings, edges_x, edges_y, grid, expected, params)
    keep = _object_columns(grid, params.min_height)
    box, lower, upper, extents = None, np.full(3, np.nan), np.full(3, np.nan), None
    filled = np.zeros(grid.shape, bool)
    if keep.any() and (not screen or _outside(np.where(keep, grid, 0.0), expected,
                                              params.min_height)):
        edges_x, edges_y, grid, filled = _outlined(readings, edges_x, edges_y,
                                                   np.where(keep, grid, 0.0), params)
        clipper = _Clip(readings, edges_x, edges_y, grid, params, filled)
        clip, cost = clipper.search()
        box = _clip_box(clip, origin, start.yaw)
        extents = np.array([clip[1] - clip[0], clip[3] - clip[2], clip[4]])
        if interval:
            lower, upper = clipper.interval(clip, cost, fit_params, model)
            if _swapped(box.yaw, start.yaw):  # the box's length is the grid's y
                lower, upper = lower[[1, 0, 2]], upper[[1, 0, 2]]
    else:
        cost = readings.cost(edges_x, edges_y, grid)
    return HeightMap(grid, edges_x, edges_y, origin[:2].copy(), float(start.yaw), box,
                     lower, upper, extents, float(cost), len(rays), filled)


def _readings_around(rays: ZoneRays, start: OrientedBox, table_height: float,
                     model: SensorModelParams, fit_params: BoxFitParams,
                     params: HeightMapParams
                     ) -> tuple[_Readings | None, np.ndarray, np.ndarray, np.ndarray]:
    """The grid's frame around `start` (its origin on the table under the box's centre, the
    rotation into it, the grid's half extent) and the readings fitted there: those near the
    box that land inside the grid's volume (None if there are none)."""
    c, s = math.cos(start.yaw), math.sin(start.yaw)
    to_grid = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    origin = np.array([start.center[0], start.center[1], table_height])
    hmax = float(start.dims[2]) + params.margin
    half = start.dims[:2] / 2 + params.margin
    rays = rays.take(near_box(rays, start, table_height, params.margin)
                     & _lands_inside(rays, origin, to_grid, half, hmax))
    if len(rays) == 0:
        return None, origin, to_grid, half
    return (_Readings(rays, origin, to_grid, table_height, hmax, model, fit_params), origin,
            to_grid, half)


class _Levels(NamedTuple):
    """Where `_descend_levels` left the columns."""

    edges_x: np.ndarray
    edges_y: np.ndarray
    heights: np.ndarray
    expected: np.ndarray
    cost: float
    screened: bool


def _descend_levels(readings: _Readings, start: OrientedBox, table_height: float,
                    origin: np.ndarray, to_grid: np.ndarray, half: np.ndarray,
                    params: HeightMapParams, screen: bool, initial: str) -> _Levels:
    """The coordinate descent, coarse cells to fine, from the box's columns (`initial` "box")
    or from `_back_projection` ("readings"), to the finest cells or, with `screen`, to the
    coarsest when no column is needed outside the box there (`fit_height_map` then keeps the
    other start's fit, whose parts outside the box still have to pass `_needed_parts`).

    Why two starts: the descent moves one column at a time, and under the median rule a zone's
    prediction changes only once about half its footprint has moved, so a part the box start
    lacks (a flange's 20 mm plate, a gripper's fingers) is raised only where single columns
    pay for themselves. From the box, the flange's fit stopped at 1.5-2 times the cost its
    true shape has on the same cells; from the readings, on saved episodes, the
    flange's length came 13 -> 8 mm closer (median, 15 episodes) and no gripper lost its
    fingers (31-51 mm short in 4 of 15 before), the boxes unchanged (docs/box-estimation.md)."""
    previous = None
    for size in params.cells:
        edges_x = _grid_edges(-half[0], half[0], size)
        edges_y = _grid_edges(-half[1], half[1], size)
        expected = _box_columns(edges_x, edges_y, start, table_height, origin, to_grid)
        if previous is None:
            heights = (expected.copy() if initial == "box"
                       else _back_projection(readings, edges_x, edges_y, params.min_height))
            active = np.ones(expected.shape, bool)
        else:
            heights = _resampled(*previous, edges_x, edges_y)
            active = _unsettled(heights, expected, params.min_height)
        flat = heights.reshape(-1)
        cost = readings.descend(edges_x, edges_y, flat, expected.reshape(-1),
                                active.reshape(-1), params)
        previous = (edges_x, edges_y, flat.reshape(heights.shape))
        if screen and size == params.cells[0] and len(params.cells) > 1 and not _outside(
                _needed_parts(readings, edges_x, edges_y, previous[2], expected, params),
                expected, params.min_height):
            return _Levels(*previous, expected, cost, screened=True)
    return _Levels(*previous, expected, cost, screened=False)


def _back_projection(readings: _Readings, edges_x: np.ndarray, edges_y: np.ndarray,
                     min_height: float) -> np.ndarray:
    """(nx, ny) columns where the readings put surfaces: each cell's median height of the
    sub-rays' points at their zone's reading (0 where none lands, or lower than
    `min_height`). It smears a zone over its whole footprint, so it is a start, not a fit."""
    cell, z = _landing_points(readings.landing, edges_x, edges_y)
    ok = (cell >= 0) & np.isfinite(z)
    heights = np.zeros((len(edges_x) - 1) * (len(edges_y) - 1))
    present = np.unique(cell[ok])
    if len(present):
        heights[present] = scipy.ndimage.median(np.clip(z[ok], 0.0, readings.hmax),
                                                cell[ok] + 1, present + 1)
    heights[heights < min_height] = 0.0
    return heights.reshape(len(edges_x) - 1, len(edges_y) - 1)


def _outside(grid: np.ndarray, expected: np.ndarray, min_height: float) -> bool:
    """A column stands where the expected box has none."""
    return bool(np.any((grid > min_height) & (expected.reshape(grid.shape) == 0)))


def _box_columns(edges_x: np.ndarray, edges_y: np.ndarray, box: OrientedBox,
                 table_height: float, origin: np.ndarray, to_grid: np.ndarray) -> np.ndarray:
    """The box as columns: its height where a cell's centre lies in its footprint."""
    centre = to_grid @ (box.center - origin)
    cx, cy = (edges_x[:-1] + edges_x[1:]) / 2, (edges_y[:-1] + edges_y[1:]) / 2
    inside = (np.abs(cx - centre[0]) <= box.dims[0] / 2)[:, None] \
        & (np.abs(cy - centre[1]) <= box.dims[1] / 2)[None, :]
    return np.where(inside, box.center[2] + box.dims[2] / 2 - table_height, 0.0)


def _unsettled(heights: np.ndarray, expected: np.ndarray, min_height: float) -> np.ndarray:
    """The cells a finer level refits: within two cells of a step between columns or of a
    departure from the expected height. Elsewhere (a box's flat top, the bare table) the
    coarser level has settled them, and they are most of the grid."""
    step = (scipy.ndimage.grey_dilation(heights, size=(3, 3))
            - scipy.ndimage.grey_erosion(heights, size=(3, 3))) > min_height
    departs = np.abs(heights - expected) > min_height
    return scipy.ndimage.binary_dilation(step | departs, iterations=2)


def _resampled(edges_x: np.ndarray, edges_y: np.ndarray, grid: np.ndarray,
               new_x: np.ndarray, new_y: np.ndarray) -> np.ndarray:
    """`grid` on the cells of new_x, new_y: each new cell takes the column its centre is in
    (0 outside)."""
    ix = np.searchsorted(edges_x, (new_x[:-1] + new_x[1:]) / 2) - 1
    iy = np.searchsorted(edges_y, (new_y[:-1] + new_y[1:]) / 2) - 1
    inside = ((ix >= 0) & (ix < len(edges_x) - 1))[:, None] \
        & ((iy >= 0) & (iy < len(edges_y) - 1))[None, :]
    out = grid[np.clip(ix, 0, len(edges_x) - 2)[:, None], np.clip(iy, 0, len(edges_y) - 2)]
    return np.where(inside, out, 0.0)


def _clip_edges(edges_x: np.ndarray, edges_y: np.ndarray, clip: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    x0, x1, y0, y1 = clip[:4]
    x1, y1 = max(x1, x0), max(y1, y0)  # sides moved past each other: nothing is left
    return (np.r_[x0, edges_x[(edges_x > x0) & (edges_x < x1)], x1],
            np.r_[y0, edges_y[(edges_y > y0) & (edges_y < y1)], y1])


def _clipped(edges_x: np.ndarray, edges_y: np.ndarray, grid: np.ndarray, clip: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The columns cut by the box clip = (x0, x1, y0, y1, top): a grid whose outer edges are
    the clip's sides, each column no higher than its top."""
    ex, ey = _clip_edges(edges_x, edges_y, clip)
    return ex, ey, np.minimum(_resampled(edges_x, edges_y, grid, ex, ey), clip[4])


def _superellipse(x: np.ndarray, y: np.ndarray, sides: np.ndarray, n: float) -> np.ndarray:
    """Where |(x - cx) / a|^n + |(y - cy) / b|^n <= 1 for the sides (x0, x1, y0, y1)."""
    x0, x1, y0, y1 = sides
    a, b = (x1 - x0) / 2, (y1 - y0) / 2
    return (np.abs((x - (x0 + x1) / 2) / a) ** n + np.abs((y - (y0 + y1) / 2) / b) ** n) <= 1.0


def _outlined(readings: _Readings, edges_x: np.ndarray, edges_y: np.ndarray,
              grid: np.ndarray, params: HeightMapParams
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The object's columns on `params.outline_cell` cells inside the outline that explains the
    readings best: a superellipse (four sides, an exponent from round to square) cuts the
    columns, and the empty cells inside it, except holes the columns enclose (a bore), stand
    at one fitted height (or none). Two coordinate searches from the columns' bounding box: a
    cut alone, from a square (the columns as they are), and with the fill, from a rounded
    outline at the columns' median height; the fill is kept where it gains `fill_cost` (scaled
    by the cost per zone when above one) over the cut, and the cut leaves at most
    `fill_misfit` a zone.

    Why: 1 cm columns cannot draw a round rim. On nine LR-NBV flange episodes the true flange
    on 1 cm cells explained the readings worse than the fit (cost 487-1165 against 442-718),
    on 5 mm cells far better (233-686), and the column descent cannot get there on 5 mm cells: one
    column does not move a zone's median. An outline moves a whole rim at once, and its fill
    puts back a plate the descent lost in places (docs/box-estimation.md). Also returns the
    cells the fill raised."""
    size = params.outline_cell
    if size <= 0 or not (grid > params.min_height).any():
        return edges_x, edges_y, grid, np.zeros(grid.shape, bool)
    fx, fy = _grid_edges(edges_x[0], edges_x[-1], size), _grid_edges(edges_y[0], edges_y[-1], size)
    columns = _resampled(edges_x, edges_y, grid, fx, fy)
    raised = columns > params.min_height
    holes = scipy.ndimage.binary_fill_holes(raised) & ~raised
    x, y = np.meshgrid((fx[:-1] + fx[1:]) / 2, (fy[:-1] + fy[1:]) / 2, indexing="ij")
    ix, iy = np.flatnonzero(raised.any(axis=1)), np.flatnonzero(raised.any(axis=0))
    box = np.array([fx[ix[0]], fx[ix[-1] + 1], fy[iy[0]], fy[iy[-1] + 1]])
    reach = params.outline_reach
    lower, upper = box - reach, box + reach

    def outlined(p: np.ndarray) -> np.ndarray:
        inside = _superellipse(x, y, p[:4], p[4])
        return np.where(inside, np.where(raised, columns, np.where(holes, 0.0, p[5])), 0.0)

    # Only the zones that cross a cell some trial can change are evaluated: inside the
    # smallest outline the columns and holes stay as they are (an object narrower than two
    # reaches has none).
    inner = box + np.array([reach, -reach, reach, -reach])
    fixed = np.zeros(raised.shape, bool)
    if inner[1] > inner[0] and inner[3] > inner[2]:
        fixed = _superellipse(x, y, inner, 2.0) & (raised | holes)
    ray_start, cell, _, _ = _all_crossings(readings.o, readings.d, fx, fy, readings.hmax)
    free = ~fixed.reshape(-1)[cell]
    changing = np.add.reduceat(np.r_[free, False].astype(np.int64), ray_start[:-1]) > 0
    changing &= np.diff(ray_start) > 0
    near = readings.take(changing.reshape(readings.zones, readings.m).any(axis=1),
                         readings.hmax)
    if near.zones == 0:  # no reading sees where an outline could change anything
        return edges_x, edges_y, grid, np.zeros(grid.shape, bool)

    on_grid = near.cost_on(fx, fy)

    def cost(p: np.ndarray) -> float:
        return on_grid(outlined(p))

    # Fill heights: `fill_min` up to the tallest column, in at most 24 steps.
    low, top = params.fill_min, float(columns.max())
    levels = np.arange(low, top + 1e-9, max(0.0025, (top - low) / 24))
    starts = [np.r_[box, params.outline_exponents[-1], 0.0]]
    if len(levels):  # an object lower than the fill's floor: no fill
        starts.append(np.r_[box, params.outline_exponents[1],
                            np.clip(np.median(columns[raised]), low, top)])
    fits = []
    for p in starts:
        best = cost(p)
        searched = range(5) if p[5] == 0.0 else range(6)  # the cut alone: no fill
        for step in (2 * size, size):
            for _ in range(4):
                moved = False
                for i in searched:
                    trials = (params.outline_exponents if i == 4 else levels if i == 5 else
                              np.clip(p[i] + step * np.array([-3, -2, -1, 1, 2, 3]),
                                      lower[i], upper[i]))
                    for t in trials:
                        q = p.copy()
                        q[i] = t
                        if q[1] - q[0] < 2 * size or q[3] - q[2] < 2 * size or np.all(q == p):
                            continue
                        c = cost(q)
                        if c < best - 1e-9:
                            best, p, moved = c, q, True
                if not moved:
                    break
        fits.append((best, p))
    (cut_cost, cut), (fill_cost, fill) = fits[0], fits[-1]  # the same fit without a fill
    price = params.fill_cost * max(1.0, fill_cost / near.zones)
    explained = cut_cost <= params.fill_misfit * near.zones
    heights = outlined(fill if explained and fill_cost <= cut_cost - price else cut)
    return fx, fy, heights, (heights > params.min_height) & ~raised


class _Clip:
    """The object's box as a clip (x0, x1, y0, y1, top) of its columns, so that the box is not
    quantised to the cells: each side and the top are searched continuously over the columns
    extended straight outward from the object's outermost ones (a side moved out by d predicts
    the object d longer, as a box fit's side does)."""

    def __init__(self, readings: _Readings, edges_x: np.ndarray, edges_y: np.ndarray,
                 grid: np.ndarray, params: HeightMapParams,
                 filled: np.ndarray | None = None) -> None:
        self.readings, self.edges_x, self.edges_y, self.params = readings, edges_x, edges_y, \
            params
        # The cells an outline raised (`_outlined`): not columns, so not the top's evidence.
        self.filled = np.zeros(grid.shape, bool) if filled is None else filled
        self.size = float(edges_x[1] - edges_x[0])
        ix = np.flatnonzero((grid > 0).any(axis=1))
        iy = np.flatnonzero((grid > 0).any(axis=0))
        self.start = np.array([edges_x[ix[0]], edges_x[ix[-1] + 1], edges_y[iy[0]],
                               edges_y[iy[-1] + 1], grid.max()])
        inner = grid[ix[0]:ix[-1] + 1, iy[0]:iy[-1] + 1]
        self.base = np.pad(inner, ((ix[0], grid.shape[0] - 1 - ix[-1]),
                                   (iy[0], grid.shape[1] - 1 - iy[-1])), mode="edge")

    def cost(self, clip: np.ndarray, grid: np.ndarray | None = None,
             readings: _Readings | None = None) -> float:
        """The readings' (or a subset's) cost for the columns (`base`, or `grid` on the
        same cells) cut by `clip`."""
        return (readings or self.readings).cost(*_clipped(
            self.edges_x, self.edges_y, self.base if grid is None else grid, clip))

    def _near(self, i: int, lo: float, hi: float) -> _Readings:
        """The readings a move of side i between lo and hi can change (the top: all that
        pass below it)."""
        top = float(self.base.max()) + 1e-6
        ex, ey = self.edges_x[[0, -1]], self.edges_y[[0, -1]]
        if i < 2:
            ex = np.array([lo, hi])
        elif i < 4:
            ey = np.array([lo, hi])
        return self.readings.take(self.readings.crossing(ex, ey, top), top)

    def search(self) -> tuple[np.ndarray, float]:
        """Each side by up to `clip_span` in or one cell out (4 mm then 1 mm steps), the
        middle of a tie; then the top (`_plateau_top`)."""
        clip, size, ex, ey = self.start.copy(), self.size, self.edges_x, self.edges_y
        lower = np.array([max(ex[0], clip[0] - size), clip[0] + size,
                          max(ey[0], clip[2] - size), clip[2] + size, 0.5 * clip[4]])
        upper = np.array([clip[1] - size, min(ex[-1], clip[1] + size), clip[3] - size,
                          min(ey[-1], clip[3] + size), clip[4]])
        reach = self.params.clip_span + 0.004
        for _ in range(3):
            moved = False
            for i in range(5):
                # A side stays a cell from its opposite one.
                if i in (0, 2):
                    upper[i] = min(upper[i], clip[i + 1] - size)
                elif i in (1, 3):
                    lower[i] = max(lower[i], clip[i - 1] + size)
                near = self._near(i, max(lower[i], clip[i] - reach),
                                  min(upper[i], clip[i] + reach))
                best = self.cost(clip, readings=near)
                for span, step in ((self.params.clip_span, 0.004), (0.004, 0.001)):
                    trials = np.unique(np.clip(clip[i] + np.arange(-span, span + step / 2,
                                                                   step), lower[i], upper[i]))
                    costs = np.array([self.cost(np.r_[clip[:i], t, clip[i + 1:]],
                                                readings=near) for t in trials])
                    ties = trials[costs <= costs.min() + 1e-9]
                    if costs.min() < best - 1e-9:
                        moved = True
                    if costs.min() <= best + 1e-9:
                        clip[i], best = float(ties[len(ties) // 2]), float(costs.min())
            if not moved:
                break
        clip[4] = self._plateau_top(clip)
        return clip, self.flat_cost(clip)

    def _plateau_top(self, clip: np.ndarray) -> float:
        """The object's height: its top plateau (the columns within `plateau` of the 99th
        percentile of the object's column heights) refitted as one flat top. Column by column
        the heights also fit the noise, and their maximum is biased up (1-2 cm on a box seen
        at grazing angles); a plateau's common height is fitted by all its zones together, as
        the box fit's top is. A spike on less than 1 % of the footprint is not the object's
        height: the price is that a thin post on a part is missed."""
        grid = self.base
        cx = (self.edges_x[:-1] + self.edges_x[1:]) / 2
        cy = (self.edges_y[:-1] + self.edges_y[1:]) / 2
        inside = ((cx > clip[0]) & (cx < clip[1]))[:, None] \
            & ((cy > clip[2]) & (cy < clip[3]))[None, :]
        # Of the columns only: a fill taken in would be refitted as part of the top (a flange
        # 13 mm short).
        columns = inside & (grid > self.params.min_height) & ~self.filled
        if not columns.any():
            self.plateau = columns
            return float(clip[4])
        reference = float(np.percentile(grid[columns], 99))
        self.plateau = columns & (np.abs(grid - reference) <= self.params.plateau)
        top = reference
        for span, step in ((self.params.plateau, 0.002), (0.003, 0.0005)):
            trials = top + np.arange(-span, span + step / 2, step)
            costs = [self.flat_cost(np.r_[clip[:4], t]) for t in trials]
            top = float(trials[int(np.argmin(costs))])
        return top

    def flat_cost(self, clip: np.ndarray) -> float:
        """The cost with the top plateau at the clip's top (after `_plateau_top`)."""
        return self.cost(clip, np.where(self.plateau, clip[4], self.base))

    def _walled(self, clip: np.ndarray, i: int) -> Callable[[np.ndarray], float]:
        """The cost with side i (0-3) of the clip moved out as a wall: the columns beyond the
        clip's outermost line on that side at that line's tallest column as `flat_cost` has
        it (no higher than the top). Extended column by column instead, a side whose outermost
        line is a lone column of a spike or a skirt a few millimetres tall moves out with
        nothing the readings can see, and bounds nothing (a gripper's width came out 12 cm
        open). A wall asks what the box fit's interval asks of a box's side."""
        heights = np.where(self.plateau, clip[4], self.base)
        if i >= 2:
            heights = heights.T
        edges, across_edges = ((self.edges_x, self.edges_y) if i < 2
                               else (self.edges_y, self.edges_x))
        n = len(edges) - 1
        lower_side = i in (0, 2)
        # The clip's outermost cell on that side: a side on a cell edge keeps the inner cell,
        # also when the search's steps left it a rounding error outside the edge.
        inward = clip[i] + (1e-9 if lower_side else -1e-9)
        line = int(np.clip(np.searchsorted(edges, inward, side="right") - 1, 0, n - 1))
        low, high = (clip[2], clip[3]) if i < 2 else (clip[0], clip[1])
        across = np.flatnonzero((across_edges[1:] > low) & (across_edges[:-1] < high))
        beyond = np.arange(line) if lower_side else np.arange(line + 1, n)
        walled = heights.copy()
        if len(across):
            walled[beyond[:, None], across[None, :]] = min(float(heights[line, across].max()),
                                                           float(clip[4]))
        grid = walled if i < 2 else walled.T

        def cost(q: np.ndarray) -> float:
            return self.cost(q, np.where(self.plateau, q[4], grid))
        return cost

    def interval(self, clip: np.ndarray, best: float, fit_params: BoxFitParams,
                 model: SensorModelParams) -> tuple[np.ndarray, np.ndarray]:
        """(3,) lower and upper dimension bounds, as `box_fit.fit_box` makes them: how far each
        side and the top (the plateau with it) move out and in before the cost rises by the
        profile level. A side moves out as a wall (`_walled`) and no further than the grid's
        edge: past it the map has no columns and took no readings, so it could not say."""
        rise = fit_params.interval_cost * max(1.0, best / max(self.readings.zones - 5, 1))
        grid_edges = (self.edges_x[0], self.edges_x[-1], self.edges_y[0], self.edges_y[-1])
        moves = np.zeros((5, 2))
        for i in range(5):
            outward = -1 if i in (0, 2) else 1
            for k, sign in enumerate((outward, -outward)):
                cost, limit = self.flat_cost, None
                if i < 4 and k == 0:
                    cost, limit = self._walled(clip, i), abs(grid_edges[i] - clip[i])
                moves[i, k] = profile_move(cost, clip, i, sign, best, rise, fit_params, limit)
        share = (fit_params.share_tolerance * float(np.median(self.readings.measured))
                 * math.radians(model.geometry.zone_deg))
        widen = fit_params.interval_floor_m + np.array([2 * share, 2 * share, 0.0])
        dims = np.array([clip[1] - clip[0], clip[3] - clip[2], clip[4]])
        out = np.array([moves[0, 0] + moves[1, 0], moves[2, 0] + moves[3, 0], moves[4, 0]])
        inward = np.array([moves[0, 1] + moves[1, 1], moves[2, 1] + moves[3, 1], moves[4, 1]])
        return np.maximum(dims - inward - widen, 0.0), dims + out + widen


def _clip_box(clip: np.ndarray, origin: np.ndarray, yaw: float) -> OrientedBox:
    x0, x1, y0, y1, top = clip
    c, s = math.cos(yaw), math.sin(yaw)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    centre = np.array([origin[0] + c * cx - s * cy, origin[1] + s * cx + c * cy,
                       origin[2] + top / 2])
    return OrientedBox(centre, np.array([x1 - x0, y1 - y0, top]), yaw)


def _needed_parts(readings: _Readings, edges_x: np.ndarray, edges_y: np.ndarray,
                  grid: np.ndarray, expected: np.ndarray, params: HeightMapParams
                  ) -> np.ndarray:
    """`grid` without the parts outside the box the readings do not need: each group of
    columns raised outside it (8-connected) stays only if it has two columns or more and
    removing it raises the cost by `part_cost` a column. Measured on saved episodes: a
    gripper's finger or a flange's rim gains 10-70 a column, the strips a 1 cm grid adds
    beside a box 3-6, a lone column anything up to 70; 8 lies between.

    The price is in units of the model's sigma, so it is scaled by the cost per zone the
    height map leaves (when above one): a device that is not the model (uncalibrated) leaves
    5-16 a zone even on a box, and there, unscaled, every box grew parts 4 cm long out of the
    misfit (the datasheet device with the nominal model, docs/results.md)."""
    out = grid.copy()
    outside = (expected.reshape(grid.shape) == 0) & (grid > params.min_height)
    labels, count = scipy.ndimage.label(outside, structure=np.ones((3, 3)))
    if count == 0:
        return out
    base = readings.cost(edges_x, edges_y, grid)
    price = params.part_cost * max(1.0, base / readings.zones)
    for k in range(1, count + 1):
        part = labels == k
        without = np.where(part, 0.0, grid)
        n = int(part.sum())
        if n < 2 or readings.cost(edges_x, edges_y, without) - base < price * n:
            out[part] = 0.0
    return out


def _object_columns(grid: np.ndarray, min_height: float, min_volume_share: float = 0.1
                    ) -> np.ndarray:
    """The columns of the object: raised groups (columns one empty cell apart are one group:
    a part whose joint no view resolved, like a gripper's fingers) holding at least
    `min_volume_share` of the largest one's volume. A lone column explains one odd reading;
    a part of the object (one of two blocks) holds a fair share of it."""
    raised = grid > min_height
    labels, count = scipy.ndimage.label(scipy.ndimage.binary_dilation(raised),
                                        structure=np.ones((3, 3)))
    labels[~raised] = 0
    if count == 0:
        return raised
    volumes = scipy.ndimage.sum_labels(grid, labels, np.arange(1, count + 1))
    keep = np.flatnonzero(volumes >= min_volume_share * volumes.max()) + 1
    return np.isin(labels, keep)


class ShapeEstimator(BoxEstimator):
    """The box fit, replaced by the height map's box where the readings need more than a box
    (`extraction.estimator: shape`).

    The height map is fitted around the box fit and expects it (`_descend`'s prior is the box,
    not the empty table), so a column departs from the box only where the readings pay for
    it (see `fit_height_map` for its two starts). Its box is reported when it is larger
    than the box fit's upper bound in some dimension: the readings show object outside
    anything a box explains (the gripper's fingers, the flange's plate). Otherwise the box fit
    stands, 0.5-2 mm on boxes, where the height map's 1 cm columns add a spurious strip about
    once in five episodes. The warm start and the stop rule keep using the box fit."""

    def __init__(self, model: SensorModelParams, table_height: float,
                 params: BoxFitParams | None = None, shape: HeightMapParams | None = None
                 ) -> None:
        super().__init__(model, table_height, params)
        self._shape = shape or HeightMapParams()

    def estimate(self, start: OrientedBox | None = None, interval: bool = True
                 ) -> BoxFit | None:
        """The box fit (always with its interval: the decision needs its upper bound), or the
        height map's box with its own interval when `interval`."""
        fit = super().estimate(start, interval=True)
        if fit is None:
            return None
        shape = fit_height_map(self._rays, fit.box, self._table_height, self._model,
                               self._params, self._shape, interval, screen=True)
        # The grid is aligned with the fitted box, whose length runs along its x.
        if shape is None or shape.box is None or not np.any(shape.extents > fit.dims_upper):
            return fit
        return BoxFit(shape.box, shape.dims_lower, shape.dims_upper, shape.cost, shape.zones,
                      fit.n_evaluations, shape="height_map")


def compile_kernels() -> None:
    """Runs the shape estimate once on readings of a box predicted from two views, so that numba
    compiles its kernels and caches them on disk. A cold cache costs a process about 5 s the
    first time it fits (the report written after a fault on the real cell too): `make` calls
    this right after installing (`python -m lrnbv_drake.core.kernels`)."""
    model = SensorModelParams()
    box = OrientedBox(np.array([0.5, 0.0, 0.05]), np.array([0.12, 0.08, 0.10]), 0.0)
    x = _as_vector(box)
    frame = ToFFrame(distance_mm=np.full((8, 8), 300, np.int32), status=np.full((8, 8), 5),
                     sigma_mm=np.full((8, 8), 5), sequence=1, timestamp_us=0)
    rays = ZoneRays.empty(model.subsamples ** 2)
    for eye in ([0.5, 0.0, 0.45], [0.78, 0.1, 0.2]):
        view = zone_rays(frame, look_at(np.array(eye), box.center), model)
        view.measured[:] = np.nan_to_num(predicted_depths(view, x, 0.0, model), nan=0.3)
        rays = rays.extend(view)
    fit = fit_box(rays, box, 0.0, model)
    fit_height_map(rays, fit.box if fit else box, 0.0, model)
