"""OctoMap's insertPointCloud (discretize=False) as numba kernels on the dense grid, bit for bit.

Every float32 operation of OctoMap is written as a float64 operation rounded to float32: for
+, -, *, / and sqrt this gives the correctly rounded float32 result, i.e. what C++ computes.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from lrnbv_drake.core.mapping.keys import KEY_OFFSET

_F32 = np.float32


@numba.njit(cache=True)
def _update_cell(flat, v, update, lmin, lmax):
    """OctoMap's updateNode(key, log_odds_update) on one leaf (NaN = no node yet)."""
    old = flat[v]
    if old == old:  # existing node: OctoMap's early abort at the clamps (same result as
        # clamping, but it spares the store)
        if (update >= 0 and old >= lmax) or (update <= 0 and old <= lmin):
            return
        new = _F32(old + update)
    else:  # new nodes start at log-odds 0
        new = _F32(_F32(0.0) + update)
    if new < lmin:
        new = lmin
    elif new > lmax:
        new = lmax
    flat[v] = new


@numba.njit(cache=True)
def _key(c, inv_res):
    """OctoMap's coordToKeyChecked on a float32 coordinate; -1 when out of the tree (or NaN)."""
    s = np.floor(np.float64(c) * inv_res)
    if s >= -KEY_OFFSET and s < KEY_OFFSET:
        return np.int64(s) + KEY_OFFSET
    return np.int64(-1)


@numba.njit(cache=True)
def _flat_index(kx, ky, kz, off, dims):
    """Flat grid index of a key, -1 outside the grid."""
    ix = kx - off[0]
    iy = ky - off[1]
    iz = kz - off[2]
    if ix < 0 or iy < 0 or iz < 0 or ix >= dims[0] or iy >= dims[1] or iz >= dims[2]:
        return np.int64(-1)
    return (ix * dims[1] + iy) * dims[2] + iz


@numba.njit(cache=True)
def _never_enters(i, step, n):
    """True if a ray at grid index i on an axis, stepping by `step`, never gets into [0, n)."""
    return (i < 0 and step <= 0) or (i >= n and step >= 0)


@numba.njit(cache=True)
def _border_tmax(k, step, o, d, res):
    """OctoMap's initial tMax on one axis: float voxel border, double arithmetic."""
    border = (np.float64(k - KEY_OFFSET) + 0.5) * res
    border += np.float64(_F32(step * res * 0.5))
    return (border - np.float64(o)) / np.float64(d)


