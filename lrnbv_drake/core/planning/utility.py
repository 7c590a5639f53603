"""The LR-NBV utility U = we*Ge + wd*Gd + wq*Gq + wv*Gv, evaluated for many sensor poses at once.

Gains (paper, Section "Utility Function"; docs/algorithm.md maps every symbol here):

- Rays: one per zone (optionally k x k per zone) from the sensor's zone geometry, r(t) = o + t*d
  with |d| = `max_range`, sampled at t_k spaced one map cell apart.
- Validity V(r, t_k): the sample lies in the ROI and no occupied cell comes before it on the
  ray (found by walking the ray cell by cell, so that a ray clipping the corner of an
  occupied cell between two samples is stopped there); the first occupied cell (the object
  surface) is itself valid, counted once, and nothing behind it is.
- Ge: sum over valid samples of W = the volume of the sample's cell when that cell is unknown
  (the volumetric gain of Bircher et al.: unknown volume the view would traverse).
- Gd: sum over valid samples of 1 / (1 + rho), rho the object points within r_d of the sample.
- Gq: 1 / (1 + |x_T - x_object|).
- Gv: -1 if the sensor position's cell of the coarse visited grid was visited, else 0.
- Gb (not the paper's, `planner.utility: box`): the width of the estimate's side bands the
  view's rays cross (core/planning/box_gain.py).

The map state inside the ROI is copied once per planning step into a small dense snapshot
(`PlanningSnapshot`), so the kernel walks plain arrays and never touches the map.
"""

from __future__ import annotations

import dataclasses as dc

import numba
import numpy as np
from numba.core import types
from numba.extending import intrinsic
from scipy import ndimage

from lrnbv_drake.core.boxes import AlignedBox, OrientedBox
from lrnbv_drake.core.mapping import OccupancyMap, ray_box_interval, walk_start, walk_step
from lrnbv_drake.core.planning.box_gain import SideBands, box_gains
from lrnbv_drake.core.planning.config import GainParams, UtilityWeights
from lrnbv_drake.core.sensing.sensor import ZoneGeometry

#: Cell states in a snapshot, as `OccupancyMap.classify` returns them (0 is free).
UNKNOWN, OCCUPIED = -1, 1


@dc.dataclass
class PlanningSnapshot:
    """The map inside the ROI as dense arrays, plus the object estimate.

    Args:
        roi: the region of interest.
        origin: world position of the corner of cell (0, 0, 0).
        resolution: cell size, metres.
        state: (nx, ny, nz) int8, -1 unknown, 0 free, 1 occupied.
        density: (nx, ny, nz) float32, object points within the density radius of each cell.
        object_center: x_object for the quality gain.
        bands: where the reported estimate's sides may lie, for the box gain; None before an
            estimate with an interval.
    """

    roi: AlignedBox
    origin: np.ndarray
    resolution: float
    state: np.ndarray
    density: np.ndarray
    object_center: np.ndarray
    bands: SideBands | None = None


def _sphere_kernel(radius_cells: float) -> np.ndarray:
    r = int(np.floor(radius_cells))
    ax = np.arange(-r, r + 1)
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    return (x**2 + y**2 + z**2 <= radius_cells**2 + 1e-9).astype(np.float32)


def make_snapshot(occupancy, roi: AlignedBox, object_points: np.ndarray,
                  object_center: np.ndarray, density_radius: float,
                  bands: SideBands | None = None) -> PlanningSnapshot:
    """Copies the map's cells inside `roi` and counts object points around each cell.

    Args:
        occupancy: an `OccupancyMap` (anything with `resolution` and `classify_block`).
        roi: region of interest, snapped outwards to whole cells.
        object_points: (N, 3) centres of the object's cells.
        object_center: the object's estimated centre.
        density_radius: r_d of the density gain, metres.
        bands: the estimate's side bands (`PlanningSnapshot.bands`).
    """
    res = float(occupancy.resolution)
    lo = np.floor(roi.lower / res).astype(np.int64)
    hi = np.ceil(roi.upper / res).astype(np.int64)
    shape = tuple(int(n) for n in np.maximum(hi - lo, 1))
    origin = lo * res
    state = occupancy.classify_block(lo, shape)
    counts = np.zeros(shape, np.float32)
    pts = np.asarray(object_points, float).reshape(-1, 3)
    if len(pts):
        cells = np.floor((pts - origin) / res).astype(np.int64)
        inside = np.all((cells >= 0) & (cells < shape), axis=1)
        np.add.at(counts, tuple(cells[inside].T), 1.0)
    # rho(cell) = object points within r_d of the cell centre (a sphere of cells).
    density = ndimage.convolve(counts, _sphere_kernel(density_radius / res), mode="constant")
    return PlanningSnapshot(roi=roi, origin=origin, resolution=res, state=state,
                            density=density.astype(np.float32),
                            object_center=np.asarray(object_center, float), bands=bands)


