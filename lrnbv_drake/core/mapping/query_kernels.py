"""Numba kernels for the map's queries: cell scans over the grid, and the planner's ray walks.

The ray walks are grid-local double-precision DDAs: queries, not OctoMap ports.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def cells_at_least(grid, low):
    """(N, 3) indices of the cells whose log-odds are >= low (unknown cells never are), C order."""
    flat = grid.reshape(-1)
    n = 0
    for value in flat:
        if value >= low:
            n += 1
    out = np.empty((n, 3), dtype=np.int64)
    ny, nz = grid.shape[1], grid.shape[2]
    j = 0
    for v in range(flat.size):
        if flat[v] >= low:
            out[j, 0] = v // (ny * nz)
            out[j, 1] = (v // nz) % ny
            out[j, 2] = v % nz
            j += 1
    return out


@numba.njit(cache=True)
def count_cells(flat, thres):
    """(unknown, free, occupied) cell counts of the flattened grid."""
    unknown = free = 0
    for value in flat:
        if value != value:
            unknown += 1
        elif value < thres:
            free += 1
    return unknown, free, flat.size - unknown - free


@numba.njit(cache=True)
def ray_box_interval(o, u, t0, t1, bmin, bmax):
    """Slab test: the part of [t0, t1] where the ray o + t u is inside the box (returned
    t0 > t1 if none). A numba function, also used by the planner's gain kernel."""
    for a in range(3):
        if u[a] == 0.0:
            if o[a] < bmin[a] or o[a] > bmax[a]:
                return 1.0, 0.0
        else:
            ta = (bmin[a] - o[a]) / u[a]
            tb = (bmax[a] - o[a]) / u[a]
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
    return t0, t1


@numba.njit(cache=True, inline="always")
def _axis_start(o, u, t0, lo, n, res):
    """One axis of `walk_start`: (cell, step, parameter of the next boundary, per cell)."""
    cell = min(max(np.int64(math.floor((o + u * t0) / res)) - lo, 0), n - 1)
    if u > 0:
        return cell, 1, ((lo + cell + 1) * res - o) / u, res / u
    if u < 0:
        return cell, -1, ((lo + cell) * res - o) / u, -res / u
    return cell, 0, np.inf, np.inf


@numba.njit(cache=True, inline="always")
def walk_start(o, u, t0, lo, dims, res):
    """Grid DDA state at ray parameter t0 (a point inside the grid box) of the ray o + t u (u a
    unit vector; the grid's cell (0, 0, 0) is the world's cell `lo`): (cell, step, next,
    per_cell), each a 3-tuple. Tuples, not arrays: numba keeps them in registers, which made
    the planner's gain kernel 5x faster than array state."""
    i, si, ti, di = _axis_start(o[0], u[0], t0, lo[0], dims[0], res)
    j, sj, tj, dj = _axis_start(o[1], u[1], t0, lo[1], dims[1], res)
    k, sk, tk, dk = _axis_start(o[2], u[2], t0, lo[2], dims[2], res)
    return (i, j, k), (si, sj, sk), (ti, tj, tk), (di, dj, dk)


@numba.njit(cache=True, inline="always")
def walk_step(cell, step, next_t, per_cell, dims):
    """The next cell of the walk: (cell, next, t), t the parameter where it is entered, or -1
    on leaving the grid."""
    if next_t[0] < next_t[1]:
        a = 0 if next_t[0] < next_t[2] else 2
    else:
        a = 1 if next_t[1] < next_t[2] else 2
    t = next_t[a]
    if a == 0:
        cell = (cell[0] + step[0], cell[1], cell[2])
        next_t = (next_t[0] + per_cell[0], next_t[1], next_t[2])
    elif a == 1:
        cell = (cell[0], cell[1] + step[1], cell[2])
        next_t = (next_t[0], next_t[1] + per_cell[1], next_t[2])
    else:
        cell = (cell[0], cell[1], cell[2] + step[2])
        next_t = (next_t[0], next_t[1], next_t[2] + per_cell[2])
    if cell[a] < 0 or cell[a] >= dims[a]:
        return cell, next_t, -1.0
    return cell, next_t, t


@numba.njit(cache=True)
def first_occupied_kernel(grid, lo, res, thres, origins, dirs, max_range, out_t, out_cell):
    """`OccupancyMap.first_occupied` on the raw grid, into out_t and out_cell."""
    dims = grid.shape
    gmin = lo * res
    gmax = (lo + np.array(dims)) * res
    u = np.empty(3)
    for r in range(origins.shape[0]):
        o = origins[r]
        norm = math.sqrt(dirs[r, 0] ** 2 + dirs[r, 1] ** 2 + dirs[r, 2] ** 2)
        if not norm > 0:
            continue
        for a in range(3):
            u[a] = dirs[r, a] / norm
        t0, t1 = ray_box_interval(o, u, 0.0, max_range, gmin, gmax)
        if t0 > t1:
            continue
        cell, step, next_t, per_cell = walk_start(o, u, t0, lo, dims, res)
        t = t0
        while True:
            if grid[cell[0], cell[1], cell[2]] >= thres:
                out_t[r] = t
                out_cell[r, 0], out_cell[r, 1], out_cell[r, 2] = cell[0], cell[1], cell[2]
                break
            cell, next_t, t = walk_step(cell, step, next_t, per_cell, dims)
            if t < 0 or t > t1:
                break


@numba.njit(cache=True)
def unknown_kernel(grid, lo, res, thres, origins, ends, bmin, bmax, stop_at_occupied,
                   out_n, out_len):
    """`OccupancyMap.unknown_along_segments` on the raw grid, added into out_n and out_len."""
    dims = grid.shape
    gmin = lo * res
    gmax = (lo + np.array(dims)) * res
    u = np.empty(3)
    for r in range(origins.shape[0]):
        o = origins[r]
        for a in range(3):
            u[a] = ends[r, a] - o[a]
        length = math.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
        if not length > 0:
            continue
        for a in range(3):
            u[a] /= length
        t0, t1 = ray_box_interval(o, u, 0.0, length, gmin, gmax)
        b0, b1 = ray_box_interval(o, u, 0.0, length, bmin, bmax)
        if t0 > t1 or b0 > b1:
            continue
        cell, step, next_t, per_cell = walk_start(o, u, t0, lo, dims, res)
        t = t0
        while t <= t1:
            value = grid[cell[0], cell[1], cell[2]]
            if stop_at_occupied and value >= thres:
                break
            t_next = min(next_t[0], next_t[1], next_t[2])
            if value != value:
                overlap = min(t_next, t1, b1) - max(t, b0)
                # The walk's t accumulates rounding: a box face on a cell face leaves the
                # next cell an overlap of 1e-17 m, not 0.
                if overlap > 1e-9 * res:
                    out_n[r] += 1
                    out_len[r] += overlap
            cell, next_t, t = walk_step(cell, step, next_t, per_cell, dims)
            if t < 0:
                break