@numba.njit(cache=True)
def _free_ray(flat, stamp, scan, off, dims, res, inv_res, o, e, model):
    """Misses along OctoMap's computeRayKeys(o, e): origin voxel included, end voxel excluded,
    each cell once per scan and never a cell already hit in this scan."""
    kox, koy, koz = _key(o[0], inv_res), _key(o[1], inv_res), _key(o[2], inv_res)
    kx_end, ky_end, kz_end = _key(e[0], inv_res), _key(e[1], inv_res), _key(e[2], inv_res)
    if min(kox, koy, koz, kx_end, ky_end, kz_end) < 0:
        return  # computeRayKeys fails: out of the tree
    if kox == kx_end and koy == ky_end and koz == kz_end:
        return
    miss, lmin, lmax = model[1], model[2], model[3]

    dx = _F32(e[0] - o[0])
    dy = _F32(e[1] - o[1])
    dz = _F32(e[2] - o[2])
    length = _F32(math.sqrt(np.float64(_F32(_F32(_F32(dx * dx) + _F32(dy * dy))
                                            + _F32(dz * dz)))))
    dx = _F32(dx / length)
    dy = _F32(dy / length)
    dz = _F32(dz / length)
    sx = 1 if dx > 0 else (-1 if dx < 0 else 0)
    sy = 1 if dy > 0 else (-1 if dy < 0 else 0)
    sz = 1 if dz > 0 else (-1 if dz < 0 else 0)
    big = 1.7976931348623157e308
    tx = _border_tmax(kox, sx, o[0], dx, res) if sx != 0 else big
    ty = _border_tmax(koy, sy, o[1], dy, res) if sy != 0 else big
    tz = _border_tmax(koz, sz, o[2], dz, res) if sz != 0 else big
    ddx = res / abs(np.float64(dx)) if sx != 0 else big
    ddy = res / abs(np.float64(dy)) if sy != 0 else big
    ddz = res / abs(np.float64(dz)) if sz != 0 else big
    flen = np.float64(length)

    # Grid-relative indices; the flat index is only valid while all three are inside.
    nx, ny, nz = dims[0], dims[1], dims[2]
    ix, iy, iz = kox - off[0], koy - off[1], koz - off[2]
    ex, ey, ez = kx_end - off[0], ky_end - off[1], kz_end - off[2]
    v = (ix * ny + iy) * nz + iz
    vx, vy, vz = sx * ny * nz, sy * nz, sz
    in_x, in_y, in_z = 0 <= ix < nx, 0 <= iy < ny, 0 <= iz < nz
    # A ray outside the grid on an axis and not stepping towards it never enters it: stop
    # (nothing OctoMap would update inside the grid is skipped).
    if (_never_enters(ix, sx, nx) or _never_enters(iy, sy, ny)
            or _never_enters(iz, sz, nz)):
        return
    while True:
        if in_x and in_y and in_z and stamp[v] != scan:
            stamp[v] = scan
            _update_cell(flat, v, miss, lmin, lmax)
        # OctoMap's step choice, ties included.
        if tx < ty:
            dim = 0 if tx < tz else 2
        else:
            dim = 1 if ty < tz else 2
        if dim == 0:
            ix += sx
            tx += ddx
            v += vx
            in_x = 0 <= ix < nx
            if not in_x and _never_enters(ix, sx, nx):
                return
        elif dim == 1:
            iy += sy
            ty += ddy
            v += vy
            in_y = 0 <= iy < ny
            if not in_y and _never_enters(iy, sy, ny):
                return
        else:
            iz += sz
            tz += ddz
            v += vz
            in_z = 0 <= iz < nz
            if not in_z and _never_enters(iz, sz, nz):
                return
        if ix == ex and iy == ey and iz == ez:
            return
        if min(tx, ty, tz) > flen:  # OctoMap's guard against discretisation error
            return


@numba.njit(cache=True)
def _ray_end(o, p, max_range, end):
    """Writes the end of the free ray to `end`; returns True if `p` is a hit (within range)."""
    dx = _F32(p[0] - o[0])
    dy = _F32(p[1] - o[1])
    dz = _F32(p[2] - o[2])
    norm = math.sqrt(np.float64(_F32(_F32(_F32(dx * dx) + _F32(dy * dy)) + _F32(dz * dz))))
    if max_range < 0 or norm <= max_range:
        end[0], end[1], end[2] = p[0], p[1], p[2]
        return True
    # OctoMap: direction = (p - origin).normalized(); end = origin + direction * maxrange.
    fn = _F32(norm)
    mr = _F32(max_range)
    end[0] = _F32(o[0] + _F32(_F32(dx / fn) * mr))
    end[1] = _F32(o[1] + _F32(_F32(dy / fn) * mr))
    end[2] = _F32(o[2] + _F32(_F32(dz / fn) * mr))
    return False


@numba.njit(cache=True)
def insert_scan_kernel(grid, stamp, scan, off, dims, res, origin, points, max_range,
                       model):
    """OctoMap's computeUpdate + update: all hits first (stamped), then the misses."""
    grid = grid.reshape(-1)
    stamp = stamp.reshape(-1)
    inv_res = 1.0 / res
    hit, lmin, lmax = model[0], model[2], model[3]
    end = np.empty(3, dtype=np.float32)
    n = points.shape[0]
    for i in range(n):
        p = points[i]
        if not (np.isfinite(p[0]) and np.isfinite(p[1]) and np.isfinite(p[2])):
            continue
        if _ray_end(origin, p, max_range, end):
            kx, ky, kz = _key(p[0], inv_res), _key(p[1], inv_res), _key(p[2], inv_res)
            if kx < 0 or ky < 0 or kz < 0:
                continue
            v = _flat_index(kx, ky, kz, off, dims)
            if v >= 0 and stamp[v] != scan:
                stamp[v] = scan
                _update_cell(grid, v, hit, lmin, lmax)
    for i in range(n):
        p = points[i]
        if not (np.isfinite(p[0]) and np.isfinite(p[1]) and np.isfinite(p[2])):
            continue
        _ray_end(origin, p, max_range, end)
        _free_ray(grid, stamp, scan, off, dims, res, inv_res, origin, end, model)