def sensor_rays(geometry: ZoneGeometry, rays_per_zone: int = 1) -> np.ndarray:
    """(R, 3) unit ray directions in the sensor frame, one per zone (or k x k per zone)."""
    d = geometry.sub_directions(rays_per_zone).reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c with one rounding (LLVM's fma), which numba does not otherwise offer."""
    def codegen(context, builder, signature, args):
        return builder.fma(*args)
    return types.float64(types.float64, types.float64, types.float64), codegen


@numba.njit(cache=True)
def _first_occupied(p, u, t0, t1, res, state, hit):
    """The parameter in [t0, t1] where the ray p + t u (grid frame, u a unit vector) first
    enters an occupied cell of `state`, its cell into `hit`; inf if none."""
    dims = state.shape
    cell, step, next_t, per_cell = walk_start(p, u, t0, (0, 0, 0), dims, res)
    t = t0
    while t >= 0.0 and t <= t1:
        if state[cell[0], cell[1], cell[2]] == OCCUPIED:
            hit[0], hit[1], hit[2] = cell
            return t
        cell, next_t, t = walk_step(cell, step, next_t, per_cell, dims)
    return np.inf


@numba.njit(cache=True)
def _ray_gains_kernel(poses, rays, max_range, roi_lo, roi_hi, origin, res, state, density,
                      out_ge, out_gd):
    nx, ny, nz = state.shape
    cell_volume = res * res * res
    d = np.empty(3)
    hit = np.empty(3, dtype=np.int64)
    for p in range(poses.shape[0]):
        o = poses[p, :3, 3]
        o0, o1, o2 = o[0], o[1], o[2]
        rotation = poses[p]
        ge = 0.0
        gd = 0.0
        for r in range(rays.shape[0]):
            # d = rotation @ ray, its fused multiply-adds in the order of the OpenBLAS dgemv
            # (SkylakeX kernel) that np.dot called here: the samples and their cells stay bit
            # for bit what they were on the development machine, without a BLAS call per ray
            # (40 % of the kernel's time), and no longer vary with the CPU's BLAS kernel.
            x0, x1, x2 = rays[r, 0], rays[r, 1], rays[r, 2]
            for a in range(3):
                d[a] = _fma(rotation[a, 2], x2,
                            _fma(rotation[a, 0], x0, rotation[a, 1] * x1))
            t0, t1 = ray_box_interval(o, d, 0.0, max_range, roi_lo, roi_hi)
            if t1 <= t0:
                continue
            d0, d1, d2 = d[0], d[1], d[2]
            # Where the ray first enters an occupied cell, walked cell by cell (the samples
            # below are a cell apart and would step past the corner of one).
            t_hit = _first_occupied((o0 - origin[0], o1 - origin[1], o2 - origin[2]),
                                    (d0, d1, d2), t0, t1, res, state, hit)
            # Samples one cell apart (t in metres: the paper's t is t / max_range), from where
            # the ray enters the ROI. Scalars, not `o + t * d`: the same arithmetic without
            # a temporary array per sample.
            t = t0 + 0.5 * res
            seen = False  # the surface cell, counted once
            while t < min(t1, t_hit):
                i = int(np.floor(((o0 + t * d0) - origin[0]) / res))
                j = int(np.floor(((o1 + t * d1) - origin[1]) / res))
                k = int(np.floor(((o2 + t * d2) - origin[2]) / res))
                t += res
                if i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
                    continue
                s = state[i, j, k]
                if s == UNKNOWN:
                    ge += cell_volume
                gd += 1.0 / (1.0 + density[i, j, k])
                if s == OCCUPIED:  # a sample rounded into the surface cell
                    seen = True
                    break
            if t_hit < t1 and not seen:  # the surface is seen; nothing behind it is
                gd += 1.0 / (1.0 + density[hit[0], hit[1], hit[2]])
        out_ge[p] = ge
        out_gd[p] = gd


@dc.dataclass
class Gains:
    """Raw gains of a batch of poses, each (P,); the box gain zero where not given."""

    exploration: np.ndarray
    density: np.ndarray
    quality: np.ndarray
    visited: np.ndarray
    box: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.box is None:
            self.box = np.zeros(len(self.exploration))

    def _fields(self) -> tuple[np.ndarray, ...]:
        # Not dataclasses.astuple, which deep-copies every array.
        return self.exploration, self.density, self.quality, self.visited, self.box

    def take(self, index) -> Gains:
        """The gains of a subset of the poses."""
        return Gains(*(np.atleast_1d(g[index]) for g in self._fields()))

    @staticmethod
    def concatenate(parts: list[Gains]) -> Gains:
        if not parts:
            return Gains(*(np.zeros(0) for _ in range(5)))
        return Gains(*(np.concatenate(g) for g in zip(*(p._fields() for p in parts),
                                                       strict=True)))


def ray_gains(poses: np.ndarray, snapshot: PlanningSnapshot, rays: np.ndarray,
              max_range: float) -> tuple[np.ndarray, np.ndarray]:
    """Ge and Gd of each pose (P, 4, 4): the two ray-casting gains."""
    poses = np.ascontiguousarray(np.asarray(poses, np.float64).reshape(-1, 4, 4))
    ge = np.zeros(len(poses))
    gd = np.zeros(len(poses))
    _ray_gains_kernel(poses, np.ascontiguousarray(rays, dtype=np.float64), float(max_range),
                      snapshot.roi.lower.astype(np.float64), snapshot.roi.upper.astype(np.float64),
                      snapshot.origin.astype(np.float64), snapshot.resolution, snapshot.state,
                      snapshot.density, ge, gd)
    return ge, gd


class VisitedGrid:
    """The coarse grid of sensor positions already used for an acquisition (Gv)."""

    def __init__(self, cell_size: float = 0.18):
        if not cell_size > 0:
            raise ValueError(f"visited cell size must be > 0; got {cell_size}")
        self.cell_size = cell_size
        self._cells: set[tuple[int, int, int]] = set()

    def _keys(self, positions: np.ndarray) -> np.ndarray:
        return np.floor(np.asarray(positions, float).reshape(-1, 3) / self.cell_size).astype(
            np.int64)

    def visit(self, position: np.ndarray) -> None:
        self._cells.add(tuple(int(v) for v in self._keys(position)[0]))

    def visited(self, positions: np.ndarray) -> np.ndarray:
        """(P,) bool: whether each position's cell was visited."""
        return np.array([tuple(k) in self._cells for k in self._keys(positions).tolist()],
                        dtype=bool)

    def __len__(self) -> int:
        return len(self._cells)


def evaluate_gains(poses: np.ndarray, snapshot: PlanningSnapshot, rays: np.ndarray,
                   visited: VisitedGrid, params: GainParams) -> Gains:
    """The raw gains for each pose (P, 4, 4): the paper's four, and the box gain where the
    snapshot has the estimate's bands."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    ge, gd = ray_gains(poses, snapshot, rays, params.max_range)
    distance = np.linalg.norm(poses[:, :3, 3] - snapshot.object_center, axis=1)
    gq = 1.0 / (1.0 + distance)
    gv = -visited.visited(poses[:, :3, 3]).astype(float)
    gb = (None if snapshot.bands is None
          else box_gains(poses, snapshot.bands, rays, params.max_range))
    return Gains(exploration=ge, density=gd, quality=gq, visited=gv, box=gb)


class UtilityFunction:
    """U from raw gains, with the running maxima used for normalisation.

    The maxima only grow, so a utility computed now is comparable with any other computed now:
    cached nodes keep their raw gains and are scored again whenever they are compared.
    """

    def __init__(self, weights: UtilityWeights, normalize: bool = True):
        self.weights = weights
        self.normalize = normalize
        self._max = np.full(4, 1e-12)

    def observe(self, gains: Gains) -> None:
        """Raises the running maxima with newly evaluated gains."""
        if len(gains.exploration):
            self._max = np.maximum(self._max, [gains.exploration.max(), gains.density.max(),
                                               gains.quality.max(), gains.box.max()])

    def __call__(self, gains: Gains) -> np.ndarray:
        w = self.weights
        scale = self._max if self.normalize else np.ones(4)
        return (w.exploration * gains.exploration / scale[0]
                + w.density * gains.density / scale[1]
                + w.quality * gains.quality / scale[2]
                + w.visited * gains.visited
                + w.box * gains.box / scale[3])


def compile_kernels() -> None:
    """Compiles the gains' kernels into numba's on-disk cache by scoring one view of a small
    map, the box gain included: cold, the first planning iteration of every process would
    wait for them (`python -m lrnbv_drake.core.kernels`)."""
    occupancy = OccupancyMap(bounds=((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2)))
    box = OrientedBox(np.array([0.0, 0.0, 0.02]), np.full(3, 0.04), 0.0)
    snapshot = make_snapshot(occupancy, AlignedBox(occupancy.bounds[0], occupancy.bounds[1]),
                             box.center[None], box.center, GainParams().density_radius,
                             SideBands.of(box, 0.9 * box.dims, 1.1 * box.dims, 0.0))
    view = np.diag([1.0, -1.0, -1.0, 1.0])
    view[2, 3] = 0.3
    evaluate_gains(view[None], snapshot, sensor_rays(ZoneGeometry()), VisitedGrid(),
                   GainParams())
